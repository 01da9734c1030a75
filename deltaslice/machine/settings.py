"""The bed and the default slicing and planning settings of a machine."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: How far outside the work envelope (below the bed, above max_height, off its edge) a commanded
#: point may be, mm: coordinates written to a micron, offsets summed in floating point.
ENVELOPE_TOLERANCE = 1e-6


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

    def z_limits(self) -> tuple[float, float]:
        """(lowest, highest) z a commanded tool point may have, mm: the bed surface and max_height,
        each with :data:`ENVELOPE_TOLERANCE` (a file's coordinates are rounded)."""
        return -ENVELOPE_TOLERANCE, self.max_height + ENVELOPE_TOLERANCE

    def contains(self, points: np.ndarray) -> np.ndarray:
        """The work envelope: points (n, 3) mm -> (n,) bool, on or above the bed surface, at most
        max_height above it and over the bed (the declared build volume)."""
        points = np.asarray(points, dtype=float)
        lo, hi = self.z_limits()
        return (points[:, 2] >= lo) & (points[:, 2] <= hi) & self.contains_xy(points[:, :2])

    def outside(self, point) -> str:
        """Why ``point`` (3,) mm is outside the work envelope (:meth:`contains`), or "" when it is not."""
        x, y, z = (float(v) for v in point)
        lo, hi = self.z_limits()
        if not z >= lo:
            return f"{-z:.2f} mm below the bed surface"
        if not z <= hi:
            return f"{z - self.max_height:.2f} mm above [bed] max_height = {self.max_height:g} mm"
        if not self.contains_xy(np.array([[x, y]]))[0]:
            what = (f"a circle of radius {self.radius:g} mm" if self.shape == "circle"
                    else f"{self.size_x:g} x {self.size_y:g} mm")
            return f"off the bed ({what} about its centre)"
        return ""


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
    Jacobian condition number beyond which a pose counts as singular, and the job's
    approach: the height (mm) above the first point (and above the printed part at the
    end) the tool comes down from and lifts to, and the speed of that vertical move (mm/s)."""

    output_rate: float
    blend_tolerance: float
    limit_margin: float
    travel_lift: float
    singularity_limit: float
    approach_height: float = 5.0
    approach_speed: float = 4.0
