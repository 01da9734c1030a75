"""Infill: which parts of a layer are solid, and rectilinear lines to fill them.

Solid regions are found per layer from the neighbouring layers' cross-sections:
the part of the infill region not covered by every one of the ``top`` layers
above is top (or internal) solid, and likewise for the ``bottom`` layers below,
so a top surface at mid-height gets its solid layers too. Lines are computed
for all edges of a region at once (vectorised scanline crossings), clipped to
the region, and linked into zig-zag chains where neighbouring lines overlap, to
save travels.
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from manifold3d import CrossSection, JoinType, OpType


def solid_masks(sections: list[CrossSection], layer: int, top: int, bottom: int,
                covers: list[CrossSection] | None = None) -> tuple[CrossSection, CrossSection]:
    """(exposed_or_near_top, near_bottom): regions of ``sections[layer]`` that need solid
    fill because a layer within ``top`` above (``bottom`` below) does not cover them.
    Layers beyond the part count as empty. ``covers``: what each layer counts as
    covering, default its section; the slicer passes the sections shrunk by the
    perimeter band, so the infill next to a neighbour's wall is solid too (PrusaSlicer's
    ensure_vertical_shell_thickness: a hole starting two layers up gets a solid shell)."""
    n = len(sections)
    here = sections[layer]
    sections = sections if covers is None else covers

    def uncovered(idx: list[int]) -> CrossSection:
        if not idx:
            return CrossSection()
        if any(i < 0 or i >= n for i in idx):
            return here
        cover = idx[0] if len(idx) == 1 else None
        covered = sections[cover] if cover is not None else CrossSection.batch_boolean([sections[i] for i in idx], OpType.Intersect)
        return here - covered

    return uncovered(list(range(layer + 1, layer + 1 + top))), uncovered(list(range(layer - bottom, layer)))


def clean(region: CrossSection, radius: float) -> CrossSection:
    """Morphological opening: drop slivers thinner than ``2 * radius``."""
    if region.is_empty() or radius <= 0:
        return region
    return region.offset(-radius, JoinType.Miter, 3.0).offset(radius, JoinType.Miter, 3.0)


def scanline_segments(region: CrossSection, angle: float, spacing: float, min_length: float = 0.0):
    """Rectilinear lines ``spacing`` mm apart at ``angle`` rad, clipped to ``region``.

    Lines lie on a global grid (``y' = (k + 1/2) * spacing`` in the frame rotated by
    ``-angle``), so layers at the same angle line up. Returns (k (m,) int,
    x0 (m,), x1 (m,)) in the rotated frame, sorted by k then x.
    """
    polys = region.rotate(-math.degrees(angle)).to_polygons()
    if not polys:
        e = np.zeros(0)
        return e.astype(int), e, e
    p0 = np.concatenate(polys)
    p1 = np.concatenate([q for p in polys for q in (p[1:], p[:1])])  # each ring's next vertex
    y0, y1 = p0[:, 1], p1[:, 1]
    ylo, yhi = np.minimum(y0, y1), np.maximum(y0, y1)
    # scanline k at (k + 0.5) * spacing; count crossings with half-open [ylo, yhi)
    kmin = np.ceil(ylo / spacing - 0.5).astype(np.int64)
    kmax = np.ceil(yhi / spacing - 0.5).astype(np.int64) - 1
    cnt = np.maximum(kmax - kmin + 1, 0)
    total = int(cnt.sum())
    if total == 0:
        e = np.zeros(0)
        return e.astype(int), e, e
    edge = np.repeat(np.arange(len(p0)), cnt)
    offs = np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    k = kmin[edge] + offs
    ys = (k + 0.5) * spacing
    t = (ys - y0[edge]) / (y1[edge] - y0[edge])
    xs = p0[edge, 0] + t * (p1[edge, 0] - p0[edge, 0])
    order = np.lexsort((xs, k))
    k, xs = k[order], xs[order]
    # crossings come in pairs on each scanline (closed contours); guard anyway
    ka, kb = k[0::2], k[1::2]
    m = min(len(ka), len(kb))
    ka, kb, xa, xb = ka[:m], kb[:m], xs[0::2][:m], xs[1::2][:m]
    ok = (ka == kb) & (xb - xa > min_length)
    return ka[ok], xa[ok], xb[ok]


def chain_segments(k: np.ndarray, xa: np.ndarray, xb: np.ndarray, spacing: float, max_link: float) -> list[np.ndarray]:
    """Link segments of consecutive scanlines into zig-zag chains.

    k: (m,) int scanline of each segment, the segments grouped by scanline in increasing order;
    xa, xb: (m,) float, mm, each segment's ends along its line (xa < xb).
    Segment j on line k joins segment i on line k-1 when they are each other's only
    overlapping neighbour and the link (end of one to start of the next) is
    shorter than ``max_link``. Returns a list of index arrays (chains, in order).

    Vectorised (no compiled kernel: the slicing workers never load numba)."""
    m = len(k)
    if m == 0:
        return []
    k = np.asarray(k, dtype=np.int64)
    xa, xb = np.asarray(xa, dtype=float), np.asarray(xb, dtype=float)
    nxt, prev = _sole_overlaps(k, xa, xb)
    order, starts = _split_chains(nxt, prev, xa, xb, float(spacing), float(max_link))
    return np.split(order, starts[1:])


def _sole_overlaps(k, xa, xb):
    """(nxt, prev) (m,) int64, -1 where none: nxt[i] = j and prev[j] = i for segment i of scanline
    k and segment j of scanline k + 1 where each is the other's only overlapping segment (open
    intervals).

    The segments of a scanline are disjoint and in order (``scanline_segments`` pairs sorted
    crossings; touching ends allowed), so those of the next line that overlap segment i are one
    run, found by binary search: from the first whose end passes xa_i to the first whose start
    reaches xb_i. The search goes over all lines at once on (line, x) keys ordered line first
    (complex numbers: numpy orders them by real part, then imaginary). Time O(m log m), memory
    O(m), however many segments share a line (all pairs of neighbouring lines' segments took
    gigabytes for a thousand a line)."""
    m = len(k)
    nxt, prev = np.full(m, -1, dtype=np.int64), np.full(m, -1, dtype=np.int64)
    same_line = k[1:] == k[:-1]
    if not (np.all(k[1:] >= k[:-1]) and np.all(xa < xb) and np.all(xb[:-1][same_line] <= xa[1:][same_line])):
        raise ValueError("chain_segments: expected segments grouped by scanline in increasing order, each "
                         "xa < xb, and a line's segments disjoint and in order (as scanline_segments gives them)")
    line = k.astype(float)
    starts, ends = line + 1j * xa, line + 1j * xb

    def overlaps(seg, other_line):
        """(first, count) of the segments of line ``other_line`` overlapping segments ``seg``."""
        first = np.searchsorted(ends, other_line + 1j * xa[seg], side="right")
        return first, np.searchsorted(starts, other_line + 1j * xb[seg], side="left") - first

    first, count = overlaps(slice(None), line + 1)
    i = np.flatnonzero(count == 1)
    j = first[i]
    sole = overlaps(j, line[j] - 1)[1] == 1  # j's overlaps on i's line: i's alone?
    nxt[i[sole]] = j[sole]
    prev[j[sole]] = i[sole]
    return nxt, prev


def _split_chains(nxt, prev, xa, xb, spacing, max_link):
    """(order, starts): the chains of ``nxt`` (from each segment with no ``prev``, in index order)
    end to end in ``order`` (m,), each cut where its zig-zag link is longer than ``max_link``;
    ``starts``: where each chain begins in ``order``. A chain runs its first segment forward (xa
    to xb) and alternates, as :func:`chain_polylines` draws it, so a link is measured with the
    directions its own chain gives after a cut: forward, it joins xb to the next segment's xb;
    backward, xa to xa.

    A segment's direction follows from the link into it alone: after a forward segment whose
    xb-to-xb link is too long it starts a chain (forward); after a backward one it is forward
    whether the chain is cut there or not. So directions alternate from the last head or such
    link, and the chains' order and depths come from pointer jumping (log of the longest chain
    passes over the segments)."""
    m = len(nxt)
    idx = np.arange(m)
    head = prev < 0
    up = np.where(head, idx, prev)
    depth = (~head).astype(np.int64)
    while True:
        further = up[up]
        if np.array_equal(further, up):
            break
        depth = depth + depth[up]
        up = further
    order = np.lexsort((depth, up))  # chains by head index, each from its head
    src = prev[order]  # the segment before each one in its chain (-1 at heads)
    link = src >= 0
    s = np.where(link, src, order)
    too_long_fwd = np.hypot(xb[s] - xb[order], spacing) > max_link
    too_long_bwd = np.hypot(xa[s] - xa[order], spacing) > max_link
    pos = np.arange(m)
    reset = ~link | too_long_fwd
    last = np.maximum.accumulate(np.where(reset, pos, 0))
    forward = (pos - last) % 2 == 0
    before = np.concatenate([[True], forward[:-1]])  # the direction of the link's source
    cut = link & np.where(before, too_long_fwd, too_long_bwd)
    return order, np.flatnonzero(~link | cut)


def chain_polylines(k, xa, xb, chains, spacing: float, angle: float) -> list[np.ndarray]:
    """Chains of segments -> zig-zag polylines (bed frame, (p, 2))."""
    c, s = math.cos(angle), math.sin(angle)
    rot = np.array([[c, s], [-s, c]])  # row vectors: p_bed = p_rot @ rot
    lines = []
    for ch in chains:
        y = (k[ch] + 0.5) * spacing
        fwd = np.arange(len(ch)) % 2 == 0
        x_first = np.where(fwd, xa[ch], xb[ch])
        x_last = np.where(fwd, xb[ch], xa[ch])
        pts = np.empty((2 * len(ch), 2))
        pts[0::2, 0], pts[1::2, 0] = x_first, x_last
        pts[0::2, 1] = pts[1::2, 1] = y
        lines.append(pts @ rot)
    return lines


def rectilinear(region: CrossSection, angle: float, spacing: float, width: float, anchor: float = 0.0) -> list[np.ndarray]:
    """Fill ``region`` with lines ``spacing`` apart at ``angle``; zig-zag where it saves travels,
    and join lines whose ends are less than ``anchor`` mm apart along the outline."""
    if region.is_empty():
        return []
    k, xa, xb = scanline_segments(region, angle, spacing, min_length=width * 0.5)
    chains = chain_segments(k, xa, xb, spacing, max_link=max(3 * spacing, 2 * width) if spacing < 3 * width else 2.0 * spacing)
    lines = chain_polylines(k, xa, xb, chains, spacing, angle)
    if anchor > 0:
        lines = link_along_boundary(lines, region, anchor)
    return lines


def _arc(ring2: tuple, L: float, u0: float, u1: float, forward: bool) -> np.ndarray:
    """Points along a closed ring from arc length ``u0`` to ``u1`` going forward (increasing) or
    backward, ends included. ring2: (s2, p2), the ring's arc lengths and points twice over
    ((2k+1,) and (2k+1, 2): its points, then its points after the first with ``L``, its length,
    added to their arc lengths), so a stretch across the ring's start is one slice."""
    if not forward:
        return _arc(ring2, L, u1, u0, True)[::-1]
    if u1 < u0:
        u1 += L
    s2, p2 = ring2
    # the points strictly between u0 and u1 (s2 is sorted): a slice, not a mask of the whole ring
    inner = p2[np.searchsorted(s2, u0, side="right") : np.searchsorted(s2, u1, side="left")]
    start = np.array([np.interp(u0, s2, p2[:, 0]), np.interp(u0, s2, p2[:, 1])])
    end = np.array([np.interp(u1, s2, p2[:, 0]), np.interp(u1, s2, p2[:, 1])])
    return np.vstack([start, inner, end])


def link_along_boundary(lines: list[np.ndarray], region: CrossSection, max_link: float) -> list[np.ndarray]:
    """Join infill polylines whose ends lie on one contour of ``region`` less than
    ``max_link`` mm apart along it, by extruding along the contour (PrusaSlicer's
    infill anchors): a ring of short dashes becomes one path instead of a travel per
    dash. lines: (k, 2) polylines whose ends lie on the region's outline; returns
    fewer, longer polylines."""
    m = len(lines)
    if m < 2 or max_link <= 0:
        return lines
    polys = [np.asarray(p, float) for p in region.to_polygons() if len(p) >= 3]
    if not polys:
        return lines
    rings = [np.vstack([p, p[:1]]) for p in polys]
    cums = [np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(r, axis=0), axis=1))]) for r in rings]
    geoms = np.array([shapely.LineString(r) for r in rings])
    ends = np.array([[ln[0], ln[-1]] for ln in lines]).reshape(-1, 2)  # (2m, 2): head, tail
    pts = shapely.points(ends)
    dist = shapely.distance(pts[:, None], geoms[None, :])
    which = np.argmin(dist, axis=1)
    which[dist[np.arange(len(pts)), which] > 1e-3] = -1
    u = np.zeros(len(pts))
    # the contours met, in order (np.unique's plain path imports numpy.ma in every slicing worker)
    for c in np.flatnonzero(np.bincount(which[which >= 0])).tolist():
        sel = which == c
        u[sel] = shapely.line_locate_point(geoms[c], pts[sel])
    which, u = which.reshape(m, 2), u.reshape(m, 2)
    lengths = np.array([c[-1] for c in cums])
    twice = {}  # a ring's points and arc lengths twice over, made for the rings linked along

    alive = np.ones(m, bool)
    out = []
    cur_i = 0
    alive[0] = False
    cur = [lines[0]]
    c_end, u_end = which[0, 1], u[0, 1]
    while True:
        best = None
        if c_end >= 0:
            L = lengths[c_end]
            # both ends of every line left on this contour at once, heads before tails: the first
            # smallest distance along the contour is the head of the lowest line, as when the
            # heads were searched first and a tail had to be strictly nearer
            on = alive[:, None] & (which == c_end)
            if on.any():
                fwd = (u - u_end) % L
                d = np.where(on, np.minimum(fwd, L - fwd), np.inf).T.ravel()
                k = int(np.argmin(d))
                if d[k] <= max_link:
                    side, nxt = divmod(k, m)
                    best = (float(d[k]), nxt, side, bool(fwd[nxt, side] <= L - fwd[nxt, side]))
        if best is not None:
            _, nxt, side, forward = best
            if c_end not in twice:
                ring, cum = rings[c_end], cums[c_end]
                twice[c_end] = (np.concatenate([cum, cum[1:] + L]), np.vstack([ring, ring[1:]]))
            conn = _arc(twice[c_end], L, u_end, u[nxt, side], forward)
            seg = lines[nxt] if side == 0 else lines[nxt][::-1]
            cur.append(conn[1:-1])
            cur.append(seg)
            alive[nxt] = False
            c_end, u_end = which[nxt, 1 - side], u[nxt, 1 - side]
            continue
        out.append(np.vstack(cur))
        if not alive.any():
            break
        # nothing to anchor to: start a new path at the line nearest the last end
        last = out[-1][-1]
        idx = np.flatnonzero(alive)
        heads = np.array([lines[i][0] for i in idx])
        cur_i = int(idx[np.argmin(np.sum((heads - last) ** 2, axis=1))])
        alive[cur_i] = False
        cur = [lines[cur_i]]
        c_end, u_end = which[cur_i, 1], u[cur_i, 1]
    return out


DENSE_FLOW_MIN = 0.8  # the least a dense region's flow is scaled by (a region that small is mostly outline)


def dense_flow_scale(region: CrossSection, to_fill: CrossSection, lines: list, spacing: float) -> float:
    """Factor (DENSE_FLOW_MIN..1) on the flow of solid lines ``spacing`` apart whose centres
    fill ``region``: the area they must cover (``region`` grown by half a spacing, within
    ``to_fill``: the island less its perimeter beads and bridges) over the area the bead model
    lays (length x spacing). Lines that overlap the perimeters or double along the outline
    would otherwise put that overlap's plastic in too; lines: (k, 2) polylines, mm."""
    if not lines or region.is_empty() or to_fill.is_empty():
        return 1.0
    laid = spacing * sum(float(np.sqrt((np.diff(p, axis=0) ** 2).sum(axis=1)).sum()) for p in lines)
    if laid <= 0:
        return 1.0
    target = (region.offset(spacing / 2, JoinType.Miter, 3.0) ^ to_fill).area()
    return float(min(1.0, max(DENSE_FLOW_MIN, target / laid)))
