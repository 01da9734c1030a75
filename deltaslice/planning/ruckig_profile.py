"""A ruckig trajectory as plain arrays, sampled exactly and vectorised.

ruckig's ``Trajectory.at_time`` costs one Python call per sample and the object cannot be pickled
(so a travel could not be planned in a worker process). A time-synchronised move from rest to rest
is one section whose every degree of freedom is a sequence of seven constant-jerk phases; ruckig's
Python binding exposes them (``Trajectory.profiles``: phase durations ``t``, jerks ``j`` and the
position, velocity and acceleration ``p, v, a`` at each phase start), and evaluating the same cubic
ruckig evaluates gives the same samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..jit import njit


@dataclass(frozen=True)
class RuckigProfile:
    """t_end: (J,7) cumulative phase end times, s; p, v, a: (J,8) state at each phase start
    (joint units, /s, /s^2); j: (J,7) jerk per phase; pf: (J,) final position; duration: s."""

    t_end: np.ndarray
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    j: np.ndarray
    pf: np.ndarray
    duration: float

    @classmethod
    def from_trajectory(cls, traj) -> "RuckigProfile | None":
        """The arrays of a ruckig Trajectory, or None when it is not one section without brake or
        pre-acceleration phases (then only ``at_time`` is exact)."""
        profiles = getattr(traj, "profiles", None)
        if profiles is None or len(profiles) != 1:
            return None
        section = profiles[0]
        if any(pr.brake.duration > 0 or pr.accel.duration > 0 for pr in section):
            return None
        t = np.array([pr.t for pr in section], dtype=float)
        return cls(
            t_end=np.cumsum(t, axis=1),
            p=np.array([pr.p for pr in section], dtype=float),
            v=np.array([pr.v for pr in section], dtype=float),
            a=np.array([pr.a for pr in section], dtype=float),
            j=np.array([pr.j for pr in section], dtype=float),
            pf=np.array([pr.pf for pr in section], dtype=float),
            duration=float(traj.duration),
        )

    def positions(self, tau: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Joint positions (n,J) at times tau (n,) s, clipped to [0, duration]; written into out
        (n,J) float64 when given (the sampler's rows), and returned. One compiled pass: per joint
        numpy took a dozen calls, a sampled travel's largest cost."""
        tau = np.ascontiguousarray(tau, dtype=np.float64)
        J = self.t_end.shape[0]
        if out is None:
            out = np.empty((len(tau), J))
        elif not isinstance(out, np.ndarray) or out.shape != (len(tau), J) or out.dtype != np.float64:
            raise ValueError(f"positions: out: expected a float64 array of shape ({len(tau)}, {J})")
        _positions_kernel(self.t_end, self.p, self.v, self.a, self.j, self.pf, float(self.duration), tau, out)
        return out


@njit(inline="always")  # one caller: typed in it, no module of its own on a first run
def _cubic(dt, p, v, a, j):
    """A constant-jerk phase's position dt s after its start (p, v, a: its start state; j: its jerk),
    as ruckig evaluates it."""
    return p + dt * (v + dt * (0.5 * a + dt * j / 6.0))


@njit
def _positions_kernel(t_end, p, v, a, j, pf, duration, tau, q):
    """q (n, J): each joint's position at tau (n,) clipped to [0, duration]: in the phase whose
    cumulative end is the first after the time (searchsorted, side right, on t_end (J, P)), its
    cubic (:func:`_cubic`); the final position pf past the last phase, and at a NaN time (which
    numpy's search puts after every end)."""
    J, P = t_end.shape
    for i in range(tau.shape[0]):
        ta = tau[i]
        nan = ta != ta
        ta = min(max(ta, 0.0), duration)
        for d in range(J):
            k = 0
            if nan:
                k = P
            while k < P and t_end[d, k] <= ta:
                k += 1
            if k >= P:
                q[i, d] = pf[d]
            else:
                q[i, d] = _cubic(ta - (t_end[d, k - 1] if k > 0 else 0.0), p[d, k], v[d, k], a[d, k], j[d, k])


@njit
def _positions_many_kernel(t_end, p, v, a, j, pf, duration, tau, q):
    """:func:`_positions_kernel` of each profile r of (P, ...) stacked arrays at its own times tau[r]
    into q[r]."""
    for r in range(tau.shape[0]):
        _positions_kernel(t_end[r], p[r], v[r], a[r], j[r], pf[r], duration[r], tau[r], q[r])


def positions_many(profiles, tau: np.ndarray) -> np.ndarray:
    """:meth:`RuckigProfile.positions` of P profiles with as many joints, each at its own times:
    tau (P, n) s, each row clipped to its profile's [0, duration] -> (P, n, J). One compiled pass
    over all of them (the clearance check of a batch of travels samples hundreds of moves: in
    numpy, arrays of every phase at every time, and an array signature of the cubic to load)."""
    t_end, p, v, a, j, pf = (np.array([getattr(pr, f) for pr in profiles], dtype=np.float64)
                             for f in ("t_end", "p", "v", "a", "j", "pf"))
    duration = np.array([pr.duration for pr in profiles], dtype=np.float64)
    tau = np.ascontiguousarray(tau, dtype=np.float64).reshape(len(profiles), -1)
    q = np.empty(tau.shape + (t_end.shape[1],))
    _positions_many_kernel(t_end, p, v, a, j, pf, duration, tau, q)
    return q
