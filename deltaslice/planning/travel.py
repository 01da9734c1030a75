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

import re
from dataclasses import replace

import numpy as np
import ruckig

from ..errors import DeltasliceError, PlanningError
from .pieces import FilamentPiece, JointMovePiece
from .ruckig_profile import RuckigProfile, positions_many
from .batch import plan_lines
from .runpath import RunSpec
from .topp import plan_run
from .context import PlanContext
from .jerk import jerk_limited
from .tolerances import CLEARANCE, DIVISION_FLOOR, FEED_MATCH, NO_MOTION, RETIME
from .torque import travel_limits

CHECK_SAMPLES = 48


def _ruckig_limits(ctx: PlanContext, n: int, slower: float = 1.0) -> tuple:
    """ruckig's velocity, acceleration and jerk limits of the first n joints (lists of floats):
    the planned limits; joints without a jerk limit in the printer file get a stiff default (50 x
    their acceleration per s). slower: the move's time stretched by this factor (>= 1): velocity,
    acceleration and jerk divided by it, its square and its cube, so the move keeps its path."""
    lim = ctx.planned_limits
    acc = lim.acceleration[:n]
    given = np.isfinite(lim.jerk[:n]) & (np.nan_to_num(lim.jerk[:n]) > 0)
    jerk = np.where(given, lim.jerk[:n], 50.0 * acc)
    return (list(map(float, lim.velocity[:n] / slower)), list(map(float, acc / slower**2)),
            list(map(float, jerk / slower**3)))


# ruckig's results by code (its Python enum lacks some): what each means for a travel
_RUCKIG_DURATION, _RUCKIG_ZERO_LIMITS = -101, -104
RUCKIG_MAX_DURATION = 7.6e3  # s: ruckig plans no longer move (its ErrorTrajectoryDuration)


def _ruckig_failure(ctx: PlanContext, layer, code) -> str:
    """The one line for a travel ruckig could not plan, naming the joint limits behind it."""
    lim = ctx.machine_limits
    n = ctx.n_joints
    # the limits as the printer file gives them: degrees for a revolute joint, mm for a prismatic one
    per = np.array([np.degrees(1.0) if k == "revolute" else 1.0 for k in lim.kinds[:n]])
    unit = "deg" if lim.kinds[0] == "revolute" else "mm"
    vel, acc = lim.velocity[:n] * per, lim.acceleration[:n] * per
    limits = (f"[joints] velocity_max = {_g(vel)} {unit}/s, acceleration_max = {_g(acc)} {unit}/s^2"
              f" (printer {ctx.name})")
    if code == _RUCKIG_DURATION:
        return (f"layer {layer}: a travel would last longer than {RUCKIG_MAX_DURATION:g} s (ruckig's bound) at {limits}: "
                "are the limits in the file's units?")
    if code == _RUCKIG_ZERO_LIMITS:
        return f"layer {layer}: a travel cannot be planned with a zero limit: {limits}"
    return f"layer {layer}: ruckig could not plan a travel (its result code {code}) at {limits}"


def _g(values) -> str:
    values = [float(v) for v in values]
    return f"{values[0]:g}" if len(set(values)) == 1 else "[" + ", ".join(f"{v:g}" for v in values) + "]"


class NoTorqueBound(PlanningError):
    """No joint velocity and acceleration bound keeps a joint-space move within the actuators'
    torque (gravity takes it all at one of its poses): the caller plans a straight line instead."""


class _JointMoves:
    """ruckig's calculator, input and output made once for many rest-to-rest moves of one printer
    (a batch of travels): making and filling them took three times ruckig's calculation of a move."""

    def __init__(self, ctx: PlanContext, n: int, slower: float = 1.0):
        vel, acc, jerk = _ruckig_limits(ctx, n, slower)
        self.slower = slower
        self.n = n
        self.otg, self.inp, self.traj = ruckig.Ruckig(n), ruckig.InputParameter(n), ruckig.Trajectory(n)
        inp = self.inp
        inp.current_velocity = inp.current_acceleration = [0.0] * n
        inp.target_velocity = inp.target_acceleration = [0.0] * n
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = vel, acc, jerk
        self.ctx, self.torque = ctx, ctx.dynamics is not None
        if self.torque:
            # the joints in phase: the move stays on its straight joint line, the poses its torque
            # bounds were found at
            inp.synchronization = ruckig.Synchronization.Phase

    def move(self, q0, q1, layer, bounds=None) -> JointMovePiece:
        """The jerk-limited joint-space move from rest at q0 to rest at q1 (a JointMovePiece);
        bounds: (velocity (J,), acceleration (J,)) for this move instead of the joints' planned
        limits (:func:`.torque.travel_limits`; found here for a printer with torque limits when not
        given)."""
        if bounds is None and self.torque:
            vel, acc = travel_limits(self.ctx, q0, q1)
            if not np.isfinite(acc).all():
                raise NoTorqueBound(f"layer {layer}: no joint-space move from {np.round(q0, 4)} to {np.round(q1, 4)} "
                                    "within the actuators' torque (gravity takes it all at one of its poses)")
            bounds = (vel[0], acc[0])
        if bounds is not None:
            self.inp.max_velocity = list(map(float, np.asarray(bounds[0]) / self.slower))
            self.inp.max_acceleration = list(map(float, np.asarray(bounds[1]) / self.slower**2))
        self.inp.current_position = list(map(float, q0))
        self.inp.target_position = list(map(float, q1))
        try:
            result = self.otg.calculate(self.inp, self.traj)
        except ValueError as exc:  # a code the binding's Result enum lacks ("-101 is not a valid Result")
            code = re.match(r"\s*(-?\d+)", str(exc))
            raise PlanningError(_ruckig_failure(self.ctx, layer, int(code.group(1)) if code else None)) from None
        if result not in (ruckig.Result.Working, ruckig.Result.Finished):
            raise PlanningError(_ruckig_failure(self.ctx, layer, int(result.value)))
        profile = RuckigProfile.from_trajectory(self.traj)
        traj = None
        if profile is None:  # the piece keeps ruckig's object, one of its own (this one is reused)
            traj = ruckig.Trajectory(self.n)
            if self.otg.calculate(self.inp, traj) != result:
                raise PlanningError(f"layer {layer}: ruckig planned a travel two ways")
        return JointMovePiece(profile, traj, np.asarray(q0, float), np.asarray(q1, float), layer)


def _ruckig_move(ctx: PlanContext, q0, q1, layer, slower: float = 1.0):
    """The jerk-limited joint-space move from rest at q0 to rest at q1 (a JointMovePiece), alone,
    within the torque limits' bounds for it where the printer has them; slower: see
    :func:`_ruckig_limits`."""
    return _JointMoves(ctx, len(q0), slower).move(q0, q1, layer)


SPEED_SAMPLES = 4096  # a joint move's tool speed measured at this many instants
SPEED_SLACK = 1.02  # and held 2 % under the feed: chords between those instants fall short of the peak


def _within_feed(ctx: PlanContext, q0, q1, feed: float):
    """The jerk-limited joint-space move from q0 to q1 stretched in time so that its tool point
    (forward kinematics) goes no faster than ``feed`` mm/s (the path is the same)."""
    kin = ctx.kin
    joint, slower = _ruckig_move(ctx, q0, q1, layer=0), 1.0
    for _ in range(8):
        t = np.linspace(0.0, joint.duration, SPEED_SAMPLES)
        p = kin.forward(joint.sample(kin, t)[0])
        top = float(np.max(np.linalg.norm(np.diff(p, axis=0), axis=1))) / max(t[1] - t[0], DIVISION_FLOOR)
        if top * SPEED_SLACK <= feed * (1 + FEED_MATCH):
            return joint
        slower *= top * SPEED_SLACK / feed * (1 + RETIME)  # a hair more: the same path, its time rounded
        joint = _ruckig_move(ctx, q0, q1, layer=0, slower=slower)
    raise PlanningError(f"{ctx.name}: a move from or to the rest pose could not be slowed to {feed:g} mm/s")


def joint_move_clear(kin, piece: JointMovePiece, z_min: float) -> bool:
    """True when the move's tool point stays at or above z_min and inside the reachable volume."""
    return bool(joint_moves_clear(kin, [piece], np.array([z_min]))[0])


def joint_moves_clear(kin, pieces, z_min: np.ndarray) -> np.ndarray:
    """:func:`joint_move_clear` of many moves at once (one forward kinematics and one reach check
    of all their samples): (k,) bool. z_min: (k,) mm."""
    if not pieces:
        return np.zeros(0, dtype=bool)
    # the moves with arrays sampled in one pass; ruckig's own (rare) one sample at a time
    has = np.array([p.profile is not None for p in pieces])
    arrays = [p for p, h in zip(pieces, has) if h]
    q = np.empty((len(pieces), CHECK_SAMPLES, kin.n_joints))
    if arrays:
        tau = np.linspace(0.0, [p.duration for p in arrays], CHECK_SAMPLES, axis=1)
        q[has] = positions_many([p.profile for p in arrays], tau)
    for i, p in enumerate(pieces):
        if p.profile is None:
            q[i] = p.sample(kin, np.linspace(0.0, p.duration, CHECK_SAMPLES))[0]
    q = q.reshape(-1, kin.n_joints)
    p = kin.forward(q)
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(p).all(axis=1) & (p[:, 2] >= np.repeat(np.asarray(z_min, float), CHECK_SAMPLES) - CLEARANCE)
    ok[ok] = kin.reachable(p[ok])
    return ok.reshape(len(pieces), CHECK_SAMPLES).all(axis=1)


def plan_travel(ctx: PlanContext, a, b, *, layer, printed_top, retract, unretract, via=None, feed=None):
    """Pieces that take the tool from point a to point b (both (3,) mm, bed frame).

    via: (k,3) the toolpath's own travel points between a and b (the slicer's z-hop, if any);
    feed: the travel's feed rate, mm/s (default: the printer's travel speed).
    printed_top: height of the top of what is printed so far, mm; retract/unretract: filament mm
    (retract <= 0 <= unretract) taken from the toolpath's travel moves.
    """
    job = dict(a=a, b=b, layer=layer, printed_top=printed_top, retract=retract, unretract=unretract, via=via, feed=feed)
    return plan_travels(ctx, [job])[0]


def plan_travels(ctx: PlanContext, jobs) -> list:
    """:func:`plan_travel`'s pieces for many travels (each a dict of its keywords), one list per
    travel, in order. The straight-line moves they are made of are planned a batch at a time
    (:func:`.batch.plan_lines`): first every travel's own move, then the lift and lower moves of
    those whose joint-space candidate is faster and clears the part."""
    if not jobs:
        return []
    kin, tool, lift = ctx.kin, ctx.tool, ctx.travel_lift
    k = len(jobs)
    a = np.array([j["a"] for j in jobs], float).reshape(k, 3)
    b = np.array([j["b"] for j in jobs], float).reshape(k, 3)
    layers = [j["layer"] for j in jobs]
    feeds = [j.get("feed") or ctx.travel_speed for j in jobs]
    retract = np.array([j["retract"] for j in jobs], float)
    # The travel's own length, not the distance between its ends: a travel that leaves and comes
    # back to where it started (a job ending at its start point) still moves. Most travels have no
    # points between their ends: their one step is measured for all at once, and their polyline,
    # a to b (or a alone where it does not move), has no repeated point to drop.
    vias = [j.get("via") for j in jobs]
    step = np.linalg.norm(b - a, axis=1)
    ends = np.stack([a, b], axis=1)
    moving = step > NO_MOTION
    owns = []
    for n, via in enumerate(vias):
        if via is None or len(via) == 0:
            owns.append(ends[n] if moving[n] else ends[n, :1])
            continue
        own = _own_polyline(a[n], b[n], via)
        moving[n] = np.linalg.norm(np.diff(own, axis=0), axis=1).sum() > NO_MOTION
        owns.append(_distinct(own) if moving[n] else own[:1])
    # Candidate 1: the toolpath's own travel (what firmware would run), time-optimal.
    best = _straight(ctx, owns, feeds, layers, distinct=True)
    # Candidate 2: lift, a jerk-limited joint-space move, lower; kept only if it is faster and
    # clears the part (half the lift above the top printed so far).
    top = np.maximum(np.maximum(a[:, 2], b[:, 2]), [j["printed_top"] for j in jobs])
    a_up, b_up = a.copy(), b.copy()
    a_up[:, 2] = np.maximum(a[:, 2], top + lift)
    b_up[:, 2] = np.maximum(b[:, 2], top + lift)
    q = kin.inverse(np.concatenate([a, b, a_up, b_up])).reshape(4, k, -1)
    short = (step < tool.retract_min_travel) & (retract == 0)  # the ends' distance, measured above
    cands = []  # (travel, joint move, its own travel's time)
    joint_moves = _JointMoves(ctx, q.shape[2])
    # A joint-space move's tool speed follows the joints, not a feed: only the machine speed limit takes it.
    tried = np.flatnonzero(moving & ~short & np.isfinite(q[2:]).all(axis=(0, 2)) & (ctx.speed_limit == "machine"))
    # with torque limits, each move's own joint bounds (travel_limits); none: no joint-space candidate
    bounds = travel_limits(ctx, q[2, tried], q[3, tried]) if len(tried) else None
    for r, n in enumerate(tried):
        if bounds is not None and not np.isfinite(bounds[1][r]).all():
            continue
        joint = joint_moves.move(q[2, n], q[3, n], layers[n], None if bounds is None else (bounds[0][r], bounds[1][r]))
        # Every piece lasts >= 0 s: once the candidate is no faster than the toolpath's own
        # travel, its clearance check and its lift and lower moves need not be planned.
        own_time = sum(p.duration for p in best[n])
        if joint.duration < own_time:
            cands.append((n, joint, own_time))
    idx = [n for n, _j, _t in cands]
    clear = joint_moves_clear(kin, [joint for _n, joint, _t in cands], top[idx] + (0.5 * lift if lift > 0 else 0.0))
    cands = [c for c, ok in zip(cands, clear) if ok]
    idx = [n for n, _j, _t in cands]
    # A lift or lower of no height is one point once repeated points are dropped: no move.
    up_down = np.concatenate([np.stack([a[idx], a_up[idx]], axis=1), np.stack([b_up[idx], b[idx]], axis=1)])
    rises = np.linalg.norm(up_down[:, 1] - up_down[:, 0], axis=1) > NO_MOTION
    moves = _straight(ctx, [line if rise else line[:1] for line, rise in zip(up_down, rises)],
                      [feeds[n] for n in idx] * 2, [layers[n] for n in idx] * 2, distinct=True)
    for r, (n, joint, own_time) in enumerate(cands):
        cand = moves[r] + [joint] + moves[len(cands) + r]
        if sum(p.duration for p in cand) < own_time:
            best[n] = cand
    # retracts keep the margin the joints keep: the planned limits of the tool channel
    acc = ctx.retract_acceleration
    out = []
    for n, job in enumerate(jobs):
        pieces = []
        if job["retract"] < 0:
            pieces.append(FilamentPiece(q[0, n], job["retract"], ctx.retract_speed, acc, layers[n]))
        pieces.extend(best[n])
        if job["unretract"] > 0:
            pieces.append(FilamentPiece(q[1, n], job["unretract"], ctx.retract_speed, acc, layers[n]))
        out.append(pieces)
    return out


def _own_polyline(a, b, via) -> np.ndarray:
    """The toolpath's own travel from a through via to b, (m+1, 3) mm."""
    return np.concatenate([a[None], np.empty((0, 3)) if via is None else np.asarray(via, float), b[None]])


def _straight(ctx: PlanContext, polylines, feeds, layers, distinct: bool = False) -> list:
    """The pieces of straight tool-off travels along each polyline ((m+1, 3) mm; one point: no
    move), one list per polyline: the straight lines (two points once repeated points are
    dropped) as one batch, the rest (a slicer's z-hop) each alone. distinct: the polylines have
    no repeated points already."""
    if not distinct:
        polylines = [_distinct(p) for p in polylines]
    out = [[] for _ in polylines]
    lines = [i for i, p in enumerate(polylines) if len(p) == 2]
    if lines:
        planned = plan_lines(ctx, np.array([polylines[i][0] for i in lines]),
                             np.array([polylines[i][1] for i in lines]), np.array([feeds[i] for i in lines], float),
                             np.array([layers[i] for i in lines]))
        for i, pieces in zip(lines, planned):
            out[i] = pieces
    for i, p in enumerate(polylines):
        if len(p) > 2:
            out[i] = _cartesian(ctx, p, layers[i], feed=feeds[i])
    return out


def _distinct(pts) -> np.ndarray:
    """pts without points repeated within NO_MOTION mm of the one before."""
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > NO_MOTION])
    return pts[keep]


def _cartesian(ctx: PlanContext, pts, layer, tolerance=None, feed=None) -> list:
    """A straight Cartesian travel (tool off) planned with toppra."""
    pts = _distinct(pts)
    m = len(pts) - 1
    feed = np.full(m, feed or ctx.travel_speed)
    spec = RunSpec(pts, feed, np.zeros(m), 0.0, layer)
    return plan_run(ctx, spec, tolerance, kind="travel")


def from_rest(ctx: PlanContext, point, *, feed=None) -> list:
    """Pieces from the printer's rest pose onto ``point`` (3,) mm, the job's first working point:
    to the approach point ``[planning] approach_height`` above it (lower where the machine
    cannot reach so high), then vertically down onto it at ``approach_speed`` (whatever the
    speed limit). The move to the approach point never goes below the lower of the rest pose
    and the approach point: a jerk-limited joint-space move (ruckig) where its tool point stays
    so (under the feed speed limit stretched in time so that the tool goes no faster than
    ``feed`` mm/s, default: the printer's travel speed), else a straight line (or two: a
    vertical one at the rest pose, or at the approach point, and a level one) at ``feed``."""
    return _rest_link(ctx, np.asarray(point, float), to_rest=False, top=-np.inf, feed=feed)


def to_rest(ctx: PlanContext, point, *, top=-np.inf, feed=None) -> list:
    """Pieces from ``point`` (3,) mm, the job's last, back to the rest pose: vertically up at
    ``approach_speed`` to ``approach_height`` above the higher of the point and ``top`` (mm, the
    printed part's top), then to the rest pose (the mirror of :func:`from_rest`)."""
    return _rest_link(ctx, np.asarray(point, float), to_rest=True, top=top, feed=feed)


def _approach_point(kin, height: float, point, top) -> np.ndarray:
    """(3,) mm: the point ``height`` (approach_height, mm) above the higher of ``point`` and ``top``, or the
    highest reachable one below it on the vertical through ``point`` (``point`` itself at worst)."""
    clear = max(float(point[2]), float(top)) + height
    heights = np.linspace(clear, point[2], 33)
    cands = np.repeat(point[None], len(heights), axis=0)
    cands[:, 2] = heights
    ok = kin.reachable(cands)
    return cands[int(np.argmax(ok))] if ok.any() else point


def _rest_link(ctx: PlanContext, point, *, to_rest, top, feed):
    """:func:`from_rest` or (to_rest) :func:`to_rest`."""
    kin = ctx.kin
    # the straight links are solved by the compiled solver whatever the plan's
    fast = ctx if ctx.solver == "fast" else replace(ctx, solver="fast")
    q_rest = np.asarray(ctx.rest_pose, float)
    p_rest = kin.forward(q_rest[None])[0]
    above = _approach_point(kin, ctx.approach_height, point, top)
    z_min = min(float(above[2]), float(p_rest[2]))
    link = None
    q_above = kin.inverse(above[None])[0]
    ends = (q_above, q_rest) if to_rest else (q_rest, q_above)
    try:
        joint = _ruckig_move(ctx, *ends, layer=0)
        if joint_move_clear(kin, joint, z_min):
            # the feed speed limit keeps the path and stretches the move in time
            link = [joint if ctx.speed_limit == "machine" else _within_feed(ctx, *ends, feed or ctx.travel_speed)]
    except NoTorqueBound:  # no joint bound holds the torque along its joint line: a straight line instead
        link = None
    if link is None:
        for via in ([], [[p_rest[0], p_rest[1], above[2]]], [[above[0], above[1], p_rest[2]]]):
            pts = np.array([p_rest, *via, above])
            try:
                link = _cartesian(fast, pts[::-1] if to_rest else pts, 0, feed=feed)
                break
            except DeltasliceError:
                continue
        else:
            raise PlanningError(f"{ctx.name}: no straight way from the rest pose to x = {above[0]:.2f}, "
                                f"y = {above[1]:.2f}, z = {above[2]:.2f} mm above the job's "
                                f"{'last' if to_rest else 'first'} point stays within reach")
    if not np.array_equal(above, point):
        pts = np.array([point, above] if to_rest else [above, point])
        vertical = _cartesian(fast.with_speed_limit("feed"), pts, 0, feed=ctx.approach_speed)
        link = vertical + link if to_rest else link + vertical
    return jerk_limited(ctx, link)
