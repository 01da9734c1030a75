"""The bed and the default slicing and planning settings of a machine."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Bed:
    """Printable area on the bed, centred on the bed-frame origin. mm."""

    shape: str
    radius: float
    size_x: float
    size_y: float
    max_height: float

    def contains_xy(self, xy: np.ndarray) -> np.ndarray:
        """xy: (n, 2) float, mm -> (n,) bool."""
        xy = np.asarray(xy, dtype=float)
        if self.shape == "circle":
            return np.hypot(xy[:, 0], xy[:, 1]) <= self.radius + 1e-9
        return (np.abs(xy[:, 0]) <= self.size_x / 2 + 1e-9) & (np.abs(xy[:, 1]) <= self.size_y / 2 + 1e-9)


@dataclass(frozen=True)
class SlicingSettings:
    """Default slicing settings. mm, mm/s, fractions; ``fill_angle`` rad."""

    layer_height: float
    first_layer_height: float
    perimeters: int
    top_solid_layers: int
    bottom_solid_layers: int
    fill_density: float
    fill_angle: float
    infill_overlap: float
    perimeter_speed: float
    external_perimeter_speed: float
    infill_speed: float
    solid_infill_speed: float
    first_layer_speed: float
    travel_speed: float
    perimeter_width: float
    infill_width: float
    first_layer_width: float
    extrusion_multiplier: float
    skirt_loops: int
    skirt_distance: float
    seam: str
    gcode_resolution: float = 0.0125  # mm: paths simplified within this deviation (PrusaSlicer gcode_resolution)
    solid_infill_below_area: float = 70.0  # mm^2: infill regions smaller than this are filled solid
    bridge_speed: float = 30.0  # mm/s
    bridge_flow: float = 1.0  # multiplier on a round bead of nozzle diameter over air
    overhang_speed: float = 15.0  # mm/s: perimeters over air


@dataclass(frozen=True)
class PlanningSettings:
    """Planner settings: output sample rate (Hz), corner blend tolerance (mm), the
    fraction of each limit kept in reserve (``limit_margin``), travel lift (mm), the
    Jacobian condition number beyond which a pose counts as singular, and ``torque_limit``: "on"
    plans to the ``[dynamics]`` actuators' torque and speed-torque curve as well as the joints'
    limits (where the file has ``[dynamics]``), "off" to the joints' limits alone."""

    output_rate: float
    blend_tolerance: float
    limit_margin: float
    travel_lift: float
    singularity_limit: float
    torque_limit: str = "on"
