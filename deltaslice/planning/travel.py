"""Travels between runs: retract, lift, a jerk-limited joint-space move (ruckig),
lower, unretract.

A joint-space move is a curve in Cartesian space: forward kinematics of its
samples must stay above the printed part (half the lift above the current layer
top, never below the work surface for a laser) and inside the reachable volume.
The toolpath's own travel (straight, with the slicer's z-hop if it has one, as
firmware would run it) is always planned too, with toppra; the faster of the
two is used.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import ruckig

from ..errors import PlanningError
from .ruckig_profile import RuckigProfile
from .topp import RunPiece, RunSpec, plan_run

CHECK_SAMPLES = 48


@dataclass
class JointMovePiece:
    """A ruckig joint-space move from rest to rest, as its phases (:mod:`.ruckig_profile`);
    ``traj`` (the ruckig object, not picklable) only where the phases are not exposed."""

    profile: RuckigProfile | None
    traj: object
    q0: np.ndarray
    q1: np.ndarray
    layer: int
    kind: str = "travel"
    tool: float = 0.0

    @property
    def duration(self) -> float:
        return float(self.profile.duration if self.profile is not None else self.traj.duration)

    @property
    def active_time(self) -> float:
        # A time-optimal jerk-limited profile has the jerk, acceleration or velocity of its
        # limiting joint at a bound at every instant.
        return self.duration

    def sample(self, kin, tau):
        tau = np.clip(np.asarray(tau, dtype=float), 0.0, self.duration)
        if self.profile is not None:
            q = self.profile.positions(tau)
        else:
            q = np.array([self.traj.at_time(float(t))[0] for t in tau]).reshape(len(tau), -1)
        return q, np.zeros(len(tau)), np.zeros(len(tau))

    @property
    def filament_total(self) -> float:
        return 0.0


@dataclass(frozen=True)
class FilamentPiece:
    """Retract or unretract at rest: a trapezoidal filament move of ``amount`` mm."""

    q: np.ndarray
    amount: float
    v: float
    a: float
    layer: int
    kind: str = "retract"
    tool: float = 0.0

    @property
    def active_time(self) -> float:
        return self.duration  # trapezoid: always at the acceleration or speed bound

    @property
    def _profile(self):
        d = abs(self.amount)
        t_acc = self.v / self.a
        if self.a * t_acc**2 >= d:  # triangular
            t_acc = np.sqrt(d / self.a)
            return t_acc, 0.0, self.a * t_acc
        return t_acc, (d - self.a * t_acc**2) / self.v, self.v

    @property
    def duration(self) -> float:
        if self.amount == 0:
            return 0.0
        ta, tc, _ = self._profile
        return 2 * ta + tc

    def sample(self, kin, tau):
        tau = np.clip(np.asarray(tau, dtype=float), 0.0, self.duration)
        ta, tc, vp = self._profile
        a = vp / ta if ta > 0 else 0.0
        d1 = 0.5 * a * ta * ta
        pos = np.where(
            tau < ta,
            0.5 * a * tau**2,
            np.where(tau < ta + tc, d1 + vp * (tau - ta), 2 * d1 + vp * tc - 0.5 * a * (2 * ta + tc - tau) ** 2),
        )
        return np.broadcast_to(self.q, (len(tau), len(self.q))).copy(), np.sign(self.amount) * pos, np.zeros(len(tau))

    @property
    def filament_total(self) -> float:
        return float(self.amount)


def _ruckig_move(printer, q0, q1, layer):
    n = len(q0)
    otg = ruckig.Ruckig(n)
    inp = ruckig.InputParameter(n)
    margin = 1.0 - printer.planning.limit_margin
    acc = printer.joint_array("acceleration_max") * margin
    jerk = np.array([j.jerk_max if j.jerk_max else 50.0 * j.acceleration_max for j in printer.joints]) * margin
    inp.current_position = list(map(float, q0))
    inp.target_position = list(map(float, q1))
    inp.current_velocity = [0.0] * n
    inp.current_acceleration = [0.0] * n
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = list(map(float, printer.joint_array("velocity_max") * margin))
    inp.max_acceleration = list(map(float, acc))
    inp.max_jerk = list(map(float, jerk))
    traj = ruckig.Trajectory(n)
    result = otg.calculate(inp, traj)
    if result not in (ruckig.Result.Working, ruckig.Result.Finished):
        raise PlanningError(f"layer {layer}: ruckig could not plan a travel ({result})")
    profile = RuckigProfile.from_trajectory(traj)
    return JointMovePiece(profile, None if profile is not None else traj, np.asarray(q0, float), np.asarray(q1, float), layer)


def joint_move_clear(kin, piece: JointMovePiece, z_min: float) -> bool:
    """True when the move's tool point stays at or above z_min and inside the reachable volume."""
    tau = np.linspace(0.0, piece.duration, CHECK_SAMPLES)
    q, _, _ = piece.sample(kin, tau)
    p = kin.forward(q)
    ok = np.all(np.isfinite(p)) and np.all(p[:, 2] >= z_min - 1e-6)
    return bool(ok and kin.reachable(p).all())


def plan_travel(kin, printer, a, b, *, layer, printed_top, retract, unretract, speed_limit, via=None, feed=None, solver="fast"):
    """Pieces that take the tool from point a to point b (both (3,) mm, bed frame).

    via: (k,3) the toolpath's own travel points between a and b (the slicer's z-hop, if any);
    feed: the travel's feed rate, mm/s (default: the printer's travel speed).
    printed_top: height of the top of what is printed so far, mm; retract/unretract: filament mm
    (retract <= 0 <= unretract) taken from the toolpath's travel moves.
    """
    pieces = []
    q_a = kin.inverse(a[None])[0]
    q_b = kin.inverse(b[None])[0]
    extruder = not printer.is_laser
    if extruder and retract < 0:
        pieces.append(FilamentPiece(q_a, retract, printer.tool.retract_speed, printer.tool.max_filament_acceleration, layer))
    dist = float(np.linalg.norm(b - a))
    if dist > 1e-9:
        lift = printer.planning.travel_lift if extruder else printer.tool.travel_height
        short = extruder and dist < printer.tool.retract_min_travel and retract == 0
        top = max(a[2], b[2], printed_top)
        z_travel = top + (0.0 if short else lift)
        a_up = np.array([a[0], a[1], max(a[2], z_travel)])
        b_up = np.array([b[0], b[1], max(b[2], z_travel)])
        z_clear = top + (0.5 * lift if lift > 0 else 0.0) if not short else min(a[2], b[2])
        # Candidate 1: the toolpath's own travel (what firmware would run), time-optimal.
        own = np.concatenate([a[None], np.empty((0, 3)) if via is None else np.asarray(via, float), b[None]])
        cartesian = _cartesian(kin, printer, own, layer, speed_limit, feed=feed, solver=solver)
        best = cartesian
        # Candidate 2: lift, a jerk-limited joint-space move, lower; kept only if it clears the part.
        if not short:
            q_up_a, q_up_b = kin.inverse(a_up[None])[0], kin.inverse(b_up[None])[0]
            if np.all(np.isfinite(q_up_a)) and np.all(np.isfinite(q_up_b)):
                joint = _ruckig_move(printer, q_up_a, q_up_b, layer)
                # Every piece lasts >= 0 s: once the candidate is no faster than the toolpath's own
                # travel, its clearance check and its lift and lower moves need not be planned.
                own_time = sum(p.duration for p in cartesian)
                if joint.duration < own_time and joint_move_clear(kin, joint, z_clear):
                    cand = [joint]
                    if a_up[2] > a[2] + 1e-9:
                        cand = _cartesian(kin, printer, np.array([a, a_up]), layer, speed_limit, feed=feed, solver=solver) + cand
                    if b_up[2] > b[2] + 1e-9 and sum(p.duration for p in cand) < own_time:
                        cand = cand + _cartesian(kin, printer, np.array([b_up, b]), layer, speed_limit, feed=feed, solver=solver)
                    if sum(p.duration for p in cand) < own_time:
                        best = cand
        pieces.extend(best)
    if extruder and unretract > 0:
        pieces.append(FilamentPiece(q_b, unretract, printer.tool.retract_speed, printer.tool.max_filament_acceleration, layer))
    return pieces


def _cartesian(kin, printer, pts, layer, speed_limit, tolerance=None, feed=None, solver="fast") -> list:
    """A straight Cartesian travel (tool off) planned with toppra."""
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    pts = pts[keep]
    m = len(pts) - 1
    feed = np.full(m, feed or printer.slicing.travel_speed)
    spec = RunSpec(pts, feed, np.zeros(m), 0.0, layer)
    res = plan_run(kin, printer, spec, speed_limit, tolerance, solver)
    parts = res if isinstance(res, list) else [res]
    return [RunPiece(**{**p.__dict__, "kind": "travel"}) for p in parts]
