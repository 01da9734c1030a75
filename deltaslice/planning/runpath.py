"""The path model of a run: the run as the toolpath gives it (:class:`RunSpec`), prepared
(:class:`Polyline`), blended with what the solver needs along it (:class:`PathInputs`), and the
map from the normalised path coordinate x = s / S to the joints and filament
(:class:`RunPath`, toppra's geometric-path interface)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UnreachableError
from .blend import BlendedPath, blend_runs, run_cumsum


DERIVATIVE_BLOCK = 32768  # points per inverse-kinematics call in RunPath.derivatives


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
        bad = self.kin.scaled_path_derivatives(p, t, kappa, self.S, dq, ddq)  # the joints' columns
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


def _segment_power(spec: RunSpec, pts: np.ndarray) -> np.ndarray:
    """The laser power of each segment of the planned polyline ``pts`` (after deduplication and
    merging): the power of the toolpath segment it ends in."""
    from scipy.spatial import cKDTree

    # the kept vertices are vertices of the toolpath's own polyline
    _d, k = cKDTree(spec.points[1:]).query(pts[1:])
    return spec.power[k]
