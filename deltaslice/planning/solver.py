"""The speed profile along a blended path (:func:`solve_path`): the constraints on a grid,
solved by the compiled reachability solver or toppra's seidel solver (the reference), checked
stage by stage against the printer's own limits and refined where a stage exceeds one; and one
prepared polyline solved into a RunPiece (:func:`plan_polyline`)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from ..errors import PlanningError
from ..jit import njit
from .constraints import (CHECK, EVAL, EVAL_IN_CHECK, PathVelocityConstraint, StageAccelerationConstraint, _nan_max,
                          gridpoint_speed_factor)
from .pieces import RunPiece
from .reachability import solve as fast_solve
from .runpath import RunPath, RunSpec, _path_inputs, _PathInputs, _Polyline
from .stages import CHECK_TOLERANCE, SHORT_FRACTIONS, grid, stage_maxima
from .context import PlanContext
from .tolerances import ARC_SIDE, SAME_SPEED
from .torque import cruise_x, solve_with_torque, stage_check, stage_torque, torque_columns

logging.getLogger("toppra").setLevel(logging.ERROR)




ACTIVE = 0.95  # a limit counts as active within 5 % of it
REFINE_PASSES = 3  # times a run's violating stages are split before it fails


class _StartTooFast(PlanningError):
    """A window cannot start at the speed the previous one committed; ``speed``: the fastest it can (mm/s)."""

    def __init__(self, speed: float):
        super().__init__(f"start speed above {speed:.6g} mm/s")
        self.speed = speed


@dataclass(frozen=True)
class _Profile:
    """A path's solved speed profile on its final grid. s, x: (n+1,) grid in mm and in path units
    (s / S); sd: (n+1,) path speed x_dot; xdd: (n,) path acceleration per stage; t: (n+1,) time
    at the grid points, s; dt: (n,) stage durations; active: (n,) stages with a limit active (the
    optimality certificate); cut: the grid index of the capped point (or -1)."""

    s: np.ndarray
    x: np.ndarray
    sd: np.ndarray
    xdd: np.ndarray
    t: np.ndarray
    dt: np.ndarray
    active: np.ndarray
    cut: int = -1


def _solve_path(ctx: PlanContext, layer: int, inputs: _PathInputs, v_start: float = 0.0, cap: tuple | None = None,
                conservative: bool = True, units: tuple | None = None) -> _Profile:
    """The time-optimal speed profile along a blended path from path speed v_start (mm/s) to rest,
    refined where the stage-wise check finds a limit exceeded.

    inputs: the path and what the solver needs along it (:class:`.runpath._PathInputs`; the tool
    channel is planned where ``inputs.extruder``); cap: (s, speed) the path speed capped at arc
    length s (a window's cut); conservative: fall back to one constant-acceleration profile when
    the solver finds none (else PlanningError); units: for a path of moves that meet at rest
    (:func:`.batch.plan_lines`), (unit_length, unit_id): (k,) mm, the length of the move each
    piece belongs to (the compiled solver works in each move's own units), and (k,) int, which
    move each piece belongs to, so a stage is refined with its neighbours in its own move only
    (as planning that move alone would). The planner plans to the context's planned limits and
    checks the machine's own; where it has torque limits (and the compiled solver plans), the
    actuators' torque too (:mod:`.torque`)."""
    path, piece_feed, stop_at = inputs.path, inputs.piece_feed, inputs.stop_at
    e_ratio = inputs.e_ratio if inputs.extruder else None
    S = path.length
    tq = ctx.torque if ctx.plans_torque else None
    planned, limits = ctx.planned_limits, ctx.machine_limits
    channels = limits.n_channels if e_ratio is not None else limits.n_joints
    vmax, amax = planned.velocity[:channels], planned.acceleration[:channels]
    true_v, true_a = limits.velocity[:channels], limits.acceleration[:channels]
    s_grid = grid(path, stop_at if cap is None or cap[1] > 0 else None)  # a cut capped to rest may be anywhere
    rp = RunPath(ctx.kin, path, e_ratio, layer)

    def cut_g(grid_s):
        return int(np.argmin(np.abs(grid_s - cap[0])))

    for attempt in range(REFINE_PASSES + 1):
        x_grid = s_grid / S
        x_grid[0], x_grid[-1] = 0.0, 1.0
        # Feed cap at a grid point: the slower of the pieces on its two sides.
        before = path.locate(np.maximum(s_grid - ARC_SIDE, 0.0))
        feed_grid = np.minimum(piece_feed[path.locate(s_grid)], piece_feed[before])
        feed_grid[np.isin(s_grid, stop_at)] = 0.0
        if cap is not None:
            feed_grid[cut_g(s_grid)] = min(feed_grid[cut_g(s_grid)], cap[1])
        dq_check, ddq_check = rp.stage_derivatives(x_grid, CHECK)
        dq_st, ddq_st = dq_check[:, EVAL_IN_CHECK], ddq_check[:, EVAL_IN_CHECK]
        constraints = [
            PathVelocityConstraint(vmax, feed_grid, S, gridpoint_speed_factor(dq_st)),
            StageAccelerationConstraint(amax, EVAL, (dq_st, ddq_st)),
        ]
        unit = None if units is None else S / units[0][path.locate(s_grid)]
        extra = 0 if tq is None else torque_columns(EVAL, ctx.n_joints)
        rows = _fast_rows(constraints, rp, x_grid, amax, unit, extra) if ctx.solver == "fast" else None
        model = x0 = None
        if tq is None:
            sd, top = _speeds(constraints, rp, x_grid, rows, v_start / S, unit)
        else:
            sd, top, model, x0 = _speeds_with_torque(ctx, tq, rp, s_grid, x_grid, (dq_check, ddq_check), rows,
                                                     lambda r: _speeds(constraints, rp, x_grid, r, v_start / S, unit),
                                                     vmax, piece_feed, unit)
        if v_start > 0:
            # A start speed outside the controllable set is refused even when the solver, which
            # tolerates a small excess (toppra's), found a profile: its forward pass would cut the
            # speed where the excess meets a limit, a step of many times the acceleration limit.
            # The previous window re-plans instead.
            fastest = (_start_speed(constraints, rp, x_grid) if top is None else _root(top)) * S
            if v_start > fastest * (1 + SAME_SPEED):
                raise _StartTooFast(fastest)
        if sd is None or not np.all(np.isfinite(sd)):
            # Seidel's 2-D LP occasionally meets a degenerate stage; a conservative profile from
            # the same limits is always feasible (and slower only on this run).
            sd = None if v_start > 0 or not conservative else _conservative_profile(
                x_grid, dq_st, ddq_st, vmax, amax, feed_grid / S)
            if sd is None:
                raise PlanningError(_infeasible(ctx, layer, path, s_grid, 0, vmax, dq_st))
        sd = np.maximum(sd, 0.0)
        dx = np.diff(x_grid)
        vsum = sd[:-1] + sd[1:]
        if not np.all(vsum > 0):
            raise PlanningError(_infeasible(ctx, layer, path, s_grid, int(np.flatnonzero(vsum <= 0)[0]), vmax, dq_st))
        dt = 2 * dx / vsum
        # Constant acceleration per stage consistent with the end speeds.
        xdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2 * dx)
        check = stage_maxima(rp, x_grid, sd, xdd, true_v, true_a, stage=(dq_check, ddq_check))
        bad = check.per_stage > 1.0 + CHECK_TOLERANCE
        torque = None
        if tq is not None:
            torque = stage_check(model, tq, CHECK, sd, xdd, x0)
            bad |= ~(torque.per_stage <= 1.0 + CHECK_TOLERANCE)
        if not bad.any():
            break
        if attempt == REFINE_PASSES:
            raise PlanningError(_still_beyond(ctx, layer, path, s_grid, e_ratio, check, torque))
        s_grid = _refined(s_grid, bad, path, None if units is None else units[1])
    t = np.concatenate([[0.0], np.cumsum(dt)])

    # Which stages have a limit active (the optimality certificate): the speed at its
    # first-order cap, or some joint's acceleration at its limit.
    cap2 = rows[3] if rows is not None else constraints[0].cap2(rp, x_grid)
    active = np.empty(len(xdd), dtype=bool)
    _active_kernel(dq_check, ddq_check, xdd, sd, cap2, amax, active)  # fraction 0 of either; these are contiguous
    if tq is not None:
        active |= torque.per_stage >= ACTIVE * float(np.min(tq.planned / tq.stall))
    return _Profile(s_grid, x_grid, sd, xdd, t, dt, active, -1 if cap is None else cut_g(s_grid))


def _speeds_with_torque(ctx: PlanContext, tq, rp, s_grid, x_grid, check_derivatives, rows, speeds, vmax, piece_feed,
                        unit):
    """:func:`_speeds` with the actuators' torque rows (:func:`.torque.solve_with_torque`): (path
    speeds, top of the start's controllable set, the stages' torque model, its tangent points)."""
    dq_check, ddq_check = check_derivatives
    path, S = rp.path, rp.S
    # at the check's fractions: at the solver's three alone, the check's bound (their second
    # difference) refines more stages and batches, for more time than the two others cost
    model = stage_torque(ctx.dynamics, rp, x_grid, CHECK, dq_check, ddq_check)
    # every grid from the same first tangents (not the last grid's solution): a run refined in
    # a batch leaves the others' stages as they are alone
    mid_s = 0.5 * (s_grid[:-1] + s_grid[1:])
    x0, floor = cruise_x(model, tq, vmax[: ctx.n_joints], (piece_feed[path.locate(mid_s)] / S) ** 2, len(CHECK) // 2)
    sd, top, x0 = solve_with_torque(model, tq, x_grid, rows, EVAL_IN_CHECK, EVAL, x0, floor, speeds, unit)
    return sd, top, model, x0


def _still_beyond(ctx: PlanContext, layer: int, path, s_grid, e_ratio, check, torque) -> str:
    """The message for a path still beyond a limit after every refinement: the torque where an
    actuator exceeds its curve, else the channel and kind of limit with the largest excess."""
    if torque is not None and np.max(torque.use) > 1.0 + CHECK_TOLERANCE:
        j = int(np.argmax(torque.use))
        p = path.evaluate(np.array([s_grid[int(torque.stage[j])]]))[0]
        return (f"layer {layer}: {_describe(ctx, j)} uses {100 * torque.use[j]:.2f} % of its torque (speed-torque "
                f"line) between grid points at x = {p[0]:.2f}, y = {p[1]:.2f}, z = {p[2]:.2f} mm after "
                f"{REFINE_PASSES} grid refinements")
    ch = int(np.argmax(np.maximum(check.velocity, check.acceleration)))
    kind = "velocity" if check.velocity[ch] >= check.acceleration[ch] else "acceleration"
    st = int(check.stage_v[ch] if kind == "velocity" else check.stage_a[ch])
    return (f"layer {layer}: {_describe(ctx, ch)} {kind} reaches "
            f"{100 * max(check.velocity[ch], check.acceleration[ch]):.2f} % of its limit "
            f"{_stage_place(path, s_grid, st, e_ratio if ch == ctx.n_joints else None)} "
            f"after {REFINE_PASSES} grid refinements")


def _refined(s_grid: np.ndarray, bad: np.ndarray, path, unit_id) -> np.ndarray:
    """The grid (mm) with the offending stages ``bad`` (n,) and their neighbours split in four;
    unit_id: see :func:`_solve_path`'s units (a neighbour in another unit is left as it is)."""
    idx = np.flatnonzero(bad)
    near = np.clip(np.concatenate([idx - 1, idx, idx + 1]), 0, len(s_grid) - 2)
    if unit_id is not None:
        owner = unit_id[path.locate(0.5 * (s_grid[:-1] + s_grid[1:]))]
        near = near[owner[near] == np.tile(owner[idx], 3)]
    idx = np.unique(near)
    extra = (s_grid[idx, None] + np.diff(s_grid)[idx, None] * SHORT_FRACTIONS[None]).ravel()
    return np.unique(np.concatenate([s_grid, extra]))


def _conservative_profile(x, dq_stage, ddq_stage, vmax, amax, xd_cap):
    """Path speeds (n+1,) at the grid x for one constant path acceleration A and speed cap V
    that satisfy every limit at every evaluated point of every stage whatever the signs:
    |q'| V <= vmax and |q'| A + |q''| V^2 <= amax. Returns None when no positive speed is
    possible."""
    # |q' + 2 f d q''| <= |q'| + 2 d |q''| over the stage
    d1 = np.abs(dq_stage).max(axis=1) + 2 * np.diff(x)[:, None] * np.abs(ddq_stage).max(axis=1)
    d2 = np.abs(ddq_stage).max(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        v = min(float(np.min(vmax[None] / np.abs(dq_stage).max(axis=1))), float(np.min(xd_cap)))
        v = min(v, float(np.sqrt(0.5 * np.min(amax[None] / d2))))
        a = float(np.min((amax[None] - d2 * v * v) / d1))
    if not (v > 0 and a > 0 and np.isfinite(v) and np.isfinite(a)):
        return None
    return np.minimum(v, np.sqrt(2 * a * np.minimum(x, 1.0 - x).clip(0)))


@njit
def _active_kernel(dq, ddq, xdd, sd, cap2, amax, out):
    """Whether each stage i has a limit active (out (n,) bool): its squared path speed at either
    end within ACTIVE of cap2 there, or some channel's acceleration |q' u + q'' x_dot^2| at its
    start (dq, ddq: (n, f, dof), fraction 0 first) within ACTIVE of amax (False where any channel's
    is NaN, as numpy's max over the channels)."""
    n, _f, dof = dq.shape
    for i in range(n):
        v0 = sd[i] * sd[i]
        on = v0 >= ACTIVE * cap2[i] or sd[i + 1] * sd[i + 1] >= ACTIVE * cap2[i + 1]
        top = -np.inf
        for j in range(dof):
            r = abs(dq[i, 0, j] * xdd[i] + ddq[i, 0, j] * v0) / amax[j]
            top = _nan_max(top, r)
        out[i] = on or top >= ACTIVE


def _fast_rows(constraints, rp, x_grid, amax, unit=None, extra=0):
    """What the compiled solver takes, computed once per grid: (a, b, bound, cap2), the
    acceleration rows a u + b x in [-bound, bound] and the bound on x_dot^2 (see _speeds); with
    ``unit`` (see _speeds) the rows in each move's own units, cap2 in the path's. extra: a and b
    that many columns wider, unset (the torque rows': :func:`.torque.solve_with_torque`)."""
    # The filament's rows, the same at every fraction, once: the solver's result is the same
    # (identical bounds), its pairing of bounds much cheaper (identical lines all survive pruning).
    once = rp.e_ratio is not None
    a, b = constraints[1].rows(rp, x_grid, unit, once, extra)
    return a, b, amax[constraints[1].channels(once)], constraints[0].cap2(rp, x_grid)


def _start_speed(constraints, rp, x_grid) -> float:
    """The fastest path speed x_dot the run can start at and still stop at its end, by toppra's
    controllable sets (the compiled solver gives it with its profile, _speeds)."""
    K = _toppra(constraints, rp, x_grid).compute_controllable_sets(0.0, 0.0)
    return _root(K[0, 1])


def _root(top: float) -> float:
    """The path speed of the top of a controllable set (x = x_dot^2), 0 where there is none."""
    return float(np.sqrt(top)) if np.isfinite(top) and top > 0 else 0.0


def _speeds(constraints, rp, x_grid, rows, sd_start=0.0, unit=None):
    """(path speeds x_dot (n+1,) on the grid from sd_start to rest under the path-velocity cap and
    the stage-wise acceleration rows, or None where the solver finds no profile; the top of the
    start's controllable set, x_dot^2, or None when the solver does not give it). "fast": the
    compiled reachability solver on the same rows (collocation: each stage's rows in its
    start's (u, x); ``rows``: :func:`_fast_rows` with the same ``unit``); rows None: toppra's seidel
    solver, the reference.
    unit: (n+1,) for the compiled solver, the scale c = S / L from the path's units to those of the
    move each grid point's stage belongs to (a batch of moves, each of length L, that meet at rest:
    :func:`plan_lines`), or None."""
    if rows is not None:
        a, b, bound, cap2 = rows
        lo, hi = bound if isinstance(bound, tuple) else (-bound, bound)  # (lo, hi) per grid point: torque rows
        ds = np.diff(x_grid)
        if unit is not None:
            # Each stage in its own move's units (x' = c^2 x, u' = c u): what solving the move alone
            # computes, toppra's shrink of the forward pass included (it is a constant in x). The
            # rows came in those units (_fast_rows).
            cap2, ds = cap2 * unit**2, ds * unit[:-1]
        x, _u, K = fast_solve(a, b, lo, hi, cap2, ds, x_start=sd_start**2, interpolation=False)
        top = float(K[0, 1])
        if unit is not None:
            x, top = x / unit**2, top / unit[0] ** 2
        return (np.sqrt(np.maximum(x, 0.0)) if np.all(np.isfinite(x)) else None), top
    return _toppra(constraints, rp, x_grid).compute_parameterization(sd_start, 0.0)[1], None


def _toppra(constraints, rp, x_grid):
    """toppra's TOPPRA (seidel solver) on our constraints, each seen through a toppra
    ``LinearConstraint``. toppra is imported here, not with the module: it brings matplotlib and
    scipy.interpolate (about a second per process) and only the reference solver needs it."""
    import toppra.algorithm
    from toppra.constraint.linear_constraint import LinearConstraint

    class View(LinearConstraint):
        def __init__(self, inner):
            super().__init__()
            self.inner, self.identical = inner, inner.identical

        def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
            return self.inner.compute_constraint_params(path, gridpoints)

    return toppra.algorithm.TOPPRA([View(c) for c in constraints], rp, gridpoints=x_grid, solver_wrapper="seidel")


def _describe(ctx: PlanContext, channel: int) -> str:
    """The channel's name, for a message."""
    return ctx.machine_limits.names[channel]


def _stage_place(path, s_grid, st: int, e_ratio=None) -> str:
    """Where a stage of the grid is, for a message. A stage of a straight stretch can span several
    moves (its start was the run's first corner, far from the move at fault): for the filament,
    the join inside it where the extrusion rate jumps most, with that rate; else both its ends."""
    s0, s1 = float(s_grid[st]), float(s_grid[min(st + 1, len(s_grid) - 1)])
    if e_ratio is not None and len(e_ratio):
        first, last = (int(k) for k in path.locate(np.array([s0, s1])))
        ratio = np.asarray(e_ratio, float)
        ks = np.arange(first, last + 1)
        before = np.where(ks > 0, ratio[np.maximum(ks - 1, 0)], 0.0)
        k = int(ks[np.argmax(np.abs(ratio[ks] - before))])
        p = path.evaluate(np.array([path.piece_start[k]]), piece=np.array([k]))[0]
        return (f"where the extrusion becomes {ratio[k]:.4g} mm of filament per mm of path, at x = {p[0]:.2f}, "
                f"y = {p[1]:.2f}, z = {p[2]:.2f} mm")
    p0, p1 = path.evaluate(np.array([s0, s1]))
    return (f"between x = {p0[0]:.2f}, y = {p0[1]:.2f}, z = {p0[2]:.2f} mm and x = {p1[0]:.2f}, y = {p1[1]:.2f}, "
            f"z = {p1[2]:.2f} mm")


def _infeasible(ctx: PlanContext, layer, path, s_grid, i, vmax, dq_st) -> str:
    """Why the path speed is zero on the stage from grid point i: a forced stop with no room
    on either side, or the limit with the smallest speed cap there."""
    p = path.evaluate(np.array([s_grid[min(i, len(s_grid) - 1)]]))[0]
    where = f"x = {p[0]:.2f}, y = {p[1]:.2f}, z = {p[2]:.2f} mm"
    f = gridpoint_speed_factor(dq_st)[min(i, len(s_grid) - 1)]
    with np.errstate(divide="ignore"):
        cap = vmax / f
    ch = int(np.argmin(cap))
    return (
        f"layer {layer}: no feasible speed along the run near {where}: "
        f"{_describe(ctx, ch)} velocity limit {vmax[ch]:.4g} allows {cap[ch] * path.length:.3g} mm/s of path there"
    )


def _plan_polyline(ctx: PlanContext, spec: RunSpec, poly: _Polyline, tol: float, kind: str, v_start: float = 0.0,
                   cap: tuple | None = None):
    """One RunPiece along a polyline from the path speed v_start (mm/s) to rest; with
    ``cap = (vertex, speed)`` the path speed at that vertex is capped (mm/s) and the piece is
    cut there (the part after it was only the lookahead). Returns (piece, speed at its end)."""
    inputs = _path_inputs(poly, tol, ctx.speed_limit)
    path, e_ratio, cum_e = inputs.path, inputs.e_ratio, inputs.cum_e
    feed = poly.feed
    s_cut = None if cap is None else float(path.piece_start[np.searchsorted(path.segment, cap[0])])
    sol = _solve_path(ctx, spec.layer, inputs, v_start=v_start, cap=None if cap is None else (s_cut, cap[1]))
    S, x_grid, sd, xdd, t, dt, active = path.length, sol.x, sol.sd, sol.xdd, sol.t, sol.dt, sol.active
    power = nominal = None
    if poly.power is not None:
        power = poly.power[path.segment]
        nominal = feed[path.segment]
    if cap is not None:
        # Keep the window up to its cut; what follows was the lookahead.
        stop = int(np.searchsorted(path.segment, cap[0]))
        g = sol.cut
        path = path.head(stop)
        scale = S / path.length
        S = path.length
        x_grid, sd, xdd, t = x_grid[: g + 1] * scale, sd[: g + 1] * scale, xdd[:g] * scale, t[: g + 1]
        x_grid[-1] = 1.0
        cum_e, e_ratio, active = cum_e[: stop + 1], e_ratio[:stop], active[:g]
        dt = dt[:g]
        power = None if power is None else power[:stop]
        nominal = None if nominal is None else nominal[:stop]
    q_ends = RunPath(ctx.kin, path, None, spec.layer)(np.array([0.0, 1.0]))
    piece = RunPiece(path, S, x_grid, sd, xdd, t, cum_e, e_ratio, spec.tool, spec.layer, float(dt[active].sum()), kind,
                     q_ends[0], q_ends[1], power=power, nominal_feed=nominal, dynamic_power=spec.dynamic_power)
    return piece, float(sd[-1] * S)
