"""Skirt: loops around the first layer's outline, ``skirt_distance`` away."""

from __future__ import annotations

import numpy as np
from manifold3d import CrossSection, JoinType


def skirt_loops(first_section: CrossSection, loops: int, distance: float, width: float) -> list[np.ndarray]:
    """Closed polygons (k, 2), innermost first, around the convex hull of the first layer."""
    if loops <= 0 or first_section.is_empty():
        return []
    hull = first_section.hull()
    out = []
    for i in range(loops):
        ring = hull.offset(distance + width / 2 + i * width, JoinType.Round, 2.0, 72)
        out.extend(np.asarray(p, float) for p in ring.to_polygons())
    return out
