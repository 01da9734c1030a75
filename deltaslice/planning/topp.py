"""Time-optimal parameterisation of one run in joint space, with toppra.

A run (a continuous extrusion or laser-on polyline) is blended
(:mod:`.blend`), mapped through the inverse kinematics and parameterised by a
normalised path coordinate x = s / S in [0, 1] (s: arc length in mm, S: run
length): toppra's seidel solver is badly conditioned when the path parameter
is in mm. The path handed to toppra has one coordinate per joint plus the
filament position (extruders), so

* joint and filament velocity limits and the feed cap become one grid-wide
  bound on x_dot^2 (:class:`PathVelocityConstraint`),
* joint and filament acceleration limits are :class:`StageAccelerationConstraint`:
  inside one stage the path acceleration u is constant and x_dot^2 is linear in x,
  so the joint acceleration q'(x) u + q''(x) x_dot^2 is a known linear form in
  (u, x_dot^2) at any point of the stage. It is imposed at the stage's start,
  middle and end, each with the derivatives of the piece the
  stage lies in (every line/arc join is a grid point, so the stage ending at a
  join uses the curvature before it, the stage starting there the curvature
  after it),

all reduced by the printer's ``limit_margin``. After solving, :func:`stage_maxima`
bounds every joint's velocity and acceleration over each whole stage (five points
per stage plus a curvature bound between them) against the printer's limits; a
stage beyond them is refined and re-planned, and a run that still exceeds a limit
raises :class:`PlanningError` naming the layer, position and limit.

The grid is refined geometrically toward every line/arc join with points on both
sides of each, so braking before a corner is resolved without a fine grid on long
lines; every piece shorter than a few grid steps gets interior points, so a piece
that starts or stops at rest always has room to move. Segments shorter than
``MERGE_LENGTH`` are merged first (:func:`.blend.merge_short`).
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass

import numpy as np

from ..errors import DeltasliceError, PlanningError, UnreachableError
from ..jit import njit
from .blend import DEDUPE_EPS, BlendedPath, blend_runs, dedupe, merge_short, run_cumsum
from .pieces import FilamentPiece, RunPiece
from .reachability import solve as fast_solve
from .torque import cruise_x, solve_with_torque, stage_check, stage_torque, torque_limits

logging.getLogger("toppra").setLevel(logging.ERROR)

# Grid: spacing grows geometrically from each join up to MAX_STEP (mm).
SOLVERS = ("fast", "toppra")  # the speed-profile solvers: compiled reachability (default), toppra (reference)
MIN_STEP = 0.02
MAX_STEP = 2.0
GROWTH = 2.0
ARC_STEP = 0.2  # rad of tangent turn between grid points inside a blend arc
REFINE = 1  # stages per grid interval; tests set 10 to check grid convergence
ACTIVE = 0.95  # a limit counts as active within 5 % of it
SHORT_PIECE_STEPS = 4  # pieces shorter than this many MIN_STEP get interior grid points
SHORT_FRACTIONS = np.array([0.25, 0.5, 0.75])
MERGE_LENGTH = 0.02  # mm: segments shorter than this are merged where the path allows
MERGE_DEVIATION = 0.25  # of the blend tolerance: what merging may move the path
# Stage fractions where the solver constrains acceleration: both ends and the middle. The limits
# are held by the stage-wise check at CHECK's five (and refinement where it fails), not by these;
# the quarters too cost 70 % more rows (17 against 10 a stage with a filament channel) for print
# times within 1e-6, and the motion between them stays within the planner's margin (1 %).
EVAL = np.array([0.0, 0.5, 1.0])
# Stage fractions of the stage-wise limit check: the quarters. Its bound adds 0.3125 of the
# samples' largest second difference; at nine fractions (the eighths) it was at most 0.003 tighter,
# refined no run and changed no plan of 42 on every printer, for 80 % more derivatives (a sixth
# of the planner's CPU); at five it is still above a 257-point evaluation on every stage of them.
CHECK = np.linspace(0.0, 1.0, 5)
# EVAL's fractions are CHECK's 0, 2 and 4 (exactly: k/4): the derivatives are computed once per
# grid, and the constraints take a view of them.
EVAL_IN_CHECK = slice(0, None, 2)
DERIVATIVE_BLOCK = 32768  # points per inverse-kinematics call in RunPath.derivatives
CHECK_TOLERANCE = 1e-6  # a stage-wise ratio beyond 1 + this fails the run
REFINE_PASSES = 3  # times a run's violating stages are split before it fails
# A run of more than LONG_RUN segments is planned in windows of WINDOW segments (each planned
# LOOKAHEAD further), so the planner's memory is bounded by a window (about 200 MB at these sizes,
# measured on a spiral vase) and the lookahead costs about 7 % more solving than the whole run.
LONG_RUN = 8000
WINDOW = 6000
LOOKAHEAD = 1000  # segments each window plans past its cut (and at least LOOKAHEAD_MM)
LOOKAHEAD_MM = 50.0


@dataclass(frozen=True)
class RunSpec:
    """What the planner needs of one run. points (m+1,3) mm; feed, e: per segment (m,).

    power: per segment (m,) laser power 0..1, or None (``tool`` throughout); with
    dynamic_power the power is scaled by the tool's speed over the segment's feed (GRBL M4)."""

    points: np.ndarray
    feed: np.ndarray
    e: np.ndarray
    tool: float
    layer: int
    power: np.ndarray | None = None
    dynamic_power: bool = False

    def part(self, a: int, b: int) -> "RunSpec":
        """Segments a..b-1 as a run of their own."""
        power = None if self.power is None else self.power[a:b]
        return RunSpec(self.points[a : b + 1], self.feed[a:b], self.e[a:b], self.tool, self.layer, power, self.dynamic_power)

    def followed_by(self, other: "RunSpec") -> "RunSpec":
        """This run's segments and then ``other``'s, which starts at this one's last point."""
        cat = np.concatenate
        power = None if self.power is None else cat([self.power, other.power])
        return RunSpec(cat([self.points, other.points[1:]]), cat([self.feed, other.feed]), cat([self.e, other.e]),
                       self.tool, self.layer, power, self.dynamic_power)


class RunPath:
    """The run as toppra sees it (its ``AbstractGeometricPath`` interface, by duck typing):
    x in [0, 1] -> (q_1..q_J[, e]) with analytic first derivatives (inverse Jacobian times
    tangent) and one-sided second derivatives taken inside the piece a grid point starts
    (toppra's collocation uses the stage ahead of each grid point)."""

    def __init__(self, kin, path: BlendedPath, e_ratio: np.ndarray | None, layer: int):
        self.kin, self.path, self.e_ratio, self.layer = kin, path, e_ratio, layer
        self.S = path.length
        self._dof = kin.n_joints + (0 if e_ratio is None else 1)

    @property
    def dof(self) -> int:
        return self._dof

    @property
    def path_interval(self):
        return np.array([0.0, 1.0])

    def _ik(self, s, piece):
        return self._ik_at(self.path.evaluate(s, 0, piece))

    def _ik_at(self, p):
        q = self.kin.inverse(p)
        self._check_reach(p, q)
        return p, q

    def _check_reach(self, p, q):
        with np.errstate(over="ignore"):
            if np.isfinite(q.sum()):  # one reduction: a NaN row (out of reach) makes the sum NaN
                return
        bad = ~np.all(np.isfinite(q), axis=1)
        if bad.any():
            self._raise_unreachable(p[int(np.flatnonzero(bad)[0])])

    def _raise_unreachable(self, point):
        raise UnreachableError(
            f"layer {self.layer}: point x = {point[0]:.2f}, y = {point[1]:.2f}, z = {point[2]:.2f} mm is out of reach"
        )

    def derivatives(self, s: np.ndarray, piece: np.ndarray):
        """First and second derivatives of the path with respect to x, at arc lengths s (mm)
        inside the given pieces (so a join is evaluated on the side the caller names).
        -> (dq, ddq), (n, dof) each, joint units per path unit.

        The kinematics' ``path_derivatives`` along the piece's tangent t(s) and curvature
        kappa(s) (piece-wise; the inverse kinematics itself is smooth across joins), scaled
        from mm to path units. Evaluated DERIVATIVE_BLOCK points at a time: a long window's
        arrays would otherwise take hundreds of MB at once."""
        dq, ddq = np.empty((len(s), self._dof)), np.empty((len(s), self._dof))
        self._joint_derivatives(s, piece, dq, ddq)
        if self.e_ratio is not None:
            J = self.kin.n_joints
            np.multiply(self.e_ratio[piece], self.S, out=dq[:, J])
            ddq[:, J] = 0.0
        return dq, ddq

    def _joint_derivatives(self, s, piece, dq, ddq) -> None:
        """The joints' columns of :meth:`derivatives` into dq, ddq (n, dof)."""
        for i in range(0, len(s), DERIVATIVE_BLOCK):
            block = slice(i, i + DERIVATIVE_BLOCK)
            self._joint_rates(self.path.frame(s[block], piece[block]), dq[block], ddq[block])

    def _joint_rates(self, frame, dq, ddq) -> None:
        """The joints' columns of dq, ddq (n, dof) at the points of ``frame`` (point, tangent,
        curvature: (n, 3) each); UnreachableError at the first point out of reach."""
        p, t, kappa = frame
        J = self.kin.n_joints
        bad = self.kin.scaled_path_derivatives(p, t, kappa, self.S, dq[:, :J], ddq[:, :J])
        if bad >= 0:
            self._raise_unreachable(p[bad])

    def stage_derivatives(self, x: np.ndarray, frac: np.ndarray):
        """Derivatives at fractions ``frac`` (f,) of every stage of the grid x (n+1,), each
        with the piece the stage lies in. -> (dq, ddq), (n, f, dof) each."""
        s = np.asarray(x, float) * self.S
        ds = np.diff(s)
        owner = self.path.locate(0.5 * (s[:-1] + s[1:]))
        n, f = len(ds), len(frac)
        dq, ddq = np.empty((n, f, self._dof)), np.empty((n, f, self._dof))
        flat_dq, flat_ddq = dq.reshape(n * f, self._dof), ddq.reshape(n * f, self._dof)
        per = max(1, DERIVATIVE_BLOCK // max(f, 1))  # stages a block
        J = self.kin.n_joints
        for a in range(0, n, per):
            b = min(a + per, n)
            self._joint_rates(self.path.stage_frame(s[a:b], ds[a:b], frac, owner[a:b]), flat_dq[a * f : b * f],
                              flat_ddq[a * f : b * f])
            if self.e_ratio is not None:  # the filament's rate is its piece's: one value per stage
                # block by block, while the block is in the cache (a pass over the whole arrays
                # cost as much again)
                dq[a:b, :, J] = (self.e_ratio[owner[a:b]] * self.S)[:, None]
                ddq[a:b, :, J] = 0.0
        return dq, ddq

    def __call__(self, xs, order=0):
        xs = np.atleast_1d(np.asarray(xs, dtype=float))
        s = np.clip(xs, 0.0, 1.0) * self.S
        piece = self.path.locate(s)
        if order == 0:
            out = self._ik(s, piece)[1]
            if self.e_ratio is not None:
                out = np.column_stack([out, s * 0])  # e enters only through its derivatives
            return out
        dq, ddq = self.derivatives(s, piece)
        return dq if order == 1 else ddq


class StageAccelerationConstraint:
    """Joint (and filament) acceleration limits imposed inside every stage.

    In stage i (x_i..x_{i+1}, width d) the path acceleration u is constant and
    x_dot^2 = x_i + 2 f d u at fraction f, so the acceleration at f is
    (q'(f) + 2 f d q''(f)) u + q''(f) x_i: collocation rows in toppra's (u, x_i), one
    set per fraction in ``frac``, derivatives from the stage's own piece. ``stage``:
    precomputed ``RunPath.stage_derivatives(x, frac)``."""

    identical = True  # toppra's flag: F and g are the same at every grid point

    def __init__(self, amax: np.ndarray, frac: np.ndarray = EVAL, stage=None):
        self.amax = np.asarray(amax, dtype=float)
        self.dof = len(self.amax)
        self.frac = np.asarray(frac, dtype=float)
        self.stage = stage

    def rows(self, path, gridpoints, unit: np.ndarray | None = None, last_once: bool = False):
        """The rows' u and x coefficients a, b (n+1, f * dof), each bounded by +-amax; with
        ``unit`` (n+1,), each row in other units of the path parameter (x' = c x, c = unit[i]):
        a / c and b / c^2 (the compiled solver's rows for moves that meet at rest, _speeds).
        last_once: the last channel's rows at the first fraction only (f * dof - f + 1 columns, in
        the order of :meth:`channels`): the filament's, which are the same at every fraction
        (q' its piece's rate, q'' = 0: RunPath.stage_derivatives), so the others repeat them."""
        dq, ddq = self.stage if self.stage is not None else path.stage_derivatives(gridpoints, self.frac)
        d = np.diff(gridpoints)
        n, f, dof = dq.shape
        ch = self.channels(last_once)
        c = np.ones(n + 1) if unit is None else np.asarray(unit, dtype=float)  # x / 1.0 is x, bit for bit
        a = np.empty((n + 1, len(ch)))
        b = np.empty((n + 1, len(ch)))
        _rows_kernel(dq, ddq, self.frac, d, c, last_once, a, b)
        # The last grid point has no stage ahead: its own (end) derivatives, no u-term.
        a[-1] = dq[-1, -1][ch] / c[-1]
        b[-1] = ddq[-1, -1][ch] / (c[-1] * c[-1])
        return a, b

    def channels(self, last_once: bool = False) -> np.ndarray:
        """The channel of each of :meth:`rows`' columns: fraction-major, every channel at each
        fraction (the last one at the first fraction only, with last_once)."""
        f, dof = len(self.frac), self.dof
        return np.array([j for k in range(f) for j in range(dof) if not (last_once and k > 0 and j == dof - 1)],
                        dtype=np.int64)

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        a, b = self.rows(path, gridpoints)
        eye = np.eye(a.shape[1])
        F = np.vstack([eye, -eye])
        g = np.tile(self.amax, 2 * len(self.frac))
        return a, b, np.zeros_like(a), F, g, None, None


@njit
def _rows_kernel(dq, ddq, frac, d, unit, last_once, a, b):
    """a[i, k dof + j] = q'_j + 2 f_k d_i q''_j and b[i, k dof + j] = q''_j at fraction f_k of stage i
    (dq, ddq: (n, f, dof); rows i < n of a, b), in one pass: the same operations, in the same
    order, as the numpy expression ``dq + 2 * frac * d * ddq``, each row i then divided by unit[i]
    (a) and unit[i]^2 (b), as numpy's ``a / c, b / (c * c)`` (unit (n+1,); ones leave the rows as
    they are). last_once: the last channel at the first fraction only (the columns of
    StageAccelerationConstraint.channels)."""
    n, f, dof = dq.shape
    for i in range(n):
        c = unit[i]
        cc = c * c
        col = 0
        for k in range(f):
            w = 2.0 * frac[k] * d[i]
            for j in range(dof if not (last_once and k > 0) else dof - 1):
                a[i, col] = (dq[i, k, j] + w * ddq[i, k, j]) / c
                b[i, col] = ddq[i, k, j] / cc
                col += 1


def gridpoint_speed_factor(dq_stage: np.ndarray) -> np.ndarray:
    """Largest |q'| (n+1, dof) at each grid point over both sides of it and the stages around
    it (their start, middle and end), from stage derivatives (n, f, dof) at fractions whose
    first is 0, middle 0.5 and last 1: a cap on x_dot^2 at both ends of a stage also holds in
    its middle, where x_dot^2 is their mean."""
    out = np.empty((dq_stage.shape[0] + 1, dq_stage.shape[2]))
    _speed_factor_kernel(dq_stage, out)
    return out


@njit
def _nan_max(a, b):
    """numpy's maximum of two floats: NaN if either is."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@njit
def _speed_factor_kernel(dq, out):
    """:func:`gridpoint_speed_factor` in one pass: out[i] = max(ahead_i, behind_{i-1}) with
    ahead_i = max(|q'| at stage i's start, at its middle), behind_i = max(|q'| at its end, at its
    middle) (NaN where any is, as numpy's maximum); out[0] = ahead_0, out[n] = behind_{n-1}."""
    n, f, dof = dq.shape
    mid = f // 2
    # grid point by grid point, its channels together: one pass over dq (a pass per channel
    # read a run's whole derivative array, larger than the cache, once for each)
    for i in range(n + 1):
        for j in range(dof):
            top = 0.0
            if i < n:
                top = _nan_max(abs(dq[i, 0, j]), abs(dq[i, mid, j]))
            if i > 0:
                behind = _nan_max(abs(dq[i - 1, f - 1, j]), abs(dq[i - 1, mid, j]))
                top = _nan_max(top, behind)
            out[i, j] = top


class PathVelocityConstraint:
    """Every first-order limit at once, over the whole grid: joint (and filament)
    velocity limits through q'(x), and the feed cap on the Cartesian speed S x_dot.
    Returns only toppra's ``xbound`` (bounds on x_dot^2)."""

    identical = False

    def __init__(self, vmax: np.ndarray, feed_at_grid: np.ndarray, S: float, speed_factor: np.ndarray | None = None):
        self.speed_factor = speed_factor  # (n+1, dof) |q'| per grid point, both sides (gridpoint_speed_factor)
        self.vmax = np.asarray(vmax, dtype=float)
        self.dof = len(self.vmax)
        self.feed = np.asarray(feed_at_grid, dtype=float)
        self.S = S

    def cap2(self, path, gridpoints) -> np.ndarray:
        """The bound on x_dot^2 at each grid point (n+1,)."""
        dq = np.abs(path(gridpoints, 1)) if self.speed_factor is None else self.speed_factor
        dq = np.ascontiguousarray(dq, dtype=float)
        # the kernel reads a feed per grid point and a limit per channel unchecked: broadcast
        # them as numpy's expression did (a scalar feed; a feed for another grid refused)
        vmax = np.ascontiguousarray(np.broadcast_to(self.vmax, dq.shape[1:]))
        feed = np.ascontiguousarray(np.broadcast_to(self.feed, dq.shape[:1]), dtype=float)
        out = np.empty(len(dq))
        _cap2_kernel(dq, vmax, feed, float(self.S), out)
        return out

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        xbound = np.zeros((len(gridpoints), 2))
        xbound[:, 1] = self.cap2(path, gridpoints)
        return None, None, None, None, None, None, xbound


@njit
def _cap2_kernel(dq, vmax, feed, S, out):
    """out[i] = min(min_j vmax[j] / dq[i, j], feed[i] / S)^2 (dq (n, dof) >= 0, a zero giving
    inf), NaN where any term is: numpy's ``np.minimum(np.min(vmax / dq, axis=1), feed / S) ** 2``
    in one pass (its (n, dof) temporaries and its short reduction along each row cost more than
    the arithmetic)."""
    n, dof = dq.shape
    for i in range(n):
        cap = feed[i] / S  # NaN stays NaN: v < NaN is false
        nan = False
        for j in range(dof):
            v = vmax[j] / dq[i, j]
            nan |= v != v
            cap = v if v < cap else cap
        out[i] = np.nan if nan else cap * cap


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
    # closer than 1e-7 mm (nothing but ill-conditioned stages) left out: np.unique's values, a
    # third faster
    g = np.sort(np.concatenate([stepped, on_arcs, in_short]), kind="stable")
    keep = np.concatenate([[True], np.diff(g) > 1e-7])
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


def plan_run(kin, printer, spec: RunSpec, speed_limit: str, tolerance: float | None = None, kind: str = "run",
             solver: str = "fast") -> list:
    """Plan one run from rest to rest: a list of pieces (usually one RunPiece).

    kin: the printer's kinematics; tolerance: blend tolerance, mm (default: the printer's);
    solver: "fast" (:mod:`.reachability`) or "toppra" (the same problem through toppra's seidel solver);
    kind: the pieces' kind ("run", or "travel" for a straight travel). A run shorter than a
    micron is its filament pushed at rest (or nothing); in the rare case toppra's numerics
    fail on a whole run, the pieces of its two halves (split at a vertex, each from rest to rest)."""
    deduped = dedupe(spec.points, spec.feed, spec.e)
    if len(deduped[0]) < 2:
        amount = float(spec.e.sum())
        if amount == 0:
            return []
        limits = printer.planned_limits()
        q = kin.inverse(spec.points[-1:])[0]
        return [FilamentPiece(q, amount, float(limits.velocity[-1]), float(limits.acceleration[-1]), spec.layer, kind=kind)]
    try:
        return _plan_run(kin, printer, spec, speed_limit, tolerance, kind, solver, deduped)
    except PlanningError:
        m = len(spec.points) - 1
        if m < 2:
            raise
        h = m // 2
        return [p for part in (spec.part(0, h), spec.part(h, m)) for p in plan_run(kin, printer, part, speed_limit, tolerance, kind, solver)]


def _describe(printer, channel: int) -> str:
    return printer.limits.names[channel]


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


def _prepare(printer, spec: RunSpec, tolerance: float | None, deduped=None):
    """(polyline, blend tolerance left) of a run: deduplicated (``deduped``: dedupe's result when
    the caller has it), short segments merged."""
    pts, feed, e = dedupe(spec.points, spec.feed, spec.e) if deduped is None else deduped
    tol = printer.planning.blend_tolerance if tolerance is None else tolerance
    pts, feed, e, moved = merge_short(pts, feed, e, MERGE_LENGTH, MERGE_DEVIATION * tol)
    # merged and deduplicated segments carry their power along as they do their feed
    power = None if spec.power is None else _segment_power(spec, pts)
    # The blend keeps within what merging left of the tolerance.
    return _Polyline(pts, feed, e, power), tol - moved


def _plan_run(kin, printer, spec: RunSpec, speed_limit: str, tolerance: float | None, kind: str, solver: str,
              deduped=None) -> list:
    poly, tol = _prepare(printer, spec, tolerance, deduped)
    if len(poly.points) - 1 > LONG_RUN:
        box = [poly]
        del poly, deduped
        return [piece for piece, _done in _iter_windows(kin, printer, spec, _stretches(box, tol), speed_limit, kind,
                                                        solver)]
    return [_plan_polyline(kin, printer, spec, poly, speed_limit, tol, kind, solver)[0]]


def is_long(n_moves: int) -> bool:
    """Whether a run of ``n_moves`` moves is planned in windows (see :func:`iter_run`)."""
    return n_moves > LONG_RUN


def iter_run(kin, printer, spec: RunSpec, speed_limit: str, solver: str = "fast"):
    """``plan_run``'s pieces one at a time, each with the fraction of the run planned so far: a
    long run window by window (memory bounded by a window, however long the run), so a caller
    can put each piece away before the next is planned."""
    deduped = dedupe(spec.points, spec.feed, spec.e)
    if len(deduped[0]) >= 2:
        poly, tol = _prepare(printer, spec, None, deduped)
        del deduped  # whole-run copies: only the windows' own polyline is kept while they are planned
        m = len(poly.points) - 1
        if m > LONG_RUN:
            box = [poly]
            del poly
            for piece, done in _iter_windows(kin, printer, spec, _stretches(box, tol), speed_limit, "run", solver):
                yield piece, done / m
            return
    for piece in plan_run(kin, printer, spec, speed_limit, solver=solver):
        yield piece, 1.0


def iter_run_parts(kin, printer, parts, speed_limit: str, solver: str = "fast"):
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
            yield _prepare(printer, spec.part(0, int(kept[-1])), None)
            pending = spec.part(int(kept[-1]), len(spec.points) - 1)
        if pending is not None:
            first.append(pending)  # the last: all of the run when no segment of it is longer than a micron
            yield _prepare(printer, pending, None)

    stretches = prepared()
    head = next(stretches)
    if len(head[0].points) < 2:  # the whole run shorter than a micron: its filament pushed at rest
        for piece in plan_run(kin, printer, first[-1], speed_limit, solver=solver):
            yield piece, taken[0]
        return
    for piece, _done in _iter_windows(kin, printer, first[0], itertools.chain([head], stretches), speed_limit, "run",
                                      solver):
        yield piece, taken[0]


@dataclass(frozen=True)
class _Polyline:
    """A run's polyline after deduplication and merging: points (m+1,3) mm; feed, e, power (m,)."""

    points: np.ndarray
    feed: np.ndarray
    e: np.ndarray
    power: np.ndarray | None

    def part(self, a: int, b: int) -> "_Polyline":
        """Vertices a..b (segments a..b-1)."""
        return _Polyline(self.points[a : b + 1], self.feed[a:b], self.e[a:b], None if self.power is None else self.power[a:b])


def _stretches(box: list, tol: float):
    """A prepared polyline (taken out of ``box``, so only this generator holds it) as consecutive
    stretches of WINDOW segments (views, not copies), each with the blend tolerance ``tol`` (mm)."""
    poly = box.pop()
    m = len(poly.points) - 1
    for a in range(0, m, WINDOW):
        yield poly.part(a, min(a + WINDOW, m)), tol


class _StartTooFast(PlanningError):
    """A window cannot start at the speed the previous one committed; ``speed``: the fastest it can (mm/s)."""

    def __init__(self, speed: float):
        super().__init__(f"start speed above {speed:.6g} mm/s")
        self.speed = speed


class _Held:
    """The polyline of a long run, split at its cuts, held from one vertex (``v0``, an index in the
    split polyline) to as far as the windows have looked: stretches are taken from the run's
    iterator as they are needed and the part before a window that can no longer be planned again
    is dropped, so what is held is a few windows whatever the run's length.

    stretches: (polyline, blend tolerance left, mm) pairs. seg: (k,) the held segments' lengths, mm
    (a cut segment's two halves once it is split); tol: (k,) the tolerance left where each came
    from; s0: the arc length at v0 (mm), summed segment by segment from the run's start as
    ``np.cumsum`` sums, so the lookahead's arc lengths are the same bits however the run arrives."""

    def __init__(self, stretches):
        self.stretches = stretches
        self.v0, self.s0, self.ended = 0, 0.0, False
        first, tol = next(stretches)
        self.poly = first
        self.seg = np.linalg.norm(np.diff(first.points, axis=0), axis=1)
        self.tol = np.full(len(self.seg), tol)

    @property
    def last(self) -> int:
        """The index of the last vertex held."""
        return self.v0 + len(self.seg)

    def pull(self) -> bool:
        """Take the next stretch; False when the run has ended."""
        if self.ended:
            return False
        nxt = next(self.stretches, None)
        if nxt is None:
            self.ended = True
            return False
        nxt, tol = nxt
        p, cat = self.poly, np.concatenate
        power = None if p.power is None else cat([p.power, nxt.power])
        self.poly = _Polyline(cat([p.points, nxt.points[1:]]), cat([p.feed, nxt.feed]), cat([p.e, nxt.e]), power)
        self.seg = cat([self.seg, np.linalg.norm(np.diff(nxt.points, axis=0), axis=1)])
        self.tol = cat([self.tol, np.full(len(nxt.points) - 1, tol)])
        return True

    def reach(self, v: int) -> None:
        """Hold vertex v, or up to the run's end."""
        while self.last < v and self.pull():
            pass

    def arc_ends(self) -> np.ndarray:
        """The arc length at the end of every held segment (mm, from the run's start)."""
        return np.cumsum(np.concatenate([[self.s0], self.seg]))[1:]

    def reach_arc(self, s: float) -> None:
        """Hold the run up to arc length s (mm), or to its end."""
        while (self.arc_ends()[-1] if len(self.seg) else self.s0) < s and self.pull():
            pass

    def split(self, c: int) -> None:
        """Split segment c at its middle: a new vertex c + 1, half the filament on either side."""
        i, p = c - self.v0, self.poly
        mid = 0.5 * (p.points[i] + p.points[i + 1])
        halves = np.linalg.norm(np.diff(np.stack([p.points[i : i + 1], mid[None], p.points[i + 1 : i + 2]], axis=1),
                                        axis=1), axis=2)[0]
        e = p.e.copy()
        e[i] *= 0.5
        power = None if p.power is None else np.insert(p.power, i + 1, p.power[i])
        self.poly = _Polyline(np.insert(p.points, i + 1, mid, axis=0), np.insert(p.feed, i + 1, p.feed[i]),
                              np.insert(e, i + 1, e[i]), power)
        self.seg = np.insert(self.seg, i + 1, halves[1])
        self.seg[i] = halves[0]
        self.tol = np.insert(self.tol, i + 1, self.tol[i])

    def drop_before(self, v: int) -> None:
        """Let go of the vertices before v (copied, so the memory goes)."""
        i = v - self.v0
        if i <= 0:
            return
        self.s0 = float(np.cumsum(np.concatenate([[self.s0], self.seg[:i]]))[-1])
        p = self.poly
        self.poly = _Polyline(p.points[i:].copy(), p.feed[i:].copy(), p.e[i:].copy(),
                              None if p.power is None else p.power[i:].copy())
        self.seg, self.tol = self.seg[i:].copy(), self.tol[i:].copy()
        self.v0 = v

    def part(self, a: int, b: int) -> tuple[_Polyline, float]:
        """Vertices a..b of the split polyline, and the blend tolerance left along them (mm)."""
        return self.poly.part(a - self.v0, b - self.v0), float(self.tol[a - self.v0 : b - self.v0].min())


def _next_cut(held: _Held, prev: int) -> int | None:
    """The vertex the next window ends at, after the one ending at vertex ``prev``: its segment split
    at the middle of the longest segment within WINDOW // 8 of WINDOW segments on (a straight point:
    no blend arc crosses it, both windows see the same geometry around it); None when fewer than
    WINDOW // 2 segments would follow it (the last window takes them)."""
    target = prev + WINDOW
    held.reach(target + WINDOW // 2 + 1)
    if not target < held.last - WINDOW // 2:
        return None
    lo, hi = target - WINDOW // 8, min(target + WINDOW // 8, held.last - 1)
    c = lo + int(np.argmax(held.seg[lo - held.v0 : hi - held.v0]))
    held.split(c)
    return c + 1


def _iter_windows(kin, printer, spec: RunSpec, stretches, speed_limit, kind, solver):
    """A long run planned window by window so the planner's memory is bounded by a window, not
    the run (a spiral vase is one run of a million moves). Each window plans its WINDOW
    segments plus a lookahead to rest, then keeps the part up to its cut, ending at the speed
    the lookahead allowed there; the next window starts at that speed, so the pieces join
    without stopping. Cuts are at the middle of the longest segment near every WINDOW-th
    (:func:`_next_cut`). A window that cannot start that fast (its grid refined differently)
    makes the previous one re-plan to the speed it can start at (so each piece is handed out
    only once its successor has started). ``stretches``: the run's prepared polyline in
    consecutive stretches with the blend tolerance left in each, taken as the windows reach them
    (:class:`_Held`); spec: the run (its tool, layer and power mode). Yields (piece, segments of
    the run done)."""
    held = _Held(stretches)
    ends = [0]  # the windows' first vertices, and the run's last once known
    final = False  # whether ends[-1] is the run's last vertex

    def add_cut() -> None:
        nonlocal final
        c = _next_cut(held, ends[-1])
        final = c is None
        ends.append(held.last if final else c)

    held_piece, starts, k = None, [0.0], 0  # held_piece: the last window's, until the next one starts
    caps = {}  # window -> the fastest its successor can start, after a re-plan
    while True:
        while not final and len(ends) < k + 2:
            add_cut()
        if k >= len(ends) - 1:
            break
        if k:
            held.drop_before(ends[k - 1])  # the previous window may still be planned again
        a, b = ends[k], ends[k + 1]
        last = final and k == len(ends) - 2
        end = b
        if not last:
            # Look ahead LOOKAHEAD segments and at least LOOKAHEAD_MM past the cut, every cut in
            # that stretch decided first.
            while True:
                held.reach(b + LOOKAHEAD)
                s_cut = held.arc_ends()[b - 1 - held.v0]
                held.reach_arc(s_cut + LOOKAHEAD_MM)
                far = held.v0 + int(np.searchsorted(held.arc_ends(), s_cut + LOOKAHEAD_MM)) + 1
                end = max(b + LOOKAHEAD, far)
                if held.ended:
                    end = min(held.last, end)
                # a cut is decided before the windows reach it: splitting a segment later would move
                # the arc lengths this lookahead was measured with (deciding one early changes nothing)
                if final or ends[-1] + WINDOW - WINDOW // 8 > end + 1:
                    break
                add_cut()
            held.reach(end)
        cap = None if last else (b - a, caps.get(k, np.inf))
        poly, tol = held.part(a, end)
        try:
            piece, cut_speed = _plan_polyline(kin, printer, spec, poly, speed_limit, tol, kind, solver,
                                              v_start=starts[k], cap=cap)
        except _StartTooFast as exc:
            if held_piece is None or k - 1 in caps:  # the previous piece is gone already, or was re-planned once
                raise PlanningError(f"layer {spec.layer}: a long run's windows do not join (start {starts[k]:.4g} mm/s, "
                                    f"at most {exc.speed:.4g} mm/s)") from None
            caps[k - 1] = exc.speed
            held_piece = None
            del starts[k:]
            k -= 1
            continue
        if held_piece is not None:
            yield held_piece, a - k
        held_piece = piece
        starts.append(cut_speed)
        k += 1
    yield held_piece, ends[-1] - (len(ends) - 2)


@dataclass(frozen=True)
class _PathInputs:
    """What the solver takes of a prepared run besides the limits: the blended path; e_ratio (k,)
    filament per mm of each piece and cum_e (k+1,) filament at each piece start, mm; extruder:
    whether filament moves (else the tool channel is not planned); piece_feed (k,) mm/s feed cap
    per piece; stop_at: arc lengths (mm) where the path must be at rest."""

    path: BlendedPath
    e_ratio: np.ndarray
    cum_e: np.ndarray
    extruder: bool
    piece_feed: np.ndarray
    stop_at: np.ndarray


def _path_inputs(poly: _Polyline, tol: float, speed_limit: str) -> _PathInputs:
    """A prepared polyline blended within ``tol`` (mm) and what the solver needs along it."""
    return _path_inputs_many([poly], [tol], speed_limit)[0]


def _path_inputs_many(polys: list, tols, speed_limit: str) -> list:
    """:func:`_path_inputs` of each prepared polyline (each blended within its tolerance, mm), in
    one pass over them all (:func:`.blend.blend_runs`): the same arrays, at a fraction of the
    per-call cost of runs a few dozen segments long."""
    counts = np.array([len(p.points) for p in polys])
    starts = np.concatenate([[0], np.cumsum(counts)])
    pts = np.concatenate([p.points for p in polys]) if len(polys) > 1 else polys[0].points
    runs = blend_runs(pts, starts, np.asarray(tols, dtype=float))
    e = np.concatenate([p.e for p in polys]) if len(polys) > 1 else polys[0].e
    feed = np.concatenate([p.feed for p in polys]) if len(polys) > 1 else polys[0].feed
    n_runs = len(polys)
    seg_start = starts - np.arange(n_runs + 1)  # run r's segments: seg_start[r]..seg_start[r+1]-1
    run = np.repeat(np.arange(n_runs), np.diff(runs.offsets))  # each piece's run
    seg = seg_start[run] + runs.segment  # each piece's polyline segment, counted across the runs

    # Filament per mm of each piece: the polyline segment's own ratio, so the filament
    # pushed is always that ratio times the arc length driven (blend arcs included) and
    # the bead is what the slicer asked for; blending a corner shortens the path and the
    # filament with it.
    own = np.ones(len(pts) - 1, dtype=bool)  # the pairs of points that are a run's segment
    own[starts[1:-1] - 1] = False
    seg_ratio = e / np.linalg.norm(np.diff(pts, axis=0)[own], axis=1)
    e_ratio = seg_ratio[seg]
    piece_len = np.diff(runs.piece_start)
    piece_len = np.delete(piece_len, runs.offsets[1:-1] + np.arange(n_runs - 1)) if n_runs > 1 else piece_len
    # Where the filament per mm changes (a new extrusion width) the filament speed would step,
    # an unbounded filament acceleration: such a join is taken at rest (rare: a role change
    # inside one run).
    jump = np.zeros(len(e_ratio), dtype=bool)  # at the piece's start
    jump[1:] = np.abs(np.diff(e_ratio)) > 0.01 * np.maximum(np.abs(e_ratio[1:]), np.abs(e_ratio[:-1]))
    first = runs.offsets[:-1]
    jump[first[first < len(jump)]] = False  # a run's first piece (a run may have none)
    # Between those joins the filament per mm is the stretch's mean: a smaller change (widths of
    # one role, rounding) still stepped the filament speed, a finite-difference acceleration that
    # grows with the sample rate (1.15 of the limit at 10 kHz). The stretch pushes the filament it
    # asked for; each move in it, the stretch's mean per mm (its own was within 1 % of its neighbours').
    head = jump.copy()
    head[first[first < len(head)]] = True
    stretch = np.cumsum(head) - 1
    length = np.bincount(stretch, weights=piece_len)
    mean = np.bincount(stretch, weights=e_ratio * piece_len) / np.where(length > 0, length, 1.0)
    e_ratio = np.where(length[stretch] > 0, mean[stretch], e_ratio)
    cum_e = np.empty(len(e_ratio) + n_runs)
    run_cumsum(e_ratio * piece_len, runs.offsets, cum_e)

    # The tool channel only where filament moves (a laser's e is zero): all-zero rows make the
    # LP degenerate.
    extruder = np.bincount(np.repeat(np.arange(n_runs), np.diff(seg_start)), weights=e != 0, minlength=n_runs) > 0
    seg_feed = feed if speed_limit == "feed" else np.full(len(feed), np.inf)
    # An arc is capped by the slower of the segments it joins.
    prev_seg = seg - (runs.segment > 0)
    piece_feed = np.where(runs.kind == 1, np.minimum(seg_feed[seg], seg_feed[prev_seg]), seg_feed[seg])
    out = []
    for r in range(n_runs):
        a, b = int(runs.offsets[r]), int(runs.offsets[r + 1])
        path = runs.path(r)
        stop_at = runs.stops(r)
        if extruder[r] and b - a > 1:
            stop_at = np.concatenate([stop_at, path.piece_start[:-1][jump[a:b]]])
        out.append(_PathInputs(path, e_ratio[a:b], cum_e[a + r : b + r + 1], bool(extruder[r]), piece_feed[a:b], stop_at))
    return out


def _plan_polyline(kin, printer, spec: RunSpec, poly: _Polyline, speed_limit: str, tol: float, kind: str, solver: str,
                   v_start: float = 0.0, cap: tuple | None = None):
    """One RunPiece along a polyline from the path speed v_start (mm/s) to rest; with
    ``cap = (vertex, speed)`` the path speed at that vertex is capped (mm/s) and the piece is
    cut there (the part after it was only the lookahead). Returns (piece, speed at its end)."""
    inputs = _path_inputs(poly, tol, speed_limit)
    path, e_ratio, cum_e, extruder = inputs.path, inputs.e_ratio, inputs.cum_e, inputs.extruder
    feed = poly.feed
    s_cut = None if cap is None else float(path.piece_start[np.searchsorted(path.segment, cap[0])])
    sol = _solve_path(kin, printer, spec.layer, path, e_ratio if extruder else None, inputs.piece_feed, inputs.stop_at,
                      solver, v_start=v_start, cap=None if cap is None else (s_cut, cap[1]))
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
    q_ends = RunPath(kin, path, None, spec.layer)(np.array([0.0, 1.0]))
    piece = RunPiece(path, S, x_grid, sd, xdd, t, cum_e, e_ratio, spec.tool, spec.layer, float(dt[active].sum()), kind,
                     q_ends[0], q_ends[1], power=power, nominal_feed=nominal, dynamic_power=spec.dynamic_power)
    return piece, float(sd[-1] * S)


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


def _solve_path(kin, printer, layer: int, path: BlendedPath, e_ratio, piece_feed, stop_at, solver: str,
                v_start: float = 0.0, cap: tuple | None = None, conservative: bool = True,
                unit_length: np.ndarray | None = None, unit_id: np.ndarray | None = None) -> _Profile:
    """The time-optimal speed profile along a blended path from path speed v_start (mm/s) to rest,
    refined where the stage-wise check finds a limit exceeded.

    e_ratio: (k,) filament per mm of each piece, or None when the tool channel is not planned (no
    filament moves); piece_feed: (k,) feed cap per piece, mm/s (inf: none); stop_at: arc lengths
    (mm) where the path must be at rest; cap: (s, speed) the path speed capped at arc length s (a
    window's cut); conservative: fall back to one constant-acceleration profile when the solver
    finds none (else PlanningError); unit_length: (k,) mm, for a path of moves that meet at rest
    (:func:`plan_lines`), the length of the move each piece belongs to: the compiled solver works
    in each move's own units; unit_id: (k,) int, which move each piece belongs to, so a stage is
    refined with its neighbours in its own move only (as planning that move alone would). The
    planner plans to the margin-reduced limits and checks the real ones; where the printer has
    ``[dynamics]`` (and the compiled solver plans), the actuators' torque too (:mod:`.torque`)."""
    S = path.length
    tq = torque_limits(printer) if solver == "fast" else None
    planned, limits = printer.planned_limits(), printer.limits
    channels = limits.n_channels if e_ratio is not None else limits.n_joints
    vmax, amax = planned.velocity[:channels], planned.acceleration[:channels]
    true_v, true_a = limits.velocity[:channels], limits.acceleration[:channels]
    s_grid = grid(path, stop_at if cap is None or cap[1] > 0 else None)  # a cut capped to rest may be anywhere
    rp = RunPath(kin, path, e_ratio, layer)

    def cut_g(grid_s):
        return int(np.argmin(np.abs(grid_s - cap[0])))

    for attempt in range(REFINE_PASSES + 1):
        x_grid = s_grid / S
        x_grid[0], x_grid[-1] = 0.0, 1.0
        # Feed cap at a grid point: the slower of the pieces on its two sides.
        before = path.locate(np.maximum(s_grid - 1e-9, 0.0))
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
        unit = None if unit_length is None else S / unit_length[path.locate(s_grid)]
        rows = _fast_rows(constraints, rp, x_grid, amax, unit) if solver == "fast" else None
        if tq is None:
            sd, top = _speeds(constraints, rp, x_grid, rows, v_start / S, unit)
        else:
            # at the check's fractions: at the solver's three alone, the check's bound (their second
            # difference) refines more stages and batches, for more time than the two others cost
            model = stage_torque(printer, rp, x_grid, CHECK, dq_check, ddq_check)
            # every grid from the same first tangents (not the last grid's solution): a run refined in
            # a batch leaves the others' stages as they are alone
            mid_s = 0.5 * (s_grid[:-1] + s_grid[1:])
            x0, floor = cruise_x(model, tq, vmax[: printer.n_joints], (piece_feed[path.locate(mid_s)] / S) ** 2,
                                 len(CHECK) // 2)
            sd, top, x0 = solve_with_torque(model, tq, x_grid, rows, EVAL_IN_CHECK, EVAL, x0, floor,
                                            lambda r: _speeds(constraints, rp, x_grid, r, v_start / S, unit), unit)
        if v_start > 0:
            # A start speed outside the controllable set is refused even when the solver, which
            # tolerates a small excess (toppra's), found a profile: its forward pass would cut the
            # speed where the excess meets a limit, a step of many times the acceleration limit
            # (a window of a spiral vase on linear_kossel). The previous window re-plans instead.
            fastest = (_start_speed(constraints, rp, x_grid) if top is None else _root(top)) * S
            if v_start > fastest * (1 + 1e-9):
                raise _StartTooFast(fastest)
        if sd is None or not np.all(np.isfinite(sd)):
            # Seidel's 2-D LP occasionally meets a degenerate stage; a conservative profile from
            # the same limits is always feasible (and slower only on this run).
            sd = None if v_start > 0 or not conservative else _conservative_profile(
                x_grid, dq_st, ddq_st, vmax, amax, feed_grid / S)
            if sd is None:
                raise PlanningError(_infeasible(printer, layer, path, s_grid, 0, vmax, dq_st))
        sd = np.maximum(sd, 0.0)
        dx = np.diff(x_grid)
        vsum = sd[:-1] + sd[1:]
        if not np.all(vsum > 0):
            raise PlanningError(_infeasible(printer, layer, path, s_grid, int(np.flatnonzero(vsum <= 0)[0]), vmax, dq_st))
        dt = 2 * dx / vsum
        # Constant acceleration per stage consistent with the end speeds.
        xdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2 * dx)
        check = stage_maxima(rp, x_grid, sd, xdd, true_v, true_a, stage=(dq_check, ddq_check))
        bad = check.per_stage > 1.0 + CHECK_TOLERANCE
        if tq is not None:
            torque = stage_check(model, tq, CHECK, sd, xdd, x0)
            bad |= ~(torque.per_stage <= 1.0 + CHECK_TOLERANCE)
        if not bad.any():
            break
        if attempt == REFINE_PASSES and tq is not None and np.max(torque.use) > 1.0 + CHECK_TOLERANCE:
            j = int(np.argmax(torque.use))
            p = path.evaluate(np.array([s_grid[int(torque.stage[j])]]))[0]
            raise PlanningError(
                f"layer {layer}: {_describe(printer, j)} uses {100 * torque.use[j]:.2f} % of its torque (speed-torque "
                f"line) between grid points at x = {p[0]:.2f}, y = {p[1]:.2f}, z = {p[2]:.2f} mm after "
                f"{REFINE_PASSES} grid refinements")
        if attempt == REFINE_PASSES:
            ch = int(np.argmax(np.maximum(check.velocity, check.acceleration)))
            kind = "velocity" if check.velocity[ch] >= check.acceleration[ch] else "acceleration"
            st = int(check.stage_v[ch] if kind == "velocity" else check.stage_a[ch])
            raise PlanningError(
                f"layer {layer}: {_describe(printer, ch)} {kind} reaches "
                f"{100 * max(check.velocity[ch], check.acceleration[ch]):.2f} % of its limit "
                f"{_stage_place(path, s_grid, st, e_ratio if ch == printer.n_joints else None)} "
                f"after {REFINE_PASSES} grid refinements"
            )
        # Split the offending stages (and their neighbours) in four and plan again.
        idx = np.flatnonzero(bad)
        near = np.clip(np.concatenate([idx - 1, idx, idx + 1]), 0, len(dx) - 1)
        if unit_id is not None:
            owner = unit_id[path.locate(0.5 * (s_grid[:-1] + s_grid[1:]))]
            near = near[owner[near] == np.tile(owner[idx], 3)]
        idx = np.unique(near)
        extra = (s_grid[idx, None] + np.diff(s_grid)[idx, None] * SHORT_FRACTIONS[None]).ravel()
        s_grid = np.unique(np.concatenate([s_grid, extra]))
    t = np.concatenate([[0.0], np.cumsum(dt)])

    # Which stages have a limit active (the optimality certificate): the speed at its
    # first-order cap, or some joint's acceleration at its limit.
    cap2 = rows[3] if rows is not None else constraints[0].cap2(rp, x_grid)
    active = np.empty(len(xdd), dtype=bool)
    _active_kernel(dq_check, ddq_check, xdd, sd, cap2, amax, active)  # fraction 0 of either; these are contiguous
    if tq is not None:
        active |= torque.per_stage >= ACTIVE * float(np.min(tq.planned / tq.stall))
    return _Profile(s_grid, x_grid, sd, xdd, t, dt, active, -1 if cap is None else cut_g(s_grid))


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


def _fast_rows(constraints, rp, x_grid, amax, unit=None):
    """What the compiled solver takes, computed once per grid: (a, b, bound, cap2), the
    acceleration rows a u + b x in [-bound, bound] and the bound on x_dot^2 (see _speeds); with
    ``unit`` (see _speeds) the rows in each move's own units, cap2 in the path's."""
    # The filament's rows, the same at every fraction, once: the solver's result is the same
    # (identical bounds), its pairing of bounds much cheaper (identical lines all survive pruning).
    once = rp.e_ratio is not None
    a, b = constraints[1].rows(rp, x_grid, unit, once)
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


def _segment_power(spec: RunSpec, pts: np.ndarray) -> np.ndarray:
    """The laser power of each segment of the planned polyline ``pts`` (after deduplication and
    merging): the power of the toolpath segment it ends in."""
    from scipy.spatial import cKDTree

    # the kept vertices are vertices of the toolpath's own polyline
    _d, k = cKDTree(spec.points[1:]).query(pts[1:])
    return spec.power[k]


def _infeasible(printer, layer, path, s_grid, i, vmax, dq_st) -> str:
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
        f"{_describe(printer, ch)} velocity limit {vmax[ch]:.4g} allows {cap[ch] * path.length:.3g} mm/s of path there"
    )


def plan_lines(kin, printer, starts: np.ndarray, ends: np.ndarray, feed: np.ndarray, layers: np.ndarray, speed_limit: str,
               kind: str = "travel", solver: str = "fast") -> list:
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
        return plan_run(kin, printer, spec, speed_limit, kind=kind, solver=solver)

    if solver != "fast" or len(moving) == 1:
        for i in moving:
            out[i] = alone(i)
        return out
    a, L = starts[moving], length[moving]
    d = (ends[moving] - a) / L[:, None]
    k = len(moving)
    piece_start = np.concatenate([[0.0], np.cumsum(L)])
    path = BlendedPath(piece_start, np.zeros(k, dtype=np.int8), a, d, np.zeros((k, 3)), np.full(k, np.inf), np.arange(k))
    piece_feed = feed[moving] if speed_limit == "feed" else np.full(k, np.inf)
    try:
        profiles = _solve_units(kin, printer, int(layers[moving[0]]), path, None, piece_feed, np.zeros(0), solver, L,
                                np.arange(k))
    except DeltasliceError:
        for i in moving:
            out[i] = alone(i)
        return out
    q = kin.inverse(np.concatenate([a, a + L[:, None] * d]))
    for r, (i, (x, xd, xdd, t, active_time)) in enumerate(zip(moving, profiles)):
        line = BlendedPath(np.array([0.0, L[r]]), path.kind[r : r + 1], a[r : r + 1], d[r : r + 1], path.normal[r : r + 1],
                           path.radius[r : r + 1], np.zeros(1, dtype=path.segment.dtype))
        out[i] = [RunPiece(line, float(L[r]), x, xd, xdd, t, np.zeros(2), np.zeros(1), 0.0, int(layers[i]), active_time,
                           kind, q[r], q[k + r])]
    return out


def _solve_units(kin, printer, layer: int, path: BlendedPath, e_ratio, piece_feed, stop_at, solver: str,
                 lengths: np.ndarray, unit_of_piece: np.ndarray) -> list:
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
    sol = _solve_path(kin, printer, layer, path, e_ratio, piece_feed, np.concatenate([offsets[1:-1], stop_at]), solver,
                      conservative=False, unit_length=lengths[unit_of_piece], unit_id=unit_of_piece)
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


def plan_runs(kin, printer, specs, speed_limit: str, solver: str = "fast") -> list:
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
        return _plan_runs(kin, printer, specs, speed_limit, solver)
    except DeltasliceError:
        return [plan_run(kin, printer, spec, speed_limit, solver=solver) for spec in specs]


def _plan_runs(kin, printer, specs, speed_limit: str, solver: str) -> list:
    out = [None] * len(specs)
    # by extruder (a batch plans the tool channel for all its runs or none): [[(index, inputs)]], and
    # the path pieces in each side's last batch
    batches, size = {True: [], False: []}, {True: 0, False: 0}
    batched, prepared = [], []
    for i, spec in enumerate(specs):
        alone = solver != "fast" or spec.power is not None or is_long(len(spec.points) - 1)
        deduped = None if alone else dedupe(spec.points, spec.feed, spec.e)
        if deduped is None or len(deduped[0]) < 2:
            out[i] = plan_run(kin, printer, spec, speed_limit, solver=solver)
            continue
        batched.append(i)
        prepared.append(_prepare(printer, spec, None, deduped))
    every = _path_inputs_many([p for p, _tol in prepared], [tol for _p, tol in prepared], speed_limit) if prepared else []
    for i, inputs in zip(batched, every):
        groups, side = batches[inputs.extruder], inputs.extruder
        if not groups or size[side] + len(inputs.path.kind) > BATCH_PIECES:
            groups.append([])
            size[side] = 0
        groups[-1].append((i, inputs))
        size[side] += len(inputs.path.kind)
    for extruder, groups in batches.items():
        for group in groups:
            for (i, _inputs), pieces in zip(group, _plan_batch(kin, printer, specs, group, extruder, speed_limit, solver)):
                out[i] = pieces
    return out


def _plan_batch(kin, printer, specs, group, extruder: bool, speed_limit: str, solver: str) -> list:
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
        profiles = _solve_units(kin, printer, specs[group[0][0]].layer, path, e_ratio, feed, stop_at, solver, lengths,
                                np.repeat(np.arange(len(group)), counts))
        last = np.cumsum(counts) - 1
        q = kin.inverse(np.concatenate([path.p0[last - counts + 1], path.evaluate(offsets[1:], 0, last)]))
        if not np.isfinite(q).all():
            raise PlanningError("a run's end is out of reach")
    except DeltasliceError:
        return [plan_run(kin, printer, specs[i], speed_limit, solver=solver) for i, _inputs in group]
    k = len(group)
    return [[RunPiece(inputs.path, float(lengths[r]), x, xd, xdd, t, inputs.cum_e, inputs.e_ratio, specs[i].tool,
                      specs[i].layer, active_time, "run", q[r], q[k + r], dynamic_power=specs[i].dynamic_power)]
            for r, ((i, inputs), (x, xd, xdd, t, active_time)) in enumerate(zip(group, profiles))]
