"""Corner blending: a polyline made tangent-continuous inside a tolerance band.

Every interior corner of a run is replaced by a circular arc tangent to both
segments. The arc's radius is the largest that keeps its midpoint within
``tolerance`` of the corner (the farthest any point of the blend is from the
original path) and whose set-back uses at most half of each adjacent segment,
so neighbouring blends never overlap. The result is a :class:`BlendedPath`:
alternating line and arc pieces parameterised by arc length s (mm), evaluated
vectorised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..jit import njit
from .tolerances import DIVISION_FLOOR, SQUARED_FLOOR, STRAIGHT, ZERO_LENGTH

_MIN_TURN = 1e-6  # rad: straighter corners are not blended
# rad: a corner within this of a full reversal is taken at rest (its arc would be shorter
# than a micron, with a curvature no joint can follow at any useful speed).
_REVERSAL = 1e-3
DEDUPE_EPS = 1e-3  # mm: dedupe's shortest segment kept


@dataclass(frozen=True)
class BlendedPath:
    """A tangent-continuous path: pieces in order, alternating line and arc.

    piece_start: (k+1,) cumulative arc length at each piece start, mm (last = total length)
    kind: (k,) 0 line, 1 arc
    p0: (k,3) start point of each piece
    d0: (k,3) unit tangent at the start of each piece
    normal: (k,3) unit vector toward an arc's centre (zero for lines)
    radius: (k,) arc radius, mm (inf for lines)
    segment: (k,) index of the original polyline segment a piece belongs to
        (an arc belongs to the segment after its corner)
    """

    piece_start: np.ndarray
    kind: np.ndarray
    p0: np.ndarray
    d0: np.ndarray
    normal: np.ndarray
    radius: np.ndarray
    segment: np.ndarray

    @property
    def length(self) -> float:
        return float(self.piece_start[-1])

    def locate(self, s: np.ndarray) -> np.ndarray:
        """Piece index of each arc length (a join belongs to the piece after it). (n,) int.
        ``clip(searchsorted(piece_start, s, side="right") - 1, 0, pieces - 1)``, compiled: the
        planner's arc lengths come in order, each a step or two from the one before."""
        s = np.asarray(s, dtype=float)
        out = np.empty(s.shape, dtype=np.int64)
        _locate_kernel(self.piece_start, np.ascontiguousarray(s).reshape(-1), len(self.kind), out.reshape(-1))
        return out if out.ndim else out[()]

    def evaluate(self, s: np.ndarray, order: int = 0, piece: np.ndarray | None = None) -> np.ndarray:
        """Point (order 0), unit tangent (1) or curvature vector (2) at arc lengths s. (n,3)."""
        s = np.asarray(s, dtype=float)
        k = self.locate(s) if piece is None else piece
        u = s - self.piece_start[k]
        d0, nrm, rad = self.d0[k], self.normal[k], self.radius[k]
        arc = self.kind[k] == 1
        out = np.empty((len(s), 3))
        line = ~arc
        if order == 0:
            out[line] = self.p0[k][line] + u[line, None] * d0[line]
        elif order == 1:
            out[line] = d0[line]
        else:
            out[line] = 0.0
        if arc.any():
            a = u[arc] / rad[arc]
            r, d, n = rad[arc, None], d0[arc], nrm[arc]
            if order == 0:
                out[arc] = self.p0[k][arc] + r * (np.sin(a)[:, None] * d + (1 - np.cos(a))[:, None] * n)
            elif order == 1:
                out[arc] = np.cos(a)[:, None] * d + np.sin(a)[:, None] * n
            else:
                out[arc] = (-np.sin(a)[:, None] * d + np.cos(a)[:, None] * n) / r
        return out

    def frame(self, s: np.ndarray, piece: np.ndarray | None = None):
        """(point, unit tangent, curvature vector), each (n,3), at arc lengths s: :meth:`evaluate`'s
        three orders in one compiled pass (the planner's second hottest call; values equal
        evaluate's)."""
        s = np.ascontiguousarray(s, dtype=float)
        k = self.locate(s) if piece is None else piece
        out = np.empty((3, len(s), 3))
        _frame_kernel(s, s, _ONE_AT_ZERO, np.ascontiguousarray(k, dtype=np.int64), False, self.piece_start, self.kind,
                      self.p0, self.d0, self.normal, self.radius, out)
        return out[0], out[1], out[2]

    def stage_frame(self, s0: np.ndarray, ds: np.ndarray, frac: np.ndarray, piece: np.ndarray):
        """:meth:`frame` at the arc lengths s0 + ds f (mm) of each stage (s0, ds: (n,)) for each
        fraction f of ``frac`` (f,), inside the stage's piece (n,): (point, unit tangent, curvature
        vector), each (n f, 3), stage by stage (the planner's per-stage derivatives, without the
        (n, f) arrays of arc lengths and pieces)."""
        n, f = len(s0), len(frac)
        out = np.empty((3, n * f, 3))
        _frame_kernel(np.ascontiguousarray(s0, dtype=float), np.ascontiguousarray(ds, dtype=float),
                      np.ascontiguousarray(frac, dtype=float), np.ascontiguousarray(piece, dtype=np.int64), True,
                      self.piece_start, self.kind, self.p0, self.d0, self.normal, self.radius, out)
        return out[0], out[1], out[2]

    def joins(self) -> np.ndarray:
        """Arc lengths of the interior line/arc joins. (k-1,)"""
        return self.piece_start[1:-1]

    def head(self, k: int) -> "BlendedPath":
        """The path's first k pieces (0 < k <= number of pieces)."""
        return BlendedPath(self.piece_start[: k + 1].copy(), self.kind[:k].copy(), self.p0[:k].copy(), self.d0[:k].copy(),
                           self.normal[:k].copy(), self.radius[:k].copy(), self.segment[:k].copy())


_ONE_AT_ZERO = np.zeros(1)  # frame's one "fraction" of each arc length


@njit
def _frame_kernel(s0, ds, frac, k, staged, piece_start, kind, p0, d0, normal, radius, out):
    """out[0], out[1], out[2] (n f, 3): point, unit tangent, curvature vector at arc lengths
    s0[i] + ds[i] frac[m] (row i f + m) where ``staged``, else s0[i] (frac of one), mm, inside
    pieces k (n,). A line: p0 + u d0, d0, 0; an arc of radius r turned by a = u / r:
    p0 + r (sin a d0 + (1 - cos a) n), cos a d0 + sin a n, (-sin a d0 + cos a n) / r."""
    f = frac.shape[0]
    for i in range(s0.shape[0]):
        j = k[i]
        for m in range(f):
            row = i * f + m
            u = (s0[i] + ds[i] * frac[m] if staged else s0[i]) - piece_start[j]
            if kind[j] == 1:
                r = radius[j]
                a = u / r
                sa = math.sin(a)
                ca = math.cos(a)
                for c in range(3):
                    out[0, row, c] = p0[j, c] + r * (sa * d0[j, c] + (1.0 - ca) * normal[j, c])
                    out[1, row, c] = ca * d0[j, c] + sa * normal[j, c]
                    out[2, row, c] = (-sa * d0[j, c] + ca * normal[j, c]) / r
            else:
                for c in range(3):
                    out[0, row, c] = p0[j, c] + u * d0[j, c]
                    out[1, row, c] = d0[j, c]
                    out[2, row, c] = 0.0


WALK = 8  # steps _last_at_or_below_from takes before it bisects


@njit
def _last_at_or_below(a, v, n_max):
    """``clip(searchsorted(a, v, side="right") - 1, 0, n_max - 1)`` for a sorted (m,) a (NaN
    sorts last, as in searchsorted)."""
    if v != v:
        return n_max - 1
    lo, hi = 0, a.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if a[mid] <= v:
            lo = mid + 1
        else:
            hi = mid
    return min(max(lo - 1, 0), n_max - 1)


@njit
def _last_at_or_below_from(a, v, n_max, j):
    """:func:`_last_at_or_below`, walking from index j instead of bisecting: a step or two from the
    answer for a value near v (samples in time order); an answer more than WALK steps away is
    bisected for, which one look at a[j + WALK + 1] or a[j - WALK] tells before walking (a
    bail-out counted inside the walk's loop made the sampler's whole pass three times slower).
    j must not be at or past a NaN of a (NaN sorts last)."""
    if v != v:
        return n_max - 1
    n = a.shape[0]
    if (j + WALK + 1 < n and a[j + WALK + 1] <= v) or (j - WALK > 0 and a[j - WALK] > v):
        return _last_at_or_below(a, v, n_max)
    while j + 1 < n and a[j + 1] <= v:
        j += 1
    while j > 0 and a[j] > v:
        j -= 1
    return min(j, n_max - 1)


@njit
def _locate_kernel(a, s, n_max, out):
    """out[i] = :func:`_last_at_or_below` (a, s[i], n_max), each search starting from the answer
    before (s (n,), out (n,) int64)."""
    j = np.int64(0)  # not a literal 0: numba would compile the search for that value too
    for i in range(s.shape[0]):
        j = _last_at_or_below_from(a, s[i], n_max, j)
        out[i] = j


@njit
def sample_kernel(tau, t, x, xd, xdd, S, piece_start, kind, p0, d0, normal, radius, cum_e, e_ratio, point, de, k):
    """:meth:`.pieces.RunPiece.sample`'s pass: a run's point (n,3) mm, filament since its start
    (n,) mm and path piece (n,) at times tau (n,) s, written into point, de and k, from its
    profile (grid t, x, xd, xdd; length S mm) along this module's path arrays: per sample, the
    stage's arc length clip(x + xd dt + xdd dt^2 / 2, 0, 1) S, the piece holding it, the point on
    the piece (as :func:`_frame_kernel`), and the piece's filament, in the same operations as the numpy
    methods they replace (the same values). Here, beside the frame kernel whose point formula it
    repeats: a change to one is a change to the other."""
    duration = t[t.shape[0] - 1]
    j = m = np.int64(0)  # the stage and the piece of the sample before: in time order, the next is a few further
    before = np.nan
    for i in range(tau.shape[0]):
        ta = min(max(tau[i], 0.0), duration)
        # in order after a sample that was not NaN: walk (s moves forward too, or back by a rounding)
        walk = ta >= before
        before = ta
        j = _last_at_or_below_from(t, ta, xdd.shape[0], j) if walk else _last_at_or_below(t, ta, xdd.shape[0])
        dt = ta - t[j]
        s = min(max(x[j] + xd[j] * dt + 0.5 * xdd[j] * dt * dt, 0.0), 1.0) * S
        m = _last_at_or_below_from(piece_start, s, kind.shape[0], m) if walk else _last_at_or_below(piece_start, s, kind.shape[0])
        k[i] = m
        # the point as _frame_kernel computes it, written out here: a shared per-point helper
        # (even inlined) made both kernels three times slower
        u = s - piece_start[m]
        if kind[m] == 1:
            r = radius[m]
            a = u / r
            sa = math.sin(a)
            ca = math.cos(a)
            for c in range(3):
                point[i, c] = p0[m, c] + r * (sa * d0[m, c] + (1.0 - ca) * normal[m, c])
        else:
            for c in range(3):
                point[i, c] = p0[m, c] + u * d0[m, c]
        de[i] = cum_e[m] + (s - piece_start[m]) * e_ratio[m]


def blend_polyline(points: np.ndarray, tolerance: float) -> BlendedPath:
    """Blend the corners of a polyline.

    points: (m+1, 3) float, mm, consecutive duplicates already removed (m >= 1 segments).
    tolerance: max distance of the blend from the corner, mm.
    """
    points = np.asarray(points, dtype=float)
    return blend_runs(points, np.array([0, len(points)]), np.array([float(tolerance)])).path(0)


@dataclass(frozen=True)
class BlendedRuns:
    """Many polylines blended at once (:func:`blend_runs`), their pieces end to end.

    offsets: (R+1,) int, run r's pieces are offsets[r]..offsets[r+1]-1 of the piece arrays;
    piece_start: (k+R,) float, mm, each run's own arc lengths, 0 to its length (run r's at
    offsets[r]+r .. offsets[r+1]+r); kind, p0, d0, normal, radius as :class:`BlendedPath`'s;
    segment: (k,) int, the run's own polyline segment of each piece; breaks: (k,) bool, the
    tangent breaks where the piece starts (an exact reversal no arc can blend: the path must be
    at rest there; never a run's first piece)."""

    offsets: np.ndarray
    piece_start: np.ndarray
    kind: np.ndarray
    p0: np.ndarray
    d0: np.ndarray
    normal: np.ndarray
    radius: np.ndarray
    segment: np.ndarray
    breaks: np.ndarray

    def path(self, r: int) -> BlendedPath:
        """Run r's BlendedPath (views of these arrays)."""
        a, b = int(self.offsets[r]), int(self.offsets[r + 1])
        return BlendedPath(self.piece_start[a + r : b + r + 1], self.kind[a:b], self.p0[a:b], self.d0[a:b],
                           self.normal[a:b], self.radius[a:b], self.segment[a:b])

    def stops(self, r: int) -> np.ndarray:
        """Run r's arc lengths (mm) where the tangent breaks. (j,)"""
        a, b = int(self.offsets[r]), int(self.offsets[r + 1])
        return self.piece_start[a + r : b + r][self.breaks[a:b]]


def blend_runs(points: np.ndarray, starts: np.ndarray, tolerance: np.ndarray) -> BlendedRuns:
    """:func:`blend_polyline` of many polylines in one pass (a run of a few dozen segments
    spends most of its blend in numpy's per-call overhead).

    points: (V, 3) float, mm, the polylines end to end, each with consecutive duplicates removed
    and at least two points; starts: (R+1,) int, polyline r is points[starts[r]:starts[r+1]];
    tolerance: (R,) float, mm, each one's blend tolerance.

    The corners' arithmetic runs over every vertex at once in numpy (a vertex that ends one
    polyline and one that starts the next get values nobody reads), so each polyline's pieces
    are what blending it alone gives, bit for bit; the pieces are then laid out run by run
    compiled."""
    points = np.ascontiguousarray(points, dtype=float)
    starts = np.ascontiguousarray(starts, dtype=np.int64)
    n_runs = len(starts) - 1
    tol = np.repeat(np.asarray(tolerance, dtype=float), np.diff(starts))[1:-1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        seg = points[1:] - points[:-1]
        seg_len = np.linalg.norm(seg, axis=1)
        d = seg / seg_len[:, None]
        # Corner at vertex v (1..V-2) between segments v-1 and v.
        din, dout = d[:-1], d[1:]
        cos_t = np.clip(np.einsum("ij,ij->i", din, dout), -1.0, 1.0)
        turn = np.arccos(cos_t)
        blended = (turn > _MIN_TURN) & (turn <= np.pi - _REVERSAL)
        half = turn / 2
        # Set-back that puts the arc midpoint exactly `tolerance` from the corner.
        sb_tol = tol * np.tan(half) / (1 / np.cos(half) - 1)
        # An exact reversal cannot be blended: go to the point and turn there, at rest.
        sb_tol = np.where(turn > np.pi - _REVERSAL, 0.0, sb_tol)
        room = 0.5 * np.minimum(seg_len[:-1], seg_len[1:])
        setback = np.where(blended, np.minimum(sb_tol, room), 0.0)
        radius = np.where(blended, setback / np.tan(half), np.inf)
        # An arc's length; a corner left sharp has none.
        arc_len = np.where(blended, np.where(np.isfinite(radius), radius, 0.0) * turn, 0.0)
        perp = dout - cos_t[:, None] * din
        pn = np.linalg.norm(perp, axis=1)
        normal = np.where(pn[:, None] > DIVISION_FLOOR, perp / pn[:, None], 0.0)
    cap = max(2 * len(seg) - 1, 0)
    out = BlendedRuns(np.empty(n_runs + 1, dtype=np.int64), np.empty(cap + n_runs), np.empty(cap, dtype=np.int8),
                      np.empty((cap, 3)), np.empty((cap, 3)), np.empty((cap, 3)), np.empty(cap),
                      np.empty(cap, dtype=np.int64), np.empty(cap, dtype=bool))
    lengths = np.empty(cap)
    points = points.view()
    points.flags.writeable = False  # one compiled signature whether the caller's array is writable or not
    k = _lay_out(points, d, seg_len, starts, setback, arc_len, radius, normal, out.offsets, lengths, out.kind, out.p0,
                 out.d0, out.normal, out.radius, out.segment)
    run_cumsum(lengths[:k], out.offsets, out.piece_start)
    _breaks(out.offsets, out.piece_start, out.kind, out.d0, out.normal, out.radius, out.breaks)
    return BlendedRuns(out.offsets, out.piece_start[: k + n_runs], out.kind[:k], out.p0[:k], out.d0[:k], out.normal[:k],
                       out.radius[:k], out.segment[:k], out.breaks[:k])


@njit
def _lay_out(points, d, seg_len, starts, setback, arc_len, radius, normal, offsets, lengths, kind, p0, d0, nrm, rad,
             segment):
    """:func:`blend_runs`' pieces, run by run: line j of a polyline from its start set-back to its
    end set-back (p0 = its first point + set-back d, length = segment - both set-backs), after the
    arc of the corner before it (p0 = the corner - set-back d_in, tangent d_in); pieces of a
    picometre or less are left out (between two corners that each take half of an equal
    segment a line is left of a few ulps, and its two joins, closer than the grid keeps apart,
    would make a stop or a feed cap at the second one miss its grid point). Writes the pieces'
    lengths and each run's range of pieces (offsets); returns the number of pieces."""
    k = 0
    offsets[0] = 0
    for r in range(starts.shape[0] - 1):
        v0 = starts[r]
        m = starts[r + 1] - v0 - 1  # segments
        for j in range(m):
            g = v0 + j  # segment j: vertex g to g + 1; corners at vertices g (j > 0) and g + 1 (j < m - 1)
            if j > 0 and arc_len[g - 1] > ZERO_LENGTH:
                kind[k] = 1
                for c in range(3):
                    p0[k, c] = points[g, c] - setback[g - 1] * d[g - 1, c]
                    d0[k, c] = d[g - 1, c]
                    nrm[k, c] = normal[g - 1, c]
                rad[k] = radius[g - 1]
                segment[k] = j
                lengths[k] = arc_len[g - 1]
                k += 1
            sb_start = setback[g - 1] if j > 0 else 0.0
            sb_end = setback[g] if j < m - 1 else 0.0
            length = seg_len[g] - sb_start - sb_end
            if length > ZERO_LENGTH:
                kind[k] = 0
                for c in range(3):
                    p0[k, c] = points[g, c] + sb_start * d[g, c]
                    d0[k, c] = d[g, c]
                    nrm[k, c] = 0.0
                rad[k] = np.inf
                segment[k] = j
                lengths[k] = length
                k += 1
        offsets[r + 1] = k
    return k


@njit
def run_cumsum(values, offsets, out):
    """Per run r: out[offsets[r] + r] = 0, then the running sum of values[offsets[r]:offsets[r+1]]
    in order (np.cumsum's sums). values (k,), offsets (R+1,) int, out (k+R,)."""
    for r in range(offsets.shape[0] - 1):
        o = offsets[r] + r
        acc = 0.0
        out[o] = 0.0
        for i in range(offsets[r], offsets[r + 1]):
            acc += values[i]
            out[o + 1 + i - offsets[r]] = acc


@njit
def _breaks(offsets, piece_start, kind, d0, normal, radius, out):
    """Whether the tangent breaks where each piece starts (out (k,) bool): the tangents either
    side of each join as :func:`_frame_kernel` takes them, the piece found as
    BlendedPath.locate finds it, their dot product below 1 - STRAIGHT."""
    for r in range(offsets.shape[0] - 1):
        a, n = offsets[r], offsets[r + 1] - offsets[r]
        ps = piece_start[a + r : a + r + n + 1]
        if n > 0:
            out[a] = False
        for i in range(1, n):
            s = ps[i]
            q = _last_at_or_below(ps, s, n)
            bx, by, bz = _tangent(s - ps[q - 1], a + q - 1, kind, d0, normal, radius)
            ax, ay, az = _tangent(s - ps[q], a + q, kind, d0, normal, radius)
            out[a + i] = bx * ax + by * ay + bz * az < 1 - STRAIGHT


@njit
def _tangent(u, j, kind, d0, normal, radius):
    """The unit tangent (x, y, z) u mm into piece j, as :func:`_frame_kernel` has it."""
    if kind[j] == 1:
        a = u / radius[j]
        sa, ca = math.sin(a), math.cos(a)
        return (ca * d0[j, 0] + sa * normal[j, 0], ca * d0[j, 1] + sa * normal[j, 1], ca * d0[j, 2] + sa * normal[j, 2])
    return d0[j, 0], d0[j, 1], d0[j, 2]


def dedupe(points: np.ndarray, feed: np.ndarray, e: np.ndarray, eps: float = DEDUPE_EPS):
    """Drop segments shorter than eps (mm) from a polyline, keeping the filament.

    points (m+1,3); feed, e: per segment (m,). A dropped segment's filament goes to the
    segment kept before it (or after it, at the start). Returns (points, feed, e): the arrays
    given when every segment is kept (a spiral vase's run is not copied)."""
    keep = np.linalg.norm(np.diff(points, axis=0), axis=1) > eps
    if keep.all():
        return points, feed, e
    if not keep.any():
        return points[:1], feed[:0], e[:0]
    owner = np.maximum(np.cumsum(keep) - 1, 0)  # kept segment index that absorbs each segment
    e_kept = np.bincount(owner, weights=e, minlength=int(keep.sum()))
    pts = np.concatenate([points[:1], points[1:][keep]])
    pts[-1] = points[-1]
    return pts, feed[keep], e_kept


def merge_short(points: np.ndarray, feed: np.ndarray, e: np.ndarray, resolution: float, max_deviation: float):
    """Remove the vertices of segments shorter than ``resolution`` (mm) where the polyline
    moves by at most ``max_deviation`` (mm): PrusaSlicer's ``gcode_resolution``, done in the
    planner. Such segments leave no room for a grid and their rounded E values make the
    filament per mm jump.

    points (m+1,3); feed, e: per segment (m,). The merged segment takes both segments'
    filament (the total is exact) and the slower feed. Only interior vertices go; the
    endpoints stay. Returns (points, feed, e, deviation): the largest distance of a removed
    vertex from the new polyline, mm."""
    pts, feed, e = np.asarray(points, float), np.asarray(feed, float), np.asarray(e, float)
    deviation = 0.0
    idle = 0
    parity = 1
    short = None  # the segments' shortness, measured again only once vertices have gone
    while len(pts) > 2 and idle < 2:
        if short is None:
            short = np.linalg.norm(np.diff(pts, axis=0), axis=1) < resolution
            if not short.any():  # no vertex can go (most runs): no pass of either parity
                break
        v = np.arange(1, len(pts) - 1)  # interior vertices; vertex v joins segments v-1 and v
        cand = (short[v - 1] | short[v]) & (v % 2 == parity)
        parity ^= 1
        if cand.any():
            a, b, c = pts[v - 1], pts[v], pts[v + 1]
            ac = c - a
            ll = np.einsum("ij,ij->i", ac, ac)
            t = np.clip(np.einsum("ij,ij->i", b - a, ac) / np.maximum(ll, SQUARED_FLOOR), 0.0, 1.0)
            dev = np.linalg.norm(b - a - t[:, None] * ac, axis=1)
            cand &= (dev <= max_deviation) & (ll > 0)
        if not cand.any():
            idle += 1
            continue
        idle = 0
        gone = v[cand]
        deviation = max(deviation, float(dev[cand].max()))
        e = e.copy()
        feed = feed.copy()
        e[gone - 1] += e[gone]
        feed[gone - 1] = np.minimum(feed[gone - 1], feed[gone])
        keep_seg = np.ones(len(e), dtype=bool)
        keep_seg[gone] = False
        keep_pt = np.ones(len(pts), dtype=bool)
        keep_pt[gone] = False
        pts, feed, e = pts[keep_pt], feed[keep_seg], e[keep_seg]
        short = None
    return pts, feed, e, deviation
