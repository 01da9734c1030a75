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
from manifold3d import CrossSection, JoinType, OpType


def solid_masks(sections: list[CrossSection], layer: int, top: int, bottom: int) -> tuple[CrossSection, CrossSection]:
    """(exposed_or_near_top, near_bottom): regions of ``sections[layer]`` that need solid
    fill because a layer within ``top`` above (``bottom`` below) does not cover them.
    Layers beyond the part count as empty."""
    n = len(sections)
    here = sections[layer]

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
    p1 = np.concatenate([np.roll(p, -1, axis=0) for p in polys])
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

    Segment j on line k joins segment i on line k-1 when they are each other's only
    overlapping neighbour and the link (end of one to start of the next) is
    shorter than ``max_link``. Returns a list of index arrays (chains, in order).
    """
    m = len(k)
    if m == 0:
        return []
    # boundaries of each scanline's run of segments
    line_start = np.flatnonzero(np.concatenate([[True], k[1:] != k[:-1]]))
    line_end = np.concatenate([line_start[1:], [m]])
    nxt = np.full(m, -1)
    prev = np.full(m, -1)
    for a in range(len(line_start) - 1):
        s0, e0, s1, e1 = line_start[a], line_end[a], line_start[a + 1], line_end[a + 1]
        if k[s1] != k[s0] + 1:
            continue
        # overlap matrix between the two lines (small)
        ov = (xa[s0:e0, None] < xb[None, s1:e1]) & (xa[None, s1:e1] < xb[s0:e0, None])
        one_a = ov.sum(axis=1) == 1
        one_b = ov.sum(axis=0) == 1
        ii, jj = np.nonzero(ov)
        for i, j in zip(ii.tolist(), jj.tolist()):
            if one_a[i] and one_b[j]:
                nxt[s0 + i] = s1 + j
                prev[s1 + j] = s0 + i
    chains = []
    for head in np.flatnonzero(prev < 0).tolist():
        chain = [head]
        while nxt[chain[-1]] >= 0:
            chain.append(int(nxt[chain[-1]]))
        chains.append(chain)
    # split chains where the zig-zag link would be too long
    out = []
    for chain in chains:
        c = np.asarray(chain)
        if len(c) > 1:
            # the chain alternates direction: link i->i+1 joins the end of i to the start of i+1
            fwd = np.arange(len(c)) % 2 == 0
            end_x = np.where(fwd, xb[c], xa[c])
            start_next = np.where(fwd[:-1], xb[c[1:]], xa[c[1:]])  # the next segment runs the other way
            link = np.hypot(end_x[:-1] - start_next, spacing)
            cut = np.flatnonzero(link > max_link) + 1
            out.extend(np.split(c, cut))
        else:
            out.append(c)
    return out


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


def rectilinear(region: CrossSection, angle: float, spacing: float, width: float) -> list[np.ndarray]:
    """Fill ``region`` with lines ``spacing`` apart at ``angle``; zig-zag where it saves travels."""
    if region.is_empty():
        return []
    k, xa, xb = scanline_segments(region, angle, spacing, min_length=width * 0.5)
    chains = chain_segments(k, xa, xb, spacing, max_link=max(3 * spacing, 2 * width) if spacing < 3 * width else 2.0 * spacing)
    return chain_polylines(k, xa, xb, chains, spacing, angle)
