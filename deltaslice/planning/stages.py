"""The stages of a run: its grid (refined toward every line/arc join) and the continuous check
after solving (:func:`stage_maxima`: every channel's velocity and acceleration bounded over each
whole stage, both sides of a join)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..jit import njit
from .blend import BlendedPath
from .constraints import CHECK
from .pieces import RunPiece
from .runpath import RunPath
from .tolerances import GRID_POINT


MIN_STEP = 0.02
MAX_STEP = 2.0
GROWTH = 2.0
ARC_STEP = 0.2  # rad of tangent turn between grid points inside a blend arc
SHORT_PIECE_STEPS = 4  # pieces shorter than this many MIN_STEP get interior grid points
SHORT_FRACTIONS = np.array([0.25, 0.5, 0.75])
REFINE = 1  # stages per grid interval; tests set 10 to check grid convergence
CHECK_TOLERANCE = 1e-6  # a stage-wise ratio beyond 1 + this fails the run


def grid(path: BlendedPath, rest: np.ndarray | None = None) -> np.ndarray:
    """Grid in arc length (mm): from every join, steps growing geometrically from
    MIN_STEP to MAX_STEP on both sides, so every join has close neighbours on
    both sides and long lines get few stages. (n,) sorted, includes 0 and S.
    rest: arc lengths (mm) of the joins where the path is at rest besides its two ends (the
    solver's stop_at); None: rest may be anywhere."""
    joins = np.concatenate([[0.0], path.joins(), [path.length]])
    half = np.diff(joins) / 2  # each interval is refined from both its ends toward its middle
    steps = [MIN_STEP]
    total = MIN_STEP
    while total < half.max():
        steps.append(min(steps[-1] * GROWTH, MAX_STEP))
        total += steps[-1]
    offsets = np.cumsum(steps)
    # every join, then the steps out of it that stay short of its interval's middle from both ends
    stepped = np.empty(len(joins) + 2 * (len(joins) - 1) * len(offsets))
    stepped = stepped[: _stepped_points(joins, offsets, stepped)]
    # Inside arcs the acceleration direction turns with the tangent: one point per ARC_STEP rad.
    arc = np.flatnonzero(path.kind == 1)
    arc_len = path.piece_start[arc + 1] - path.piece_start[arc]
    count = np.ceil(arc_len / (ARC_STEP * path.radius[arc])).astype(int)
    owner = np.repeat(np.arange(len(arc)), count)
    within = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    on_arcs = path.piece_start[arc][owner] + arc_len[owner] * within / count[owner]
    # A piece too short for the geometric steps that starts and stops at rest gets interior
    # points: it needs a stage whose end can move. Elsewhere its joins are enough: such pieces are
    # common in sliced parts, and interior points there add stages without changing print times
    # by more than a few parts in 1e5.
    length = np.diff(path.piece_start)
    at_rest = np.isin(path.piece_start, rest) if rest is not None else np.ones(len(path.piece_start), dtype=bool)
    at_rest[0] = at_rest[-1] = True
    short = np.flatnonzero((length < SHORT_PIECE_STEPS * MIN_STEP) & (length > 0) & at_rest[:-1] & at_rest[1:])
    in_short = (path.piece_start[short, None] + length[short, None] * SHORT_FRACTIONS[None]).ravel()
    # sorted stably (the parts are runs in order, which timsort merges), duplicates and points
    # closer than GRID_POINT mm (nothing but ill-conditioned stages) left out: np.unique's values
    g = np.sort(np.concatenate([stepped, on_arcs, in_short]), kind="stable")
    keep = np.concatenate([[True], np.diff(g) > GRID_POINT])
    g = g[keep]
    g[-1] = path.length
    if REFINE > 1:  # uniform subdivision of every stage (convergence checks)
        f = np.arange(REFINE) / REFINE
        g = np.concatenate([(g[:-1, None] + np.diff(g)[:, None] * f[None]).ravel(), g[-1:]])
    return g


@njit
def _stepped_points(joins, offsets, out):
    """:func:`grid`'s geometric points into out, in order: each join, then in its interval the
    points join + offset and next join - offset for the offsets (ascending) below 0.999 of half
    the interval, then the last join. Returns how many. The values numpy's broadcast made (an
    (intervals, steps) array of each, masked), without them."""
    m = 0
    for k in range(joins.shape[0] - 1):
        a = joins[k]
        b = joins[k + 1]
        limit = (b - a) / 2 * 0.999
        out[m] = a
        m += 1
        n = 0
        while n < offsets.shape[0] and offsets[n] < limit:
            out[m] = a + offsets[n]
            m += 1
            n += 1
        for i in range(n - 1, -1, -1):
            out[m] = b - offsets[i]
            m += 1
    out[m] = joins[joins.shape[0] - 1]
    return m + 1


@dataclass(frozen=True)
class StageMaxima:
    """Stage-wise bounds of a planned run: per channel (joints, then the filament for
    extruders), the largest velocity and acceleration over every stage as a fraction of the
    limits given, and where the worst is. velocity, acceleration: (dof,); stage: (dof,) index
    of the stage of the acceleration peak; s: (dof,) its arc length, mm; per_stage: (n,) the
    largest ratio of any channel in each stage."""

    velocity: np.ndarray
    acceleration: np.ndarray
    stage_v: np.ndarray
    stage_a: np.ndarray
    per_stage: np.ndarray

    @property
    def worst(self) -> float:
        return float(max(self.velocity.max(initial=0.0), self.acceleration.max(initial=0.0)))


def stage_maxima(rp: "RunPath", x, xd, xdd, vmax, amax, frac: np.ndarray = CHECK, stage=None) -> StageMaxima:
    """Bound every channel's velocity and acceleration over every stage of a solution.

    x (n+1,) grid, xd (n+1,) path speed, xdd (n,) path acceleration; vmax, amax (dof,).
    Within a stage u = xdd is constant and x_dot^2 is linear, so velocity |q'| x_dot and
    acceleration |q' u + q'' x_dot^2| are exact at the ``frac`` points, each with the
    stage's own piece (a join is seen from both sides); between points the excess of a
    smooth function over its samples is at most h^2 max|g''| / 8, bounded here by an eighth
    of the largest second difference of the samples (plus a quarter, for safety). ``stage``:
    ``rp.stage_derivatives(x, frac)`` when the caller has it."""
    dq, ddq = rp.stage_derivatives(x, frac) if stage is None else stage
    n, dof = dq.shape[0], dq.shape[2]
    if n == 0:
        raise ValueError("stage_maxima: a grid of one point has no stages")
    peak = np.empty((2, dof))
    at = np.empty((2, dof), dtype=np.int64)
    per_stage = np.empty(n)
    _stage_bounds(*(np.ascontiguousarray(v, dtype=float) for v in (dq, ddq, xd, xdd, frac, vmax, amax)), peak, at,
                  per_stage)
    return StageMaxima(peak[0], peak[1], at[0], at[1], per_stage)


@njit
def _stage_bounds(dq, ddq, xd, xdd, frac, vmax, amax, peak, at, per_stage):
    """:func:`stage_maxima`'s bounds per stage and channel: at each fraction f, x_dot^2 =
    w = max(0, x_i + (x_{i+1} - x_i) f), velocity |q'| sqrt(w) / vmax and acceleration
    |q' u + q'' w| / amax; the largest sample plus 0.3125 of the largest second difference of
    the samples. Reduced as numpy's max and argmax over the stages (peak, at: (2, dof), velocity
    then acceleration; the first NaN wins, as it propagates) and max over the channels
    (per_stage (n,))."""
    n, f, dof = dq.shape
    w = np.empty(f)
    sw = np.empty(f)
    g = np.empty(f)
    for i in range(n):
        x0 = xd[i] * xd[i]
        x1 = xd[i + 1] * xd[i + 1]
        for m in range(f):
            w[m] = max(x0 + (x1 - x0) * frac[m], 0.0)
            sw[m] = math.sqrt(w[m])
        worst = 0.0
        u = xdd[i]
        for j in range(dof):
            for kind in range(2):
                if kind == 0:
                    vj = vmax[j]
                    for m in range(f):
                        g[m] = abs(dq[i, m, j]) * sw[m] / vj
                else:
                    aj = amax[j]
                    for m in range(f):
                        g[m] = abs(dq[i, m, j] * u + ddq[i, m, j] * w[m]) / aj
                # the largest sample and second difference, NaN if any is: a flag beside plain
                # selects (a NaN test in each select made the pass a quarter slower)
                top = g[0]
                nan = g[0] != g[0]
                for m in range(1, f):
                    top = g[m] if g[m] > top else top
                    nan |= g[m] != g[m]
                if f > 2:
                    dd = abs(g[2] - 2 * g[1] + g[0])
                    nan |= dd != dd
                    for m in range(1, f - 2):
                        v = abs(g[m + 2] - 2 * g[m + 1] + g[m])
                        dd = v if v > dd else dd
                        nan |= v != v
                    top = top + 0.3125 * dd
                if nan:
                    top = np.nan
                if i == 0 or (peak[kind, j] == peak[kind, j] and (top > peak[kind, j] or top != top)):
                    peak[kind, j] = top
                    at[kind, j] = i
                if (j == 0 and kind == 0) or (worst == worst and (top > worst or top != top)):
                    worst = top
        per_stage[i] = worst


def run_stage_maxima(piece: RunPiece, kin, vmax, amax, filament: tuple[float, float] | None = None) -> StageMaxima:
    """:func:`stage_maxima` of a planned RunPiece against limits vmax, amax (J,) (pass the
    printer's own limits to check the output, the margin-reduced ones to check toppra);
    filament: (speed, acceleration) limits when the run extrudes."""
    e_ratio = piece.e_ratio if filament is not None and np.any(piece.e_ratio != 0) else None
    rp = RunPath(kin, piece.path, e_ratio, piece.layer)
    if e_ratio is not None:
        vmax, amax = np.append(vmax, filament[0]), np.append(amax, filament[1])
    return stage_maxima(rp, piece.x, piece.xd, piece.xdd, np.asarray(vmax, float), np.asarray(amax, float))
