"""What the actuators can give and what the machine's parts weigh: the ``[dynamics]`` table.

Optional: a printer file without it plans to its constant ``[joints] acceleration_max`` as before.
With it, :class:`Dynamics` holds the family's masses (read by the family module's
``read_dynamics``, as its ``read_geometry`` reads ``[kinematics]``) and :class:`ActuatorCurves`,
each joint's speed-torque curve. Torques are N m at revolute joints and forces N at prismatic
ones (joint units rad and mm inside; speeds deg/s or mm/s in the file).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import Section

# linear: a DC motor behind gears (hobby servo, gear motor, Dynamixel): torque falls in a line from
# stall at rest to none at the no-load speed. pull_out: a stepper: its pull-out torque holds to a
# corner speed, then falls as corner / speed (the winding's current no longer reaches its set
# value), none from the no-load speed on. table: a measured curve.
CURVES = ("linear", "pull_out", "table")


@dataclass(frozen=True)
class ActuatorCurves:
    """Each joint's speed-torque curve where its motor drives the motion (torque and speed of one
    sign); braking, a motor is taken to give its stall torque at most (a servo's driver limits its
    current, and back-EMF helps it brake, so that is the safe side).

    stall: (J,) N m or N; no_load_speed, corner_speed: (J,) rad/s or mm/s (corner_speed NaN
    unless ``curve == "pull_out"``); points: ((speed fraction of no_load_speed, torque fraction
    of stall), ...) from (0, 1), increasing in speed, for ``curve == "table"``, else ()."""

    curve: str
    stall: tuple[float, ...]
    no_load_speed: tuple[float, ...]
    corner_speed: tuple[float, ...] = ()
    points: tuple[tuple[float, float], ...] = ()

    def driving_limit(self, speed) -> np.ndarray:
        """speed (N, J) joint units/s (either sign) -> (N, J) N m or N: the largest torque the
        motor gives while driving at that speed."""
        v = np.abs(np.asarray(speed, dtype=float))
        stall, v0 = np.array(self.stall), np.array(self.no_load_speed)
        if self.curve == "linear":
            frac = 1.0 - v / v0
        elif self.curve == "pull_out":
            corner = np.array(self.corner_speed)
            with np.errstate(divide="ignore"):
                frac = np.where(v <= corner, 1.0, corner / v)
        else:
            x, y = np.array(self.points).T
            frac = np.interp(v / v0, x, y, right=0.0)
        return stall * np.clip(np.where(v < v0, frac, 0.0), 0.0, 1.0)

    def line_speed(self) -> tuple[float, ...]:
        """(J,) joint units/s: w such that the line ``stall (1 - |speed| / w)`` lies on or under the
        curve at every speed (the planner's linear driving limit). linear: the no-load speed;
        pull_out: also at most 4 corner_speed (the line touches corner / v at v = w / 2 there);
        table: under every point (the curve is linear between them) and zero past the last."""
        v0 = np.array(self.no_load_speed, dtype=float)
        if self.curve == "pull_out":
            return tuple(np.minimum(v0, 4.0 * np.array(self.corner_speed)).tolist())
        if self.curve == "table":
            x, y = np.array(self.points, dtype=float).T
            with np.errstate(divide="ignore"):
                frac = min(float(x[-1]) if y[-1] > 0 else 1.0, float(np.min(np.where(y < 1, x / (1 - y), np.inf))))
            return tuple((v0 * min(frac, 1.0)).tolist())
        return tuple(v0.tolist())

    def scaled(self, factor: float) -> "ActuatorCurves":
        """The same curves with every torque times factor (speeds kept): the planned ones."""
        return ActuatorCurves(self.curve, tuple(s * factor for s in self.stall), self.no_load_speed, self.corner_speed,
                              self.points)

    def available(self, speed, torque) -> np.ndarray:
        """(N, J) torque magnitude the actuators give in the direction of ``torque`` (N, J) at joint
        speeds ``speed`` (N, J): the curve where they drive (torque x speed > 0), stall otherwise."""
        torque = np.asarray(torque, dtype=float)
        driving = torque * np.asarray(speed, dtype=float) > 0
        return np.where(driving, self.driving_limit(speed), np.array(self.stall))

    def over_line(self, speed, torque) -> np.ndarray:
        """(N, J) bool: where a motor drives and its torque is beyond its speed-torque curve (the
        joint goes faster than the motor can at that torque)."""
        torque = np.asarray(torque, dtype=float)
        driving = torque * np.asarray(speed, dtype=float) > 0
        return driving & (np.abs(torque) > self.driving_limit(speed))


@dataclass(frozen=True)
class Dynamics:
    """A machine's masses (its family's dataclass) and its actuators' curves."""

    masses: object
    actuators: ActuatorCurves


def read_actuators(sec: Section, kinds: tuple[str, ...], actuator: str | None = None) -> ActuatorCurves:
    """The actuator keys of ``[dynamics]`` for joints of ``kinds`` (revolute speeds deg/s in the
    file, rad/s inside); the curve defaults to the ``[joints] actuator``'s: ``pull_out`` for a
    stepper, ``linear`` for the others (DC motors behind gears)."""
    n = len(kinds)
    scale = [math.radians(1.0) if k == "revolute" else 1.0 for k in kinds]
    stall = sec.getfloats("stall_torque", n, above=0, maxval=1e6)
    v0 = sec.getfloats("no_load_speed", n, above=0)
    curve = sec.getstr("speed_torque_curve", "pull_out" if actuator == "stepper" else "linear", choices=CURVES,
                       required=False)
    corner: tuple = ()
    points: tuple = ()
    if curve == "pull_out":
        corner = sec.getfloats("corner_speed", n, above=0)
        for i in range(n):
            if not corner[i] < v0[i]:
                sec.fail("corner_speed", list(corner), f"a corner speed below no_load_speed for every joint "
                         f"(joint {i + 1}: {corner[i]:g} >= {v0[i]:g})")
        corner = tuple(c * k for c, k in zip(corner, scale))
    elif curve == "table":
        points = _read_points(sec)
    return ActuatorCurves(curve=curve, stall=stall, no_load_speed=tuple(v * k for v, k in zip(v0, scale)),
                          corner_speed=corner, points=points)


def _read_points(sec: Section) -> tuple:
    """``curve_points``: ``[[speed fraction, torque fraction], ...]`` from ``[0, 1]``, speeds
    increasing within [0, 1], torques within [0, 1]."""
    sec._record("curve_points", "list", True, None)
    pts = sec.get("curve_points", None)
    expected = ("a list of at least 2 [speed / no_load_speed, torque / stall_torque] pairs, the first [0, 1], "
                "speeds increasing within 0..1, torques within 0..1")
    ok = isinstance(pts, list) and len(pts) >= 2 and all(
        isinstance(p, list) and len(p) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                    and math.isfinite(x) and 0 <= x <= 1 for x in p) for p in pts)
    if not ok or [float(x) for x in pts[0]] != [0.0, 1.0] or any(b[0] <= a[0] for a, b in zip(pts, pts[1:])):
        sec.fail("curve_points", pts, expected)
    return tuple((float(a), float(b)) for a, b in pts)


ACCELERATION_WINDOW = 0.005  # s: sampled accelerations are averaged over this (the arms' inertia filters faster steps)
BLOCK = 65536  # samples per evaluation of the model (its (N, 3, 3) temporaries: a long 10 kHz print holds millions)


def torque_blocks(printer, q, rate: float, window: float = ACCELERATION_WINDOW, block: int = BLOCK):
    """Torques read back from sampled joints, a block at a time: q (N, J) joint units at ``rate`` Hz
    -> yields (start, tau (n, J) N m or N, qd (n, J) units/s) for rows start..start + n. Velocities
    by central differences; accelerations the second differences averaged over ``window`` s (the
    mean acceleration over the window: a single second difference at 1-10 kHz shows every step
    between the planner's stages, which no arm follows). Each block is differenced with a margin of
    its neighbours' samples, so the blocks give what the whole array would."""
    q = np.asarray(q, dtype=float)
    N = len(q)
    if N < 3:
        zero = np.zeros_like(q)
        yield 0, printer.joint_torques(q, zero, zero), zero
        return
    dt = 1.0 / rate
    n = max(1, int(round(window * rate)))
    box = np.ones(n) / n
    halo = n + 2
    for a in range(0, N, block):
        b = min(N, a + block)
        lo, hi = max(0, a - halo), min(N, b + halo)
        x = q[lo:hi]
        qd = np.gradient(x, dt, axis=0)
        second = np.zeros_like(x)
        second[1:-1] = (x[2:] - 2 * x[1:-1] + x[:-2]) / dt**2
        qdd = np.column_stack([np.convolve(second[:, j], box, mode="same") for j in range(q.shape[1])])
        # np.gradient is one-sided and the second differences zero at the slice's ends: the whole
        # array's ends are those; a block's inner ends fall in the margin, cut off here
        rows = slice(a - lo, b - lo)
        yield a, printer.joint_torques(x[rows], qd[rows], qdd[rows]), qd[rows]


def sampled_torques(printer, q, rate: float, window: float = ACCELERATION_WINDOW, block: int = BLOCK):
    """:func:`torque_blocks` joined: (tau (N, J), qd (N, J))."""
    parts = list(torque_blocks(printer, q, rate, window, block))
    return np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])
