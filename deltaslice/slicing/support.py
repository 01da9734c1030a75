"""Supports: regions under overhangs, computed once for every layer before the layers' paths.

A layer's *overhang* is what it has beyond the layer below grown by ``h * tan(support_angle)``
(a wall steeper than ``support_angle`` from vertical holds itself up; a flatter one, a
cantilever or a bridge does not), less slivers thinner than a bead. Support columns are carried
down from each overhang, ``z_gap`` layers below it (the gap that lets them break away), to the
bed or to the part's top surface (``support_type = "everywhere"``), or only where nothing of the
part lies below them (``"buildplate"``, Cura's name), and kept ``xy_gap`` away from the part
sideways. The top ``interface_layers`` of each column, those right under the part, are dense
lines across the body's (a flat face to print the overhang on); the body is sparse lines
``spacing`` apart, in one direction on every layer so the lines stack into walls.

Everything is manifold3d :class:`CrossSection` booleans and offsets, one pass down the layers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from manifold3d import CrossSection, JoinType, OpType

from .infill import clean


@dataclass(frozen=True)
class SupportLayer:
    """One layer's support: ``body`` (sparse lines) and ``interface`` (dense lines under the
    part), regions where line centres go, mm. Both empty where the layer has none."""

    body: CrossSection
    interface: CrossSection


NO_SUPPORT = SupportLayer(CrossSection(), CrossSection())


def _union(regions: list) -> CrossSection:
    regions = [r for r in regions if not r.is_empty()]
    if not regions:
        return CrossSection()
    return CrossSection.batch_boolean(regions, OpType.Add) if len(regions) > 1 else regions[0]


def overhangs(sections: list, thick, angle: float, width: float) -> list:
    """Per layer, the region (CrossSection) needing support: the layer less the layer below grown
    by ``thick[i] * tan(angle)`` (angle from vertical, rad), opened by a quarter bead (slivers of
    a slope just past the angle are not worth a column). Layer 0 sits on the bed: none."""
    out = [CrossSection()]
    for i in range(1, len(sections)):
        here, below = sections[i], sections[i - 1]
        if here.is_empty():
            out.append(CrossSection())
            continue
        reach = float(thick[i]) * math.tan(angle)
        grown = below.offset(reach, JoinType.Miter, 3.0) if not below.is_empty() else below
        out.append(clean(here - grown, width / 4))
    return out


def support_layers(sections: list, thick, layer_height: float, s, width: float) -> list:
    """Every layer's :class:`SupportLayer` ((L,) list) for the settings ``s`` (``support``,
    ``support_angle`` rad, ``support_z_gap`` mm, ``support_xy_gap`` mm, ``support_interface_layers``,
    ``support_type``); width: the support bead width, mm. All empty for ``support = "none"``."""
    n = len(sections)
    if s.support != "auto" or n < 2:
        return [NO_SUPPORT] * n
    over = overhangs(sections, thick, s.support_angle, width)
    gap = max(0, int(round(s.support_z_gap / layer_height)))
    n_iface = int(s.support_interface_layers)
    # where line centres may not go: the part, and xy_gap plus half a bead around it
    keep_out = [c.offset(s.support_xy_gap + width / 2, JoinType.Miter, 3.0) if not c.is_empty() else c for c in sections]
    bed_only = s.support_type == "buildplate"
    shadow = CrossSection()  # the part at and below a layer (buildplate: no column may stand on it)
    shadows = []
    if bed_only:
        for c in sections:
            shadow = shadow + c if not c.is_empty() else shadow
            shadows.append(shadow)
    out = [NO_SUPPORT] * n
    carry = CrossSection()  # columns coming down from the overhangs above, before the part cuts them
    for j in range(n - 1, -1, -1):
        src = j + gap + 1
        if src < n and not over[src].is_empty():
            carry = carry + over[src]
        if carry.is_empty():
            continue
        if not sections[j].is_empty():
            carry = carry - sections[j]  # a column stops on the part's top surface
        region = carry - keep_out[j] if not keep_out[j].is_empty() else carry
        # the z gap above the part's top surfaces too (the column's foot breaks away)
        for k in range(max(0, j - gap), j):
            if not sections[k].is_empty():
                region = region - sections[k]
        if bed_only:
            region = region - shadows[j]
        region = clean(region, width / 4)
        if region.is_empty():
            continue
        above = _union([sections[k] for k in range(j + gap + 1, min(n, j + gap + 1 + n_iface))]) if n_iface else CrossSection()
        interface = clean(region ^ above, width / 4) if not above.is_empty() else CrossSection()
        body = region - interface if not interface.is_empty() else region
        out[j] = SupportLayer(body, interface)
    return out
