"""Extrusion amounts and feed rates per role."""

from __future__ import annotations

import math

import numpy as np

from ..toolpath import Role


def bead_spacing(width, height: float):
    """Distance between neighbouring beads of nominal ``width`` (Slic3r's flow model).

    A bead ``width`` wide (outer edge to outer edge) and ``height`` tall has a
    rounded-rectangle section of area ``(width - height) * height + pi * height**2 / 4``
    = ``height * spacing`` with ``spacing = width - height * (1 - pi / 4)``: beads laid
    ``spacing`` apart fill the layer exactly. Never less than half the width.
    ``width`` may be an array (variable-width gap fill): the result has its shape.
    """
    w = np.asarray(width, float)
    out = np.maximum(w - height * (1.0 - math.pi / 4.0), 0.5 * w)
    return float(out) if out.ndim == 0 else out


def filament_per_mm(width, height: float, filament_area: float, multiplier: float):
    """Filament length pushed per mm of path: spacing * height / filament_area * multiplier,
    with the bead spacing of :func:`bead_spacing` as the effective width (so that
    extruded volume = filled area * height, as in Slic3r/PrusaSlicer)."""
    return bead_spacing(width, height) * height / filament_area * multiplier


def feed_table(settings, first_layer: bool) -> np.ndarray:
    """Requested speed of a move of each role on a layer, mm/s, indexed by role ((max(Role) + 1,)
    float); the first-layer speed caps working moves on layer 0."""
    s = settings
    table = {
        Role.EXTERNAL_PERIMETER: s.external_perimeter_speed,
        Role.PERIMETER: s.perimeter_speed,
        Role.INFILL: s.infill_speed,
        Role.SOLID_INFILL: s.solid_infill_speed,
        Role.TOP_SOLID_INFILL: s.solid_infill_speed,
        Role.SKIRT: s.perimeter_speed,
        Role.TRAVEL: s.travel_speed,
        Role.OVERHANG_PERIMETER: s.overhang_speed,
        Role.BRIDGE_INFILL: s.bridge_speed,
        Role.GAP_FILL: s.perimeter_speed,
        # support: the body at infill speed, its interface (the face the part rests on) slower
        Role.SUPPORT: s.infill_speed,
        Role.SUPPORT_INTERFACE: s.perimeter_speed,
    }
    out = np.empty(max(Role) + 1)
    for r in Role:
        out[r] = s.first_layer_speed if first_layer and r != Role.TRAVEL else table.get(r, s.perimeter_speed)
    return out


def bridge_flow(nozzle: float, filament_area: float, ratio: float) -> float:
    """Filament mm per mm of bridge: a round bead of the nozzle's diameter (PrusaSlicer's
    bridge flow), whatever the layer height, times ``ratio``."""
    return math.pi * nozzle**2 / 4.0 / filament_area * ratio


def segment_lengths(points: np.ndarray) -> np.ndarray:
    """(k, 2|3) polyline -> (k-1,) lengths."""
    return np.linalg.norm(np.diff(points, axis=0), axis=1)
