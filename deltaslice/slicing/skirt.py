"""Skirt and brim: loops around the first layer's outline.

The skirt runs ``skirt_distance`` outside the convex hull of the first layer (and of its brim);
the brim (PrusaSlicer's outer-only brim) is loops touching the outer outline of every island,
``brim_width`` wide, on the first layer only.
"""

from __future__ import annotations

import math

import numpy as np
from manifold3d import CrossSection, FillRule, JoinType

from ..tolerances import COUNT_ROUNDOFF


def skirt_loops(first_section: CrossSection, loops: int, distance: float, width: float) -> list[np.ndarray]:
    """Closed polygons (k, 2), innermost first, around the convex hull of the first layer
    (``first_section``, with its brim when there is one: :func:`brim_outline`)."""
    if loops <= 0 or first_section.is_empty():
        return []
    hull = first_section.hull()
    out = []
    for i in range(loops):
        ring = hull.offset(distance + width / 2 + i * width, JoinType.Round, 2.0, 72)
        out.extend(np.asarray(p, float) for p in ring.to_polygons())
    return out


def outer_outline(section: CrossSection) -> CrossSection:
    """``section`` with its holes filled: the union of its counter-clockwise (outer) contours."""
    outer = []
    for p in section.to_polygons():
        p = np.asarray(p, float)
        x, y = p[:, 0], p[:, 1]
        if len(p) >= 3 and np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)) > 0:
            outer.append(p)
    return CrossSection(outer, FillRule.NonZero) if outer else CrossSection()


def brim_count(brim_width: float, spacing: float) -> int:
    """Brim loops that fit in ``brim_width`` mm at bead ``spacing`` (PrusaSlicer: floor)."""
    return int(math.floor(brim_width / spacing + COUNT_ROUNDOFF)) if brim_width > 0 and spacing > 0 else 0


def brim_loops(first_section: CrossSection, brim_width: float, width: float, spacing: float) -> list[np.ndarray]:
    """Closed polygons (k, 2), mm, of a brim around the islands' outer outlines (not in holes):
    loop i's centre line ``spacing / 2 + i * spacing`` outside the outline, so the first bead
    touches the external perimeter; outermost first (printed from the outside in, the last loop
    against the part). Loops of neighbouring islands merge where they meet."""
    n = brim_count(brim_width, spacing)
    if n == 0 or first_section.is_empty():
        return []
    outline = outer_outline(first_section)
    out = []
    for i in reversed(range(n)):
        ring = outline.offset(spacing / 2 + i * spacing, JoinType.Round, 2.0, 72)
        out.extend(np.asarray(p, float) for p in ring.to_polygons() if len(p) >= 3)
    return out


def brim_extent(brim_width: float, width: float, spacing: float) -> float:
    """How far the brim's outer edge lies outside the part, mm (0 without a brim)."""
    n = brim_count(brim_width, spacing)
    return n * spacing + (width - spacing) / 2 if n else 0.0
