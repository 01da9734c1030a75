"""Time-optimal parameterisation of one run in joint space, with toppra.

A run (a continuous extrusion or laser-on polyline) is blended
(:mod:`.blend`), mapped through the inverse kinematics and parameterised by a
normalised path coordinate x = s / S in [0, 1] (s: arc length in mm, S: run
length): toppra's seidel solver is badly conditioned when the path parameter
is in mm. The path handed to toppra has one coordinate per joint plus the
filament position (extruders), so

* joint and filament velocity limits and the feed cap become one grid-wide
  bound on x_dot^2 (:class:`PathVelocityConstraint`),
* joint and filament acceleration limits are toppra's
  ``JointAccelerationConstraint`` (interpolation discretisation),

all reduced by the printer's ``limit_margin`` because toppra enforces them at
grid points only. The grid is refined geometrically toward every line/arc join
with points on both sides of each, so braking before a corner is resolved
without a fine grid on long lines.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import toppra
import toppra.algorithm
import toppra.constraint
from toppra.constraint.linear_constraint import LinearConstraint
from toppra.interpolator import AbstractGeometricPath

from ..errors import PlanningError, UnreachableError
from .blend import BlendedPath, blend_polyline, dedupe
from .fastpath import fast_speeds, grid_derivatives, velocity_cap2
from .pieces import FilamentPiece, RunPiece

logging.getLogger("toppra").setLevel(logging.ERROR)

# Grid: spacing grows geometrically from each join up to MAX_STEP (mm).
MIN_STEP = 0.01
MAX_STEP = 2.0
GROWTH = 2.0
ARC_STEP = 0.15  # rad of tangent turn between grid points inside a blend arc
REFINE = 1  # stages per grid interval; tests set 10 to check grid convergence
ACTIVE = 0.95  # a limit counts as active within 5 % of it


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


class RunPath(AbstractGeometricPath):
    """The run as toppra sees it: x in [0, 1] -> (q_1..q_J[, e]) with analytic first
    derivatives (inverse Jacobian times tangent) and one-sided second derivatives
    taken inside the piece a grid point starts (toppra's collocation uses the stage
    ahead of each grid point)."""

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
        p = self.path.evaluate(s, 0, piece)
        q = self.kin.inverse(p)
        bad = ~np.all(np.isfinite(q), axis=1)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise UnreachableError(
                f"layer {self.layer}: point x = {p[i, 0]:.2f}, y = {p[i, 1]:.2f}, z = {p[i, 2]:.2f} mm is out of reach"
            )
        return p, q

    def _first(self, s, piece):
        p, q = self._ik(s, piece)
        jinv = self.kin.inverse_jacobian(q) if not hasattr(self.kin, "inverse_jacobian_at") else self.kin.inverse_jacobian_at(p, q)
        dq = np.einsum("nij,nj->ni", jinv, self.path.evaluate(s, 1, piece)) * self.S
        return q, dq

    def __call__(self, xs, order=0):
        xs = np.atleast_1d(np.asarray(xs, dtype=float))
        s = np.clip(xs, 0.0, 1.0) * self.S
        piece = self.path.locate(s)
        if order == 0:
            out = self._ik(s, piece)[1]
            if self.e_ratio is not None:
                out = np.column_stack([out, s * 0])  # e enters only through its derivatives
            return out
        if order == 1:
            dq = self._first(s, piece)[1]
            if self.e_ratio is not None:
                dq = np.column_stack([dq, self.e_ratio[piece] * self.S])
            return dq
        # Second derivative: forward difference of the exact first derivative, inside the piece.
        end = self.path.piece_start[piece + 1]
        h = np.minimum(1e-4, np.maximum((end - s) / 3, 0))
        back = h <= 1e-9
        h = np.where(back, 1e-4, h)
        s2 = np.where(back, np.maximum(s - h, 0), s + h)
        d1 = self._first(s, piece)[1]
        d2 = self._first(s2, piece)[1]
        ddq = (d2 - d1) / (np.where(back, -h, h)[:, None] / self.S)
        if self.e_ratio is not None:
            ddq = np.column_stack([ddq, np.zeros(len(s))])
        return ddq


class PathVelocityConstraint(LinearConstraint):
    """Every first-order limit at once, over the whole grid: joint (and filament)
    velocity limits through q'(x), and the feed cap on the Cartesian speed S x_dot.
    Returns only toppra's ``xbound`` (bounds on x_dot^2)."""

    def __init__(self, vmax: np.ndarray, feed_at_grid: np.ndarray, S: float):
        super().__init__()
        self.vmax = np.asarray(vmax, dtype=float)
        self.dof = len(self.vmax)
        self.feed = np.asarray(feed_at_grid, dtype=float)
        self.S = S
        self._format_string = "    path velocity (joints, filament, feed)\n"

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        dq = np.abs(path(gridpoints, 1))
        with np.errstate(divide="ignore"):
            cap = np.min(self.vmax[None] / dq, axis=1)
        cap = np.minimum(cap, self.feed / self.S)
        xbound = np.zeros((len(gridpoints), 2))
        xbound[:, 1] = cap**2
        return None, None, None, None, None, None, xbound


def grid(path: BlendedPath) -> np.ndarray:
    """Grid in arc length (mm): from every join, steps growing geometrically from
    MIN_STEP to MAX_STEP on both sides, so every join has close neighbours on
    both sides and long lines get few stages (the gap where the two sequences of a
    piece meet is at most 2 MAX_STEP). (n,) sorted, includes 0 and S."""
    joins = np.concatenate([[0.0], path.joins(), [path.length]])
    half = np.diff(joins) / 2  # each interval is refined from both its ends toward its middle
    steps = [MIN_STEP]
    total = MIN_STEP
    while total < half.max():
        steps.append(min(steps[-1] * GROWTH, MAX_STEP))
        total += steps[-1]
    offsets = np.cumsum(steps)
    inside = offsets[None, :] < half[:, None] * 0.999
    left = joins[:-1, None] + offsets[None, :]
    right = joins[1:, None] - offsets[None, :]
    # Inside arcs the acceleration direction turns with the tangent: one point per ARC_STEP rad.
    arc = np.flatnonzero(path.kind == 1)
    arc_len = path.piece_start[arc + 1] - path.piece_start[arc]
    count = np.ceil(arc_len / (ARC_STEP * path.radius[arc])).astype(int)
    owner = np.repeat(np.arange(len(arc)), count)
    within = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    on_arcs = path.piece_start[arc][owner] + arc_len[owner] * within / count[owner]
    g = np.unique(np.concatenate([joins, left[inside], right[inside], on_arcs]))
    # Points closer than 1e-7 mm add nothing but ill-conditioned stages.
    keep = np.concatenate([[True], np.diff(g) > 1e-7])
    g = g[keep]
    g[-1] = path.length
    if REFINE > 1:  # uniform subdivision of every stage (convergence checks)
        f = np.arange(REFINE) / REFINE
        g = np.concatenate([(g[:-1, None] + np.diff(g)[:, None] * f[None]).ravel(), g[-1:]])
    return g


def _conservative_profile(rp, x, vmax, amax, xd_cap):
    """Path speeds (n,) at the grid x for one constant path acceleration A and speed cap V
    that satisfy every limit at every grid point whatever the signs: |q'| V <= vmax and
    |q'| A + |q''| V^2 <= amax. Returns None when no positive speed is possible."""
    d1, d2 = np.abs(rp(x, 1)), np.abs(rp(x, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        v = min(float(np.min(vmax[None] / d1)), float(np.min(xd_cap)))
        v = min(v, float(np.sqrt(0.5 * np.min(amax[None] / d2))))
        a = float(np.min((amax[None] - d2 * v * v) / d1))
    if not (v > 0 and a > 0 and np.isfinite(v) and np.isfinite(a)):
        return None
    return np.minimum(v, np.sqrt(2 * a * np.minimum(x, 1.0 - x).clip(0)))


def plan_run(kin, printer, spec: RunSpec, speed_limit: str, tolerance: float | None = None, kind: str = "run",
             solver: str = "fast") -> list:
    """Plan one run from rest to rest: a list of pieces (usually one RunPiece).

    kin: the printer's kinematics; tolerance: blend tolerance, mm (default: the printer's);
    solver: "fast" (:mod:`.reachability`) or "toppra" (the same problem through toppra's seidel solver);
    kind: the pieces' kind ("run", or "travel" for a straight travel). A run shorter than a
    micron is its filament pushed at rest (or nothing); in the rare case toppra's numerics
    fail on a whole run, the pieces of its two halves (split at a vertex, each from rest to rest)."""
    if len(dedupe(spec.points, spec.feed, spec.e)[0]) < 2:
        amount = float(spec.e.sum())
        if amount == 0:
            return []
        limits = printer.limits
        q = kin.inverse(spec.points[-1:])[0]
        return [FilamentPiece(q, amount, float(limits.velocity[-1]), float(limits.acceleration[-1]), spec.layer, kind=kind)]
    try:
        return [_plan_run(kin, printer, spec, speed_limit, tolerance, kind, solver)]
    except PlanningError:
        m = len(spec.points) - 1
        if m < 2:
            raise
        h = m // 2
        return [p for part in (spec.part(0, h), spec.part(h, m)) for p in plan_run(kin, printer, part, speed_limit, tolerance, kind, solver)]


def _plan_run(kin, printer, spec: RunSpec, speed_limit: str, tolerance: float | None, kind: str, solver: str) -> RunPiece:
    pts, feed, e = dedupe(spec.points, spec.feed, spec.e)
    path = blend_polyline(pts, printer.planning.blend_tolerance if tolerance is None else tolerance)
    S = path.length

    # Filament per mm of each piece: the polyline segment's own ratio (equal widths stay equal),
    # scaled once for the run so the blended (slightly shorter) path pushes exactly the
    # toolpath's filament.
    seg_ratio = e / np.linalg.norm(np.diff(pts, axis=0), axis=1)
    e_ratio = seg_ratio[path.segment]
    pushed = float(np.dot(e_ratio, np.diff(path.piece_start)))
    if pushed != 0.0:
        e_ratio = e_ratio * (float(e.sum()) / pushed)
    cum_e = np.concatenate([[0.0], np.cumsum(e_ratio * np.diff(path.piece_start))])

    # The tool channel only where filament moves (a laser's e is zero): all-zero rows make
    # toppra's LP degenerate.
    extruder = bool(np.any(e != 0))
    limits = printer.planned_limits()
    channels = limits.n_channels if extruder else limits.n_joints
    vmax, amax = limits.velocity[:channels], limits.acceleration[:channels]

    s_grid = grid(path)
    piece = path.locate(s_grid)
    seg_feed = feed if speed_limit == "feed" else np.full(len(feed), np.inf)
    # An arc is capped by the slower of the segments it joins.
    prev_seg = np.maximum(path.segment - 1, 0)
    piece_feed = np.where(path.kind == 1, np.minimum(seg_feed[path.segment], seg_feed[prev_seg]), seg_feed[path.segment])
    feed_grid = piece_feed[piece].copy()
    feed_grid[np.isin(s_grid, path.stops())] = 0.0  # a tangent break is taken at rest
    if extruder and len(path.kind) > 1:
        # Where the filament per mm changes (a new extrusion width) the filament speed would step,
        # an unbounded filament acceleration: such a join is taken at rest (rare: a role change
        # inside one run).
        jump = np.abs(np.diff(e_ratio)) > 0.01 * np.maximum(np.abs(e_ratio[1:]), np.abs(e_ratio[:-1]))
        at = np.clip(np.searchsorted(s_grid, path.piece_start[1:-1][jump]), 0, len(s_grid) - 1)
        feed_grid[at] = 0.0

    rp = RunPath(kin, path, e_ratio if extruder else None, spec.layer)
    x_grid = s_grid / S
    x_grid[0], x_grid[-1] = 0.0, 1.0
    if solver == "fast":
        dq, ddq = grid_derivatives(rp, x_grid)
        cap2 = velocity_cap2(dq, vmax, feed_grid, S)
        sd = fast_speeds(dq, ddq, amax, cap2, x_grid)
    else:
        constraints = [
            PathVelocityConstraint(vmax, feed_grid, S),
            toppra.constraint.JointAccelerationConstraint(
                amax, discretization_scheme=toppra.constraint.DiscretizationType.Interpolation
            ),
        ]
        algo = toppra.algorithm.TOPPRA(constraints, rp, gridpoints=x_grid, solver_wrapper="seidel")
        sdd, sd, _ = algo.compute_parameterization(0.0, 0.0)
        cap2 = constraints[0].compute_constraint_params(rp, x_grid)[-1][:, 1]
        dq, ddq = rp(x_grid, 1), rp(x_grid, 2)
    if sd is None or not np.all(np.isfinite(sd)):
        # Seidel's 2-D LP occasionally meets a degenerate stage; a conservative profile from
        # the same limits is always feasible (and slower only on this run).
        sd = _conservative_profile(rp, x_grid, vmax, amax, feed_grid / S)
        if sd is None:
            raise PlanningError(
                f"layer {spec.layer}: no feasible speed profile for the run starting at "
                f"x = {pts[0, 0]:.2f}, y = {pts[0, 1]:.2f} mm (near a singularity or limit)"
            )
    dx = np.diff(x_grid)
    vsum = sd[:-1] + sd[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        dt = np.where(vsum > 0, 2 * dx / vsum, np.inf)
    if not np.all(np.isfinite(dt)):
        raise PlanningError(f"layer {spec.layer}: path speed stays zero along a run (limits too tight)")
    # Constant acceleration per stage consistent with the end speeds.
    xdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2 * dx)
    t = np.concatenate([[0.0], np.cumsum(dt)])

    # Which stages have a limit active (the optimality certificate): the speed at its
    # first-order cap, or some joint's acceleration at its limit.
    acc = np.abs(dq[:-1] * xdd[:, None] + ddq[:-1] * (sd[:-1] ** 2)[:, None]) / amax[None]
    active = (sd[:-1] ** 2 >= ACTIVE * cap2[:-1]) | (sd[1:] ** 2 >= ACTIVE * cap2[1:]) | (acc.max(axis=1) >= ACTIVE)
    q_ends = rp(np.array([0.0, 1.0]))[:, : kin.n_joints]
    power = nominal = None
    if spec.power is not None:
        # dedupe drops the same segments from any per-segment array passed as its feed
        power = dedupe(spec.points, spec.power, spec.e)[1][path.segment]
        nominal = feed[path.segment]
    return RunPiece(path, S, x_grid, sd, xdd, t, cum_e, e_ratio, spec.tool, spec.layer, float(dt[active].sum()), kind,
                    q_ends[0], q_ends[1], power=power, nominal_feed=nominal, dynamic_power=spec.dynamic_power)
