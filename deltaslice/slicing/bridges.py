"""Bridges: solid regions with air (or sparse infill) under them.

The part of a layer's solid infill that the layer below does not hold up is
bridged: grown by an anchor distance into what is held up (lines start and end
on something), filled with lines across the shortest span, a round bead of
nozzle diameter at the bridge speed. The direction, out of 12, is the one whose
lines crossing the air rest on support at both ends over the greatest length (a
deck between two towers is crossed from tower to tower), then at one end (a
cantilever's lines run out of the block holding it), ties going to the shortest
mean line (the shortest span).
"""

from __future__ import annotations

import math

import numpy as np
import shapely
from manifold3d import CrossSection, JoinType

from .infill import scanline_segments

ANGLES = np.radians(np.arange(0.0, 180.0, 15.0))


def bridge_angle(bridge: CrossSection, support, spacing: float, fallback: float, air=None) -> float:
    """Angle (rad) of bridge lines over ``bridge`` (the grown region). Only lines that cross the
    air count (their middle over ``air``, a prepared shapely region, when given): most length
    anchored at both ends in ``support`` (a prepared shapely region or None), then most anchored
    at one end (a cantilever's lines run out of the block that holds them, not along its edge),
    then the shortest mean line."""
    best, best_key = fallback, (-math.inf, -math.inf, -math.inf)
    for a in ANGLES.tolist():
        k, xa, xb = scanline_segments(bridge, a, spacing)
        if len(xa) == 0:
            continue
        both = one = 0.0
        if support is not None:
            y = (k + 0.5) * spacing
            c, s = math.cos(a), math.sin(a)
            # rotated frame back to the bed: p_bed = (x c - y s, x s + y c)
            ends = [(x * c - y * s, x * s + y * c) for x in (xa + 0.25 * spacing, xb - 0.25 * spacing, (xa + xb) / 2)]
            at_a = shapely.contains_xy(support, *ends[0])
            at_b = shapely.contains_xy(support, *ends[1])
            crosses = shapely.contains_xy(air, *ends[2]) if air is not None else np.ones(len(xa), bool)
            length = xb - xa
            both = float(np.sum(length[at_a & at_b & crosses]))
            one = float(np.sum(length[(at_a ^ at_b) & crosses]))
        key = (round(both, 3), round(one, 3), -float(np.mean(xb - xa)))
        if key > best_key:
            best, best_key = a, key
    return best


def bridge_region(solid: CrossSection, below: CrossSection, anchor: float, min_width: float) -> tuple[CrossSection, CrossSection]:
    """(bridge, unsupported): the part of ``solid`` not over ``below``, thicker than
    ``min_width``, grown by ``anchor`` mm into ``solid``; and the unsupported part itself."""
    if solid.is_empty():
        return CrossSection(), CrossSection()
    air = solid - below if not below.is_empty() else solid
    if air.is_empty():
        return CrossSection(), CrossSection()
    air = air.offset(-min_width / 2, JoinType.Miter, 3.0).offset(min_width / 2, JoinType.Miter, 3.0)
    if air.is_empty() or air.area() < min_width**2:
        return CrossSection(), CrossSection()
    return air.offset(anchor, JoinType.Miter, 3.0) ^ solid, air
