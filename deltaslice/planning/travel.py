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

import numpy as np
import ruckig

from ..errors import PlanningError
from .pieces import FilamentPiece, JointMovePiece
from .ruckig_profile import RuckigProfile
from .topp import RunSpec, plan_run

CHECK_SAMPLES = 48


def _ruckig_move(printer, q0, q1, layer):
    n = len(q0)
    otg = ruckig.Ruckig(n)
    inp = ruckig.InputParameter(n)
    lim = printer.planned_limits()
    acc = lim.acceleration[:n]
    # Joints without a jerk limit in the printer file get a stiff default (50 x their acceleration per s).
    given = np.isfinite(lim.jerk[:n]) & (np.nan_to_num(lim.jerk[:n]) > 0)
    jerk = np.where(given, lim.jerk[:n], 50.0 * acc)
    inp.current_position = list(map(float, q0))
    inp.target_position = list(map(float, q1))
    inp.current_velocity = [0.0] * n
    inp.current_acceleration = [0.0] * n
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = list(map(float, lim.velocity[:n]))
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


def plan_travel(kin, printer, a, b, *, layer, printed_top, retract, unretract, speed_limit, via=None, feed=None,
                solver="fast"):
    """Pieces that take the tool from point a to point b (both (3,) mm, bed frame).

    via: (k,3) the toolpath's own travel points between a and b (the slicer's z-hop, if any);
    feed: the travel's feed rate, mm/s (default: the printer's travel speed).
    printed_top: height of the top of what is printed so far, mm; retract/unretract: filament mm
    (retract <= 0 <= unretract) taken from the toolpath's travel moves.
    """
    pieces = []
    q_a = kin.inverse(a[None])[0]
    q_b = kin.inverse(b[None])[0]
    tool = printer.tool
    if retract < 0:
        pieces.append(FilamentPiece(q_a, retract, tool.retract_speed, float(printer.limits.acceleration[-1]), layer))
    dist = float(np.linalg.norm(b - a))
    own = np.concatenate([a[None], np.empty((0, 3)) if via is None else np.asarray(via, float), b[None]])
    # The travel's own length, not the distance between its ends: a travel that leaves and
    # comes back to where it started (a job ending at its start point) still moves.
    if np.linalg.norm(np.diff(own, axis=0), axis=1).sum() > 1e-9:
        lift = tool.travel_lift(printer.planning)
        short = dist < tool.retract_min_travel and retract == 0
        top = max(a[2], b[2], printed_top)
        z_travel = top + (0.0 if short else lift)
        a_up = np.array([a[0], a[1], max(a[2], z_travel)])
        b_up = np.array([b[0], b[1], max(b[2], z_travel)])
        z_clear = top + (0.5 * lift if lift > 0 else 0.0) if not short else min(a[2], b[2])
        # Candidate 1: the toolpath's own travel (what firmware would run), time-optimal.
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
    if unretract > 0:
        pieces.append(FilamentPiece(q_b, unretract, tool.retract_speed, float(printer.limits.acceleration[-1]), layer))
    return pieces


def _cartesian(kin, printer, pts, layer, speed_limit, tolerance=None, feed=None, solver="fast") -> list:
    """A straight Cartesian travel (tool off) planned with toppra."""
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    pts = pts[keep]
    m = len(pts) - 1
    feed = np.full(m, feed or printer.slicing.travel_speed)
    spec = RunSpec(pts, feed, np.zeros(m), 0.0, layer)
    return plan_run(kin, printer, spec, speed_limit, tolerance, kind="travel", solver=solver)


def from_rest(kin, printer, point, speed_limit) -> list:
    """Pieces from the printer's rest pose to ``point`` (3,) mm: a jerk-limited joint-space move
    (ruckig) to the point lifted by the tool's travel lift, then straight down. Where the
    joint-space move would leave the reachable volume or dip under the bed, a straight move."""
    return _rest_link(kin, printer, np.asarray(point, float), speed_limit, to_rest=False)


def to_rest(kin, printer, point, speed_limit) -> list:
    """Pieces from ``point`` (3,) mm back to the rest pose: straight up by the travel lift, then
    the joint-space move (the mirror of :func:`from_rest`)."""
    return _rest_link(kin, printer, np.asarray(point, float), speed_limit, to_rest=True)


def _rest_link(kin, printer, point, speed_limit, *, to_rest):
    q_rest = np.asarray(printer.rest_pose, float)
    p_rest = kin.forward(q_rest[None])[0]
    lift = printer.tool.travel_lift(printer.planning)
    above = np.array([point[0], point[1], point[2] + lift])
    if lift <= 0 or not kin.reachable(above[None])[0]:
        above = point
    q_above = kin.inverse(above[None])[0]
    ends = (q_above, q_rest) if to_rest else (q_rest, q_above)
    joint = _ruckig_move(printer, *ends, layer=0)
    if joint_move_clear(kin, joint, min(0.0, point[2])):
        link = [joint]
    else:
        pts = np.array([above, p_rest] if to_rest else [p_rest, above])
        link = _cartesian(kin, printer, pts, 0, speed_limit)
    if np.array_equal(above, point):
        return link
    vertical = _cartesian(kin, printer, np.array([point, above] if to_rest else [above, point]), 0, speed_limit)
    return vertical + link if to_rest else link + vertical
