"""Cross-sections of any mesh: manifold3d for closed parts, and a layer-by-layer
cut for open or non-manifold ones (as PrusaSlicer does).

A closed part is sliced by manifold3d (exact, fast). A mesh manifold3d refuses
(holes, non-manifold edges, overlapping shells) is cut triangle by triangle at
every height; the segments are chained through the mesh edges they cross, each
layer's open polylines are joined end to nearest end and closed, and the region
is filled with the positive rule (even-odd where the winding is inconsistent).
How much had to be closed is reported as a :class:`MeshWarning`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from manifold3d import CrossSection, FillRule

from ..errors import MeshError, MeshWarning


#: Largest share of a layer's outline that gap closing may invent (closing length over
#: the length cut from the mesh); above it the layer is guesswork and the part is refused.
#: teapot.stl needs 9 %, bunny.ply 10 %; a triangle soup 240 %.
MAX_GAP_SHARE = 0.5


@dataclass(frozen=True)
class OpenSliceReport:
    """What the open-mesh cut had to close.

    layers: layers with at least one gap closed; gaps: number of gaps closed;
    gap_mm: total length of the closing segments, mm; max_gap_mm: the longest, mm;
    reversed: polylines joined end to end against their direction (inconsistent winding);
    worst_share: the largest ratio, over layers, of closing length to the length cut
    from the mesh; worst_layer: that layer's index (-1 if none).
    """

    layers: int
    gaps: int
    gap_mm: float
    max_gap_mm: float
    reversed: int
    worst_share: float = 0.0
    worst_layer: int = -1

    def text(self, shown: str, n_layers: int) -> str:
        return (
            f"{shown}: open or non-manifold mesh sliced layer by layer: closed {self.gaps} gaps in "
            f"{self.layers} of {n_layers} layers, {self.gap_mm:.2f} mm in total (longest {self.max_gap_mm:.2f} mm)"
        )


def mesh_sections(mesh, z_mid) -> list:
    """One ``manifold3d.CrossSection`` per height in ``z_mid`` ((L,) float, mm).

    A closed mesh (``mesh.closed``) is sliced by manifold3d; any other by
    :func:`open_sections`, which warns (:class:`MeshWarning`) when it had to
    close gaps.
    """
    if getattr(mesh, "closed", True):
        manifold = mesh.to_manifold()
        return [manifold.slice(float(z)) for z in z_mid]
    sections, report = open_sections(mesh.vertices, mesh.faces, z_mid, consistent=mesh.winding_consistent)
    if report.worst_share > MAX_GAP_SHARE:
        li = report.worst_layer
        raise MeshError(
            f"{mesh.path}: the surface is too broken to slice: at layer {li + 1} (z = {float(z_mid[li]):.2f} mm) "
            f"closing its outlines would invent {100 * report.worst_share:.0f} % of their length "
            f"(limit {100 * MAX_GAP_SHARE:.0f} %): expected a mesh that encloses a volume, even with holes"
        )
    if all(s.is_empty() for s in sections):
        raise MeshError(f"{mesh.path}: the open mesh encloses no area at any layer: nothing to print")
    if report.gaps:
        warnings.warn(report.text(mesh.path or "<mesh>", len(sections)), MeshWarning, stacklevel=2)
    return sections


def cut_segments(vertices: np.ndarray, faces: np.ndarray, z: np.ndarray):
    """Every triangle cut by every plane z = z[l].

    vertices: (n, 3) float mm; faces: (m, 3) int, counter-clockwise seen from
    outside; z: (L,) float mm, ascending. A vertex with z >= plane counts as
    above, so each cut triangle has exactly one edge going down and one going up
    (walking v0 -> v1 -> v2). Returns ``layer`` (S,) int, ``start``/``end`` (S,)
    int64 node ids and ``points`` (N, 2) float mm indexed by node id. A node is one
    (mesh edge, layer) crossing: both triangles of an edge share it bit for bit,
    so chaining is topological. The segment runs start -> end with the part's
    inside on its left (counter-clockwise outer contours).
    """
    z = np.asarray(z, float)
    tri = vertices[faces]  # (m, 3, 3)
    tz = tri[:, :, 2]
    # a plane cuts a triangle when a vertex lies below it and one on or above: min < z[l] <= max
    lo = np.searchsorted(z, tz.min(axis=1), side="right")
    hi = np.searchsorted(z, tz.max(axis=1), side="right")
    count = np.maximum(hi - lo, 0)
    fi = np.repeat(np.arange(len(faces)), count)
    li = np.repeat(lo - np.cumsum(count) + count, count) + np.arange(count.sum())
    if len(fi) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 2))
    h = z[li]
    above = tz[fi] >= h[:, None]  # (S, 3)
    # directed edge k goes v_k -> v_(k+1); it goes down if above -> below, up if below -> above
    nxt = np.roll(above, -1, axis=1)
    down = np.argmax(above & ~nxt, axis=1)
    up = np.argmax(~above & nxt, axis=1)

    # unique undirected mesh edges, so both faces of an edge name the same node
    f = faces[fi]
    k = np.arange(len(fi))
    a_d, b_d = f[k, down], f[k, (down + 1) % 3]
    a_u, b_u = f[k, up], f[k, (up + 1) % 3]
    n_v = len(vertices)
    key_d = (np.minimum(a_d, b_d) * n_v + np.maximum(a_d, b_d)) * len(z) + li
    key_u = (np.minimum(a_u, b_u) * n_v + np.maximum(a_u, b_u)) * len(z) + li
    keys, inv = np.unique(np.concatenate([key_d, key_u]), return_inverse=True)
    start, end = inv[: len(fi)], inv[len(fi) :]

    # the crossing point of each node, computed once from the edge's lower-index end
    layer_of = keys % len(z)
    ek = keys // len(z)
    va, vb = vertices[ek // n_v], vertices[ek % n_v]
    hz = z[layer_of]
    t = (hz - va[:, 2]) / (vb[:, 2] - va[:, 2])
    points = va[:, :2] + (vb[:, :2] - va[:, :2]) * t[:, None]
    return li, start, end, points


def _chain_labels(nxt: np.ndarray) -> tuple[int, np.ndarray]:
    """The chains and cycles that links ``nxt`` ((S,) int, the next element or -1; each element
    the next of at most one) make: their number and each element's label ((S,) int64), labels
    numbered in the order of each chain's lowest element (scipy's ``connected_components``
    numbering, without importing scipy.sparse into every compile). By pointer jumping: an
    element of an open chain reaches its end; one of a cycle, after enough doublings, the cycle's
    lowest element."""
    S = len(nxt)
    index = np.arange(S)
    rounds = S.bit_length() + 1  # 2^rounds > 2S: every jump has run past any chain's length
    end = np.where(nxt >= 0, nxt, index)
    low, jump = index.copy(), nxt.copy()
    for _ in range(rounds):
        end = end[end]
        on = jump >= 0
        if on.any():
            low[on] = np.minimum(low[on], low[jump[on]])
            jump[on] = jump[jump[on]]
    root = np.where(nxt[end] < 0, end, low)  # one element per chain or cycle
    first = np.full(S, S, dtype=np.int64)
    np.minimum.at(first, root, index)
    _, label = np.unique(first[root], return_inverse=True)
    return (int(label.max()) + 1 if S else 0), label.astype(np.int64)


def _list_rank(nxt: np.ndarray) -> np.ndarray:
    """Steps from each element to the end of its list (nxt[i] = -1 at the end)."""
    dist = (nxt >= 0).astype(np.int64)
    jump = nxt.copy()
    while True:
        m = jump >= 0
        if not m.any():
            return dist
        j = jump[m]
        dist_new = dist.copy()
        dist_new[m] = dist[m] + dist[j]
        jump_new = jump.copy()
        jump_new[m] = jump[j]
        dist, jump = dist_new, jump_new


def _nearest(pieces: list[np.ndarray], point: np.ndarray):
    """(distance, index, at_end) of the piece end nearest ``point``; at_end: its last point."""
    starts = np.array([p[0] for p in pieces])
    ends = np.array([p[-1] for p in pieces])
    ds = np.hypot(*(starts - point).T)
    de = np.hypot(*(ends - point).T)
    i, j = int(np.argmin(ds)), int(np.argmin(de))
    return (float(ds[i]), i, False) if ds[i] <= de[j] else (float(de[j]), j, True)


def _close_open(polylines: list[np.ndarray], tolerance: float = 1e-6):
    """Close open polylines as PrusaSlicer does: first join ends that coincide (within
    ``tolerance`` mm: flipped faces, non-manifold edges split chains there), then join
    each tail to the nearest free end (reversing that piece if needed) or to its own
    head, whichever is nearer.

    polylines: list of (k, 2) float arrays, mm. Returns the closed loops, the gap
    lengths of the joins longer than ``tolerance`` (mm) and how many pieces were
    reversed. The loops are over polylines, not points.
    """
    pieces, reversed_ = [], 0
    open_ = [p for p in polylines if len(p) >= 2]
    while open_:  # exact joins at both ends
        cur = open_.pop()
        while open_ and np.hypot(*(cur[0] - cur[-1])) > tolerance:
            d, i, at_end = _nearest(open_, cur[-1])
            if d <= tolerance:
                nxt = open_.pop(i)
                cur = np.vstack([cur, nxt[::-1] if at_end else nxt])
                reversed_ += at_end
                continue
            d, i, at_end = _nearest(open_, cur[0])
            if d <= tolerance:
                prv = open_.pop(i)
                cur = np.vstack([prv if at_end else prv[::-1], cur])
                reversed_ += not at_end
                continue
            break
        pieces.append(cur)

    loops, gaps = [], []
    while pieces:  # gaps: tail to the nearest end
        cur = pieces.pop()
        while True:
            d_self = float(np.hypot(*(cur[0] - cur[-1])))
            d, i, at_end = _nearest(pieces, cur[-1]) if pieces else (np.inf, -1, False)
            if d_self < d or not pieces:  # on a tie, join the other piece: a lone piece is rarely a whole outline
                gaps.append(d_self)
                loops.append(cur)
                break
            gaps.append(d)
            nxt = pieces.pop(i)
            cur = np.vstack([cur, nxt[::-1] if at_end else nxt])
            reversed_ += at_end
    gaps = np.asarray(gaps, float)
    return loops, gaps[gaps > tolerance], reversed_


def open_sections(vertices, faces, z_mid, *, consistent: bool = True, tolerance: float = 1e-6):
    """Cross-sections of an open or non-manifold mesh.

    vertices (n, 3) float mm, faces (m, 3) int, z_mid (L,) ascending mm;
    ``consistent``: the faces are wound consistently (outward), so the positive
    fill rule applies (overlapping shells unite); otherwise even-odd. Gaps shorter
    than ``tolerance`` mm (coincident ends) are joined silently. Returns a list of
    L ``CrossSection`` and an :class:`OpenSliceReport`.
    """
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    z_mid = np.asarray(z_mid, float)
    L = len(z_mid)
    order_z = np.argsort(z_mid, kind="stable")
    layer, start, end, points = cut_segments(vertices, faces, z_mid[order_z])
    layer = order_z[layer] if len(layer) else layer
    sections = [CrossSection() for _ in range(L)]
    if len(layer) == 0:
        return sections, OpenSliceReport(0, 0, 0.0, 0.0, 0)

    cut_length = np.bincount(layer, weights=np.hypot(*(points[end] - points[start]).T), minlength=L)
    order, chain, is_cycle = _chain_segments(start, end)
    # per chain: the start points of its segments in order, and the end point of the last one
    bounds = np.flatnonzero(np.r_[True, chain[1:] != chain[:-1], True])
    seg_start_pts = points[start[order]]
    chain_layer = layer[order[bounds[:-1]]]
    rule = FillRule.Positive if consistent else FillRule.EvenOdd
    closed_by_layer: list[list[np.ndarray]] = [[] for _ in range(L)]
    open_by_layer: list[list[np.ndarray]] = [[] for _ in range(L)]
    for c, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        lab = chain[a]
        pts = seg_start_pts[a:b]
        if is_cycle[lab]:
            if len(pts) >= 3:
                closed_by_layer[chain_layer[c]].append(pts)
        else:
            pts = np.vstack([pts, points[end[order[b - 1]]][None]])
            open_by_layer[chain_layer[c]].append(pts)

    n_layers = n_gaps = n_rev = 0
    total = longest = worst = 0.0
    worst_layer = -1
    for li in range(L):
        loops = closed_by_layer[li]
        layer_rule = rule
        if open_by_layer[li]:
            joined, real, rev = _close_open(open_by_layer[li], tolerance)
            loops = loops + [p for p in joined if len(p) >= 3]
            if len(real):
                n_layers += 1
                n_gaps += len(real)
                total += float(real.sum())
                longest = max(longest, float(real.max()))
                share = float(real.sum()) / max(float(cut_length[li]), 1e-12)
                if share > worst:
                    worst, worst_layer = share, li
            if rev:
                n_rev += rev
                layer_rule = FillRule.EvenOdd  # a reversed piece has no meaningful orientation
        if loops:
            sections[li] = CrossSection([np.ascontiguousarray(p, dtype=np.float64) for p in loops], layer_rule)
    return sections, OpenSliceReport(n_layers, n_gaps, total, longest, n_rev, worst, worst_layer)


def _chain_segments(start: np.ndarray, end: np.ndarray):
    """Order segments into chains by node identity (vectorised list ranking).

    start, end: (S,) int node ids. Where a node ends k segments and starts j
    (non-manifold edges, flipped faces), the i-th ender links to the i-th starter.
    Returns ``order`` (S,) segment indices grouped chain by chain, head first;
    ``chain`` (S,) the chain label of each entry of ``order``; ``is_cycle``
    (n_chains,) bool.
    """
    S = len(start)

    def ranked(keys):
        o = np.argsort(keys, kind="stable")
        k = keys[o]
        first = np.r_[True, k[1:] != k[:-1]]
        grp_start = np.maximum.accumulate(np.where(first, np.arange(S), 0))
        r = np.empty(S, np.int64)
        r[o] = np.arange(S) - grp_start
        return r

    rs, re = ranked(start), ranked(end)
    big = int(max(rs.max(), re.max())) + 1
    skey = start * big + rs
    ekey = end * big + re
    so = np.argsort(skey)
    pos = np.minimum(np.searchsorted(skey[so], ekey), S - 1)
    nxt = np.where(skey[so][pos] == ekey, so[pos], -1)
    nxt[nxt == np.arange(S)] = -1  # a one-segment loop (degenerate) is left open

    linked = nxt >= 0
    n_chain, label = _chain_labels(nxt)
    has_pred = np.zeros(S, bool)
    has_pred[nxt[linked]] = True
    is_cycle = np.ones(n_chain, bool)
    is_cycle[label[~has_pred]] = False
    head = np.full(n_chain, S, np.int64)
    np.minimum.at(head, label, np.arange(S))
    # in a cycle the segment pointing at the head (lowest index) becomes the tail
    nxt[is_cycle[label] & linked & (nxt == head[label])] = -1
    dist = _list_rank(nxt)
    order = np.lexsort((-dist, label))
    return order, label[order], is_cycle
