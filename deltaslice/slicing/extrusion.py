"""Extrusion amounts and feed rates per role."""

from __future__ import annotations

import numpy as np

from ..toolpath import Role


def filament_per_mm(width: float, height: float, filament_area: float, multiplier: float) -> float:
    """Filament length pushed per mm of path: width * height / filament_area * multiplier."""
    return width * height / filament_area * multiplier


def feed_for(role: int, settings, first_layer: bool) -> float:
    """Requested speed of a move of ``role``, mm/s (first-layer speed caps working moves on layer 0)."""
    s = settings
    table = {
        Role.EXTERNAL_PERIMETER: s.external_perimeter_speed,
        Role.PERIMETER: s.perimeter_speed,
        Role.INFILL: s.infill_speed,
        Role.SOLID_INFILL: s.solid_infill_speed,
        Role.TOP_SOLID_INFILL: s.solid_infill_speed,
        Role.SKIRT: s.perimeter_speed,
        Role.TRAVEL: s.travel_speed,
    }
    v = float(table.get(Role(role), s.perimeter_speed))
    if first_layer and role != Role.TRAVEL:
        v = float(s.first_layer_speed)
    return v


def segment_lengths(points: np.ndarray) -> np.ndarray:
    """(k, 2|3) polyline -> (k-1,) lengths."""
    return np.linalg.norm(np.diff(points, axis=0), axis=1)
