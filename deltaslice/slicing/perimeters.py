"""Perimeters: inward offsets of each island's outline.

The outer loop runs half a perimeter width inside the outline, each further
loop one width further in; holes get their loops too (the offsets of a
cross-section with holes grow the holes). Loops that vanish (a region thinner
than the offset) are dropped. The region left for infill is the inner edge of
the innermost perimeter.
"""

from __future__ import annotations

import numpy as np
import shapely
from manifold3d import CrossSection, JoinType

MIN_LOOP_LENGTH_FACTOR = 2.0  # drop external loops shorter than this many widths
# inner loops shorter than this many widths (beads of a ring that barely fits, broken into
# specks where the wall thickness wavers) are left to the gap fill: one line instead of a
# travel per speck
MIN_INNER_LOOP_LENGTH_FACTOR = 8.0


def perimeter_loops(island: CrossSection, width: float, count: int, spacing: float | None = None) -> list[tuple[int, np.ndarray]]:
    """[(depth, (k, 2) closed polygon without repeated end point)], depth 0 = external.

    Loop k runs ``width / 2 + k * spacing`` inside the outline (spacing: the bead
    spacing, default ``width``)."""
    spacing = width if spacing is None else spacing
    loops = []
    for k in range(count):
        ring = island.offset(-(width / 2 + k * spacing), JoinType.Miter, 3.0)
        # where a ring is thinner than half a spacing its two sides would overlap into one
        # over-full bead: leave that part to the gap fill (one line as wide as the gap)
        ring = ring.offset(-spacing / 4, JoinType.Miter, 3.0).offset(spacing / 4, JoinType.Miter, 3.0)
        if ring.is_empty():
            break
        for poly in ring.to_polygons():
            if len(poly) < 3:
                continue
            per = np.linalg.norm(np.diff(np.vstack([poly, poly[:1]]), axis=0), axis=1).sum()
            if per < (MIN_LOOP_LENGTH_FACTOR if k == 0 else MIN_INNER_LOOP_LENGTH_FACTOR) * width:
                continue
            loops.append((k, np.asarray(poly, float)))
    return loops


def infill_boundary(island: CrossSection, width: float, count: int, overlap: float, spacing: float | None = None) -> CrossSection:
    """Where infill line centres may go: the inner edge of the innermost perimeter
    moved by ``overlap`` mm outward (negative: inward). The slicer passes
    ``infill_overlap * perimeter_width - infill_spacing / 2``, so a line's edge
    overlaps the perimeter by ``infill_overlap`` of a perimeter width."""
    spacing = width if spacing is None else spacing
    inner_edge = (width / 2 + (count - 0.5) * spacing) if count else 0.0
    return island.offset(-inner_edge + overlap, JoinType.Miter, 3.0)


CONCAVE_SEAM_TURN = np.radians(25.0)  # a corner must turn at least this much to hide a seam


def concave_corners(poly: np.ndarray) -> np.ndarray:
    """(k,) bool: vertices of a loop (material on its left, as manifold3d orients outlines
    and holes) where it turns right by more than :data:`CONCAVE_SEAM_TURN`: inside
    corners of the printed surface, where a seam hides."""
    d_out = np.empty_like(poly, dtype=float)  # poly[i + 1] - poly[i] round the loop
    d_out[:-1] = poly[1:] - poly[:-1]
    d_out[-1] = poly[0] - poly[-1]
    d_in = np.concatenate([d_out[-1:], d_out[:-1]])
    cross = d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]
    dot = np.sum(d_in * d_out, axis=1)
    turn = np.arctan2(cross, dot)
    return turn < -CONCAVE_SEAM_TURN


def seam_index(poly: np.ndarray, mode: str, position: np.ndarray) -> int:
    """Where a loop starts. ``aligned``: the rearmost (+y, then -x) concave corner,
    else the rearmost vertex, so seams hide in corners and line up from layer to
    layer (PrusaSlicer's preference); ``nearest``: the vertex nearest ``position``."""
    if mode == "nearest":
        return int(np.argmin(np.sum((poly - position[:2]) ** 2, axis=1)))
    score = poly[:, 1] * 1.0 - poly[:, 0] * 1e-3
    concave = concave_corners(poly)
    if concave.any():
        score = np.where(concave, score, -np.inf)
    return int(np.argmax(score))


def _next(a: np.ndarray) -> np.ndarray:
    """Each row's successor round a loop, np.roll(a, -1, axis=0) without its set-up (a few
    microseconds a call, thousands of calls a print)."""
    return np.concatenate([a[1:], a[:1]])


def overhang_segments(poly: np.ndarray, below, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Split a loop where it leaves the layer below: (points (m, 2), over (m,) bool per
    segment i -> i+1 mod m). A segment is over air when its midpoint lies outside
    ``below`` (a prepared shapely region: the layer under this one grown by half a
    width, so only a bead with nothing under it counts). Segments are cut every
    ``step`` mm to find where support ends, then merged back where the flag does not
    change, so a loop without overhang comes back unchanged."""
    if shapely.contains(below, shapely.LinearRing(poly)):
        # the whole loop over the layer below (most loops): one prepared test, no cutting
        return poly, np.zeros(len(poly), bool)
    nxt = _next(poly)
    seg = np.linalg.norm(nxt - poly, axis=1)
    n = np.maximum(np.ceil(seg / step).astype(int), 1)
    owner = np.repeat(np.arange(len(poly)), n)
    t = (np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)) / n[owner]
    dense = poly[owner] + t[:, None] * (nxt - poly)[owner]
    mid = 0.5 * (dense + _next(dense))
    over = ~shapely.contains_xy(below, mid[:, 0], mid[:, 1])
    keep = (t == 0) | (over != np.concatenate([over[-1:], over[:-1]]))
    return dense[keep], over[keep]


def loop_path(poly: np.ndarray, start: int) -> np.ndarray:
    """A closed loop as a polyline starting and ending at vertex ``start``."""
    return np.concatenate([poly[start:], poly[: start + 1]])
