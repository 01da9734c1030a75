"""Perimeters: inward offsets of each island's outline.

The outer loop runs half a perimeter width inside the outline, each further
loop one width further in; holes get their loops too (the offsets of a
cross-section with holes grow the holes). Loops that vanish (a region thinner
than the offset) are dropped. The region left for infill is the inner edge of
the innermost perimeter.
"""

from __future__ import annotations

import numpy as np
from manifold3d import CrossSection, JoinType

MIN_LOOP_LENGTH_FACTOR = 2.0  # drop loops shorter than this many widths


def perimeter_loops(island: CrossSection, width: float, count: int, spacing: float | None = None) -> list[tuple[int, np.ndarray]]:
    """[(depth, (k, 2) closed polygon without repeated end point)], depth 0 = external.

    Loop k runs ``width / 2 + k * spacing`` inside the outline (spacing: the bead
    spacing, default ``width``)."""
    spacing = width if spacing is None else spacing
    loops = []
    for k in range(count):
        ring = island.offset(-(width / 2 + k * spacing), JoinType.Miter, 3.0)
        if ring.is_empty():
            break
        for poly in ring.to_polygons():
            if len(poly) < 3:
                continue
            per = np.linalg.norm(np.diff(np.vstack([poly, poly[:1]]), axis=0), axis=1).sum()
            if per < MIN_LOOP_LENGTH_FACTOR * width:
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


def seam_index(poly: np.ndarray, mode: str, position: np.ndarray) -> int:
    """Where a loop starts. ``aligned``: the vertex furthest towards +y (rear), then
    -x, so seams line up from layer to layer; ``nearest``: the vertex nearest
    ``position``."""
    if mode == "nearest":
        return int(np.argmin(np.sum((poly - position[:2]) ** 2, axis=1)))
    score = poly[:, 1] * 1.0 - poly[:, 0] * 1e-3
    return int(np.argmax(score))


def loop_path(poly: np.ndarray, start: int) -> np.ndarray:
    """A closed loop as a polyline starting and ending at vertex ``start``."""
    rolled = np.roll(poly, -start, axis=0)
    return np.vstack([rolled, rolled[:1]])
