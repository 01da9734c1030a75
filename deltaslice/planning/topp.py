"""Time-optimal parameterisation of one run in joint space: the entry for a run
(:func:`plan_run`, :func:`iter_run`, :func:`iter_run_parts`).

A run (a continuous extrusion or laser-on polyline) is deduplicated, its segments shorter than
``MERGE_LENGTH`` merged (:func:`.blend.merge_short`), blended (:mod:`.blend`), mapped through the
inverse kinematics and parameterised by a normalised path coordinate x = s / S in [0, 1] (s: arc
length in mm, S: run length; :mod:`.runpath`): toppra's seidel solver is badly conditioned when
the path parameter is in mm. The path has one coordinate per joint plus the filament position
(extruders), so

* joint and filament velocity limits and the feed cap become one grid-wide bound on x_dot^2,
* joint and filament acceleration limits are rows linear in (u, x_dot^2) at the start, middle
  and end of every stage, each with the derivatives of the piece the stage lies in
  (:mod:`.constraints`),

all to the context's planned (margin-reduced) limits. After solving (:mod:`.solver`), every
channel is bounded over each whole stage against the machine's own limits
(:func:`.stages.stage_maxima`); a stage beyond them is refined and re-planned, and a run that
still exceeds a limit raises :class:`PlanningError` naming the layer, position and limit. A run
of more than ``windows.LONG_RUN`` segments is planned window by window (:mod:`.windows`).
"""

from __future__ import annotations

import itertools

import numpy as np

from ..errors import PlanningError
from .blend import DEDUPE_EPS, dedupe, merge_short
from .context import PlanContext
from .pieces import FilamentPiece
from .runpath import RunSpec, _Polyline, _segment_power
from .solver import _plan_polyline
from .windows import _iter_windows, _stretches, is_long


MERGE_LENGTH = 0.02  # mm: segments shorter than this are merged where the path allows
MERGE_DEVIATION = 0.25  # of the blend tolerance: what merging may move the path


def plan_run(ctx: PlanContext, spec: RunSpec, tolerance: float | None = None, kind: str = "run") -> list:
    """Plan one run from rest to rest: a list of pieces (usually one RunPiece).

    ctx: the plan's context (its solver: "fast", :mod:`.reachability`, or "toppra", the same problem
    through toppra's seidel solver); tolerance: blend tolerance, mm (default: the context's);
    kind: the pieces' kind ("run", or "travel" for a straight travel). A run shorter than a
    micron is its filament pushed at rest (or nothing); in the rare case toppra's numerics
    fail on a whole run, the pieces of its two halves (split at a vertex, each from rest to rest)."""
    deduped = dedupe(spec.points, spec.feed, spec.e)
    if len(deduped[0]) < 2:
        amount = float(spec.e.sum())
        if amount == 0:
            return []
        limits = ctx.planned_limits
        q = ctx.kin.inverse(spec.points[-1:])[0]
        return [FilamentPiece(q, amount, float(limits.velocity[-1]), float(limits.acceleration[-1]), spec.layer, kind=kind)]
    try:
        return _plan_run(ctx, spec, tolerance, kind, deduped)
    except PlanningError:
        m = len(spec.points) - 1
        if m < 2:
            raise
        h = m // 2
        return [p for part in (spec.part(0, h), spec.part(h, m)) for p in plan_run(ctx, part, tolerance, kind)]


def _prepare(ctx: PlanContext, spec: RunSpec, tolerance: float | None, deduped=None):
    """(polyline, blend tolerance left) of a run: deduplicated (``deduped``: dedupe's result when
    the caller has it), short segments merged."""
    pts, feed, e = dedupe(spec.points, spec.feed, spec.e) if deduped is None else deduped
    tol = ctx.blend_tolerance if tolerance is None else tolerance
    pts, feed, e, moved = merge_short(pts, feed, e, MERGE_LENGTH, MERGE_DEVIATION * tol)
    # merged and deduplicated segments carry their power along as they do their feed
    power = None if spec.power is None else _segment_power(spec, pts)
    # The blend keeps within what merging left of the tolerance.
    return _Polyline(pts, feed, e, power), tol - moved


def _plan_run(ctx: PlanContext, spec: RunSpec, tolerance: float | None, kind: str, deduped=None) -> list:
    """:func:`plan_run` of a run of two points or more (``deduped``: its dedupe), without the split
    of a run the solver fails on."""
    poly, tol = _prepare(ctx, spec, tolerance, deduped)
    if is_long(len(poly.points) - 1):
        box = [poly]
        del poly, deduped
        return [piece for piece, _done in _iter_windows(ctx, spec, _stretches(box, tol), kind)]
    return [_plan_polyline(ctx, spec, poly, tol, kind)[0]]


def iter_run(ctx: PlanContext, spec: RunSpec):
    """``plan_run``'s pieces one at a time, each with the fraction of the run planned so far: a
    long run window by window (memory bounded by a window, however long the run), so a caller
    can put each piece away before the next is planned."""
    deduped = dedupe(spec.points, spec.feed, spec.e)
    if len(deduped[0]) >= 2:
        poly, tol = _prepare(ctx, spec, None, deduped)
        del deduped  # whole-run copies: only the windows' own polyline is kept while they are planned
        m = len(poly.points) - 1
        if is_long(m):
            box = [poly]
            del poly
            for piece, done in _iter_windows(ctx, spec, _stretches(box, tol), "run"):
                yield piece, done / m
            return
    for piece in plan_run(ctx, spec):
        yield piece, 1.0


def iter_run_parts(ctx: PlanContext, parts):
    """A run handed over in consecutive parts (RunSpecs, each starting at the previous one's last
    point), planned window by window as its parts arrive: a spiral vase read a stretch at a
    time is never held whole. Yields (piece, moves of the parts taken so far).

    Each part is deduplicated and merged on its own (its ends stay vertices; a part is handed on
    up to its last segment longer than a micron, so the filament of the shorter ones after it goes
    to a segment of the next); a window's blends keep to what merging left of the tolerance in
    the parts it spans (a whole run's keep to what merging left anywhere in it)."""
    taken, first = [0], []

    def prepared():
        pending = None
        for part in parts:
            taken[0] += len(part.points) - 1
            if not first:
                first.append(part)
            spec = part if pending is None else pending.followed_by(part)
            kept = np.flatnonzero(np.linalg.norm(np.diff(spec.points, axis=0), axis=1) > DEDUPE_EPS)
            if len(kept) < 2:
                pending = spec
                continue
            yield _prepare(ctx, spec.part(0, int(kept[-1])), None)
            pending = spec.part(int(kept[-1]), len(spec.points) - 1)
        if pending is not None:
            first.append(pending)  # the last: all of the run when no segment of it is longer than a micron
            yield _prepare(ctx, pending, None)

    stretches = prepared()
    head = next(stretches)
    if len(head[0].points) < 2:  # the whole run shorter than a micron: its filament pushed at rest
        for piece in plan_run(ctx, first[-1]):
            yield piece, taken[0]
        return
    for piece, _done in _iter_windows(ctx, first[0], itertools.chain([head], stretches), "run"):
        yield piece, taken[0]
