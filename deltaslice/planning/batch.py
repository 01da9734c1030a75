"""Many short runs or straight travels solved as one path (:func:`plan_runs`, :func:`plan_lines`):
a run of a few dozen segments spends most of its time in a solve's per-problem set-up, not in
the kernels; each unit's profile is what solving it alone gives, to rounding."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..errors import DeltasliceError, PlanningError
from ..jit import njit
from .blend import DEDUPE_EPS, BlendedPath, dedupe
from .pieces import RunPiece
from .context import PlanContext
from .runpath import RunSpec, _path_inputs_many, _PathInputs
from .solver import _solve_path
from .topp import _prepare, plan_run
from .windows import is_long


def plan_lines(ctx: PlanContext, starts: np.ndarray, ends: np.ndarray, feed: np.ndarray, layers: np.ndarray,
               kind: str = "travel") -> list:
    """Many straight tool-off moves, each from rest to rest: what ``plan_run`` returns for each
    (a list of pieces per move, empty for a move shorter than dedupe's micron), solved as one path.

    starts, ends: (k, 3) float, mm; feed: (k,) mm/s; layers: (k,) int. The moves' lines are laid
    end to end in arc length as the pieces of one path, each join a forced stop, so one grid, one
    set of derivatives, one solve and one stage-wise check serve them all (a travel alone is
    about a millisecond of per-problem set-up for twenty stages); each move's RunPiece is then its
    stretch of the solution in its own path units. The grid around a join is what each move's own
    grid has at its ends, so the profiles match planning each alone (to rounding, and to the odd
    extra refinement a neighbour's check adds). Where the joint solve fails (a move out of
    reach, a limit the refinements cannot meet) every move is planned alone, which raises
    the error that move's own plan raises. toppra's solver (the reference) plans each alone."""
    starts, ends = np.asarray(starts, float).reshape(-1, 3), np.asarray(ends, float).reshape(-1, 3)
    feed, layers = np.asarray(feed, float).reshape(-1), np.asarray(layers).reshape(-1)
    length = np.linalg.norm(ends - starts, axis=1)
    out = [[] for _ in range(len(starts))]
    moving = np.flatnonzero(length > DEDUPE_EPS)  # shorter: dedupe leaves one point, and no filament moves
    if len(moving) == 0:
        return out

    def alone(i):
        spec = RunSpec(np.array([starts[i], ends[i]]), feed[i : i + 1], np.zeros(1), 0.0, int(layers[i]))
        return plan_run(ctx, spec, kind=kind)

    if ctx.solver != "fast" or len(moving) == 1:
        for i in moving:
            out[i] = alone(i)
        return out
    a, L = starts[moving], length[moving]
    d = (ends[moving] - a) / L[:, None]
    k = len(moving)
    piece_start = np.concatenate([[0.0], np.cumsum(L)])
    path = BlendedPath(piece_start, np.zeros(k, dtype=np.int8), a, d, np.zeros((k, 3)), np.full(k, np.inf), np.arange(k))
    piece_feed = feed[moving] if ctx.speed_limit == "feed" else np.full(k, np.inf)
    try:
        inputs = _PathInputs(path, np.zeros(k), np.zeros(k + 1), False, piece_feed, np.zeros(0))
        profiles = _solve_units(ctx, int(layers[moving[0]]), inputs, L, np.arange(k))
    except DeltasliceError:
        for i in moving:
            out[i] = alone(i)
        return out
    q = ctx.kin.inverse(np.concatenate([a, a + L[:, None] * d]))
    for r, (i, (x, xd, xdd, t, active_time)) in enumerate(zip(moving, profiles)):
        line = BlendedPath(np.array([0.0, L[r]]), path.kind[r : r + 1], a[r : r + 1], d[r : r + 1], path.normal[r : r + 1],
                           path.radius[r : r + 1], np.zeros(1, dtype=path.segment.dtype))
        out[i] = [RunPiece(line, float(L[r]), x, xd, xdd, t, np.zeros(2), np.zeros(1), 0.0, int(layers[i]), active_time,
                           kind, q[r], q[k + r])]
    return out


def _solve_units(ctx: PlanContext, layer: int, inputs: _PathInputs, lengths: np.ndarray, unit_of_piece: np.ndarray
                 ) -> list:
    """Units (moves or runs) that each go from rest to rest, laid end to end as the pieces of one
    path (``path.piece_start`` at unit r's start: the sum of ``lengths`` (u,) mm before it), solved
    as one: one grid, one set of derivatives, one solve and one stage-wise check serve them all,
    each stage in its own unit's path units and refined with its neighbours in its own unit only,
    so every unit's profile is what solving it alone gives, to rounding. unit_of_piece (k,) int;
    stop_at: stops inside the units (the joins are stops already). Returns per unit
    (x, xd, xdd, t, active_time) in its own path units (x = s / its length). Raises a
    DeltasliceError where the joint solve fails or a unit's end is not a grid point: the caller
    then plans each unit alone."""
    offsets = np.concatenate([[0.0], np.cumsum(lengths)])
    path = inputs.path
    stops = replace(inputs, stop_at=np.concatenate([offsets[1:-1], inputs.stop_at]))
    sol = _solve_path(ctx, layer, stops, conservative=False, units=(lengths[unit_of_piece], unit_of_piece))
    at = np.searchsorted(sol.s, offsets)
    if not np.array_equal(sol.s[np.minimum(at, len(sol.s) - 1)], offsets):
        raise PlanningError("a unit's end is not a grid point")
    at = at.astype(np.int64)
    n_stages = int(at[-1])
    x, xd, t = np.empty(n_stages + len(lengths)), np.empty(n_stages + len(lengths)), np.empty(n_stages + len(lengths))
    xdd, active = np.empty(n_stages), np.empty(len(lengths))
    _unit_profiles(sol.s, sol.sd, sol.xdd, sol.dt, sol.active, at, np.ascontiguousarray(lengths, dtype=np.float64),
                   float(path.length), x, xd, xdd, t, active)
    # each unit's arrays are views of the units' laid end to end (unit r's points from at[r] + r)
    ends = (at + np.arange(len(at))).tolist()
    at, active = at.tolist(), active.tolist()
    return [(x[ends[r] : ends[r + 1]], xd[ends[r] : ends[r + 1]], xdd[at[r] : at[r + 1]],
             t[ends[r] : ends[r + 1]], active[r]) for r in range(len(active))]


@njit
def _unit_profiles(s, sd, xdd, dt, active, at, lengths, path_length, x_out, xd_out, xdd_out, t_out, active_out):
    """:func:`_solve_units`' per-unit profiles in one pass: unit r (grid points at[r]..at[r + 1] of
    the solution s, sd (n+1,), stages at[r]..at[r + 1]-1 of xdd, dt, active (n,)) in its own path
    units, its points at at[r] + r.. of x_out, xd_out, t_out and its stages at at[r].. of xdd_out:
    x = (s - its start) / its length (0 and 1 at its ends), sd and xdd scaled by path_length /
    its length, t from 0 summed in order as np.cumsum sums; active_out (R,): the time of its
    stages with a limit active. The operations numpy did a unit at a time, the same values (the
    active time summed in order, not pairwise: a report's figure)."""
    for r in range(lengths.shape[0]):
        g0 = at[r]
        g1 = at[r + 1]
        o = g0 + r
        length = lengths[r]
        scale = path_length / length
        for k in range(g1 - g0 + 1):
            x_out[o + k] = (s[g0 + k] - s[g0]) / length
            xd_out[o + k] = sd[g0 + k] * scale
        x_out[o] = 0.0
        x_out[o + g1 - g0] = 1.0
        t_out[o] = 0.0
        total = 0.0
        busy = 0.0
        for k in range(g1 - g0):
            xdd_out[g0 + k] = xdd[g0 + k] * scale
            total = dt[g0 + k] if k == 0 else total + dt[g0 + k]
            t_out[o + k + 1] = total
            if active[g0 + k]:
                busy += dt[g0 + k]
        active_out[r] = busy


BATCH_PIECES = 16384  # path pieces (lines and arcs) solved at once by plan_runs


def plan_runs(ctx: PlanContext, specs) -> list:
    """``plan_run`` of every spec (a list of pieces each, in order), the short ones solved as one
    path: a run of a few dozen segments spends most of its time in a solve's per-problem set-up
    (grid, derivatives, rows, solve, check: about 2 ms), not in the kernels.

    Each run is prepared alone, as ``plan_run`` does, and the runs are blended in one pass (the same
    paths as blending each alone: :func:`.blend.blend_runs`); batches of up to BATCH_PIECES
    of their pieces are then solved as one path (:func:`_solve_units`, as ``plan_lines`` does
    for straight travels), each run's RunPiece its stretch of the solution: what planning it
    alone gives, to rounding.
    Long runs (windows), laser runs, runs that push filament at rest and the reference solver
    plan alone; where a batch's solve fails, each of its runs plans alone, and where a run fails
    alone too, every run is planned alone in order: the error raised is that of the first run in
    print order that fails, as without batches."""
    try:
        return _plan_runs(ctx, specs)
    except DeltasliceError:
        return [plan_run(ctx, spec) for spec in specs]


def _plan_runs(ctx: PlanContext, specs) -> list:
    """:func:`plan_runs` without the fall-back to planning every run alone."""
    out = [None] * len(specs)
    # by extruder (a batch plans the tool channel for all its runs or none): [[(index, inputs)]], and
    # the path pieces in each side's last batch
    batches, size = {True: [], False: []}, {True: 0, False: 0}
    batched, prepared = [], []
    for i, spec in enumerate(specs):
        alone = ctx.solver != "fast" or spec.power is not None or is_long(len(spec.points) - 1)
        deduped = None if alone else dedupe(spec.points, spec.feed, spec.e)
        if deduped is None or len(deduped[0]) < 2:
            out[i] = plan_run(ctx, spec)
            continue
        batched.append(i)
        prepared.append(_prepare(ctx, spec, None, deduped))
    every = (_path_inputs_many([p for p, _tol in prepared], [tol for _p, tol in prepared], ctx.speed_limit)
             if prepared else [])
    for i, inputs in zip(batched, every):
        groups, side = batches[inputs.extruder], inputs.extruder
        if not groups or size[side] + len(inputs.path.kind) > BATCH_PIECES:
            groups.append([])
            size[side] = 0
        groups[-1].append((i, inputs))
        size[side] += len(inputs.path.kind)
    for extruder, groups in batches.items():
        for group in groups:
            for (i, _inputs), pieces in zip(group, _plan_batch(ctx, specs, group, extruder)):
                out[i] = pieces
    return out


def _plan_batch(ctx: PlanContext, specs, group, extruder: bool) -> list:
    """The runs of ``group`` [(index in specs, _PathInputs)] solved as one path (:func:`_solve_units`):
    a list of pieces per run, each run planned alone where the batch fails."""
    paths = [inputs.path for _i, inputs in group]
    lengths = np.array([p.length for p in paths])
    offsets = np.concatenate([[0.0], np.cumsum(lengths)])
    counts = np.array([len(p.kind) for p in paths])
    path = BlendedPath(
        np.concatenate([p.piece_start[:-1] + o for p, o in zip(paths, offsets[:-1].tolist())] + [offsets[-1:]]),
        np.concatenate([p.kind for p in paths]), np.concatenate([p.p0 for p in paths]),
        np.concatenate([p.d0 for p in paths]), np.concatenate([p.normal for p in paths]),
        np.concatenate([p.radius for p in paths]), np.concatenate([p.segment for p in paths]))
    stop_at = np.concatenate([inp.stop_at + o for (_i, inp), o in zip(group, offsets[:-1].tolist())])
    e_ratio = np.concatenate([inp.e_ratio for _i, inp in group]) if extruder else None
    feed = np.concatenate([inp.piece_feed for _i, inp in group])
    try:
        inputs = _PathInputs(path, e_ratio, None, extruder, feed, stop_at)
        profiles = _solve_units(ctx, specs[group[0][0]].layer, inputs, lengths, np.repeat(np.arange(len(group)), counts))
        last = np.cumsum(counts) - 1
        q = ctx.kin.inverse(np.concatenate([path.p0[last - counts + 1], path.evaluate(offsets[1:], 0, last)]))
        if not np.isfinite(q).all():
            raise PlanningError("a run's end is out of reach")
    except DeltasliceError:
        return [plan_run(ctx, specs[i]) for i, _inputs in group]
    k = len(group)
    return [[RunPiece(inputs.path, float(lengths[r]), x, xd, xdd, t, inputs.cum_e, inputs.e_ratio, specs[i].tool,
                      specs[i].layer, active_time, "run", q[r], q[k + r], dynamic_power=specs[i].dynamic_power)]
            for r, ((i, inputs), (x, xd, xdd, t, active_time)) in enumerate(zip(group, profiles))]
