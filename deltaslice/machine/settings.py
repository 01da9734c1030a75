"""The bed and the default slicing and planning settings of a machine."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..tolerances import SAME_LENGTH

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
            return np.hypot(xy[:, 0], xy[:, 1]) <= self.radius + SAME_LENGTH
        return (np.abs(xy[:, 0]) <= self.size_x / 2 + SAME_LENGTH) & (np.abs(xy[:, 1]) <= self.size_y / 2 + SAME_LENGTH)

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
class CoolingSettings:
    """Part-cooling fan and minimum layer time (PrusaSlicer's cooling options, its defaults).

    Fan speeds are percent 0..100 (PrusaSlicer's units; events carry 0..255); times s; speeds
    mm/s. A layer printed faster than ``slowdown_below_layer_time`` is slowed down to take that
    long, no move below ``min_print_speed``; the fan runs at ``max_fan_speed`` for such a layer,
    falls linearly to ``min_fan_speed`` at ``fan_below_layer_time`` and stays there for longer
    layers; it is off on the first ``disable_fan_first_layers`` layers. Bridges and overhang
    perimeters run it at their own speeds. A machine without a part fan: every speed 0."""

    min_fan_speed: float = 35.0
    max_fan_speed: float = 100.0
    bridge_fan_speed: float = 100.0
    overhang_fan_speed: float = 100.0
    disable_fan_first_layers: int = 3
    fan_below_layer_time: float = 60.0
    slowdown_below_layer_time: float = 5.0
    min_print_speed: float = 10.0


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
    fill_pattern: str = "rectilinear"  # sparse infill: "rectilinear" | "grid"
    brim_width: float = 0.0  # mm: brim loops around the first layer's outer outlines (0: none)
    support: str = "none"  # "none" | "auto": support under overhangs flatter than support_angle
    support_angle: float = 0.8726646259971648  # rad from vertical (50 deg)
    support_z_gap: float = 0.2  # mm between a support's top and the part
    support_xy_gap: float = 0.25  # mm between a support's lines and the part's edge
    support_interface_layers: int = 3  # dense layers at the top of each support
    support_spacing: float = 2.5  # mm between the centre lines of the support's body
    support_type: str = "everywhere"  # "everywhere" | "buildplate" (only columns standing on the bed)
    support_pattern: str = "rectilinear"  # "rectilinear" (one direction) | "grid" (alternating by layer)
    cooling: CoolingSettings = CoolingSettings()  # the printer file's [cooling] table


@dataclass(frozen=True)
class PlanningSettings:
    """Planner settings: output sample rate (Hz), corner blend tolerance (mm), the
    fraction of each limit kept in reserve (``limit_margin``), travel lift (mm), the
    Jacobian condition number beyond which a pose counts as singular, the job's approach: the
    height (mm) above the first point (and above the printed part at the end) the tool comes
    down from and lifts to, and the speed of that vertical move (mm/s), and ``torque_limit``:
    "on" plans to the ``[dynamics]`` actuators' torque and speed-torque curve as well as the
    joints' limits (where the file has ``[dynamics]``), "off" to the joints' limits alone;
    ``jerk_limit``: "on" re-times runs and straight travels within each channel's ``jerk_max``
    (:mod:`deltaslice.planning.jerk`), "off" (the default: the re-timing's linear programs cost
    50-500 times the planning they follow) leaves them bang-bang in path acceleration."""

    output_rate: float
    blend_tolerance: float
    limit_margin: float
    travel_lift: float
    singularity_limit: float
    approach_height: float = 5.0
    approach_speed: float = 4.0
    torque_limit: str = "on"
    jerk_limit: str = "off"


@dataclass(frozen=True)
class SafetySettings:
    """What a firmware player guards, written into its configuration header (``deltaslice
    firmware-config``). Temperatures deg C, times s. The defaults are Marlin 2.1's
    (``Configuration.h`` HEATER_0_MINTEMP/MAXTEMP, BED_MINTEMP/MAXTEMP; ``Configuration_adv.h``
    WATCH_TEMP_*, WATCH_BED_TEMP_*, THERMAL_PROTECTION_*): a heater being heated must rise by
    ``*_heating_gain`` within every ``*_heating_period`` until it reaches its set point; once there,
    a drop of more than ``*_hold_drop`` below it lasting ``*_hold_period`` is a thermal runaway.
    ``wait_timeout``: the longest heating wait; ``host_timeout``: the longest the board waits for a
    byte it has asked for before it switches its heaters off (Klipper's MCU drops a heater its host
    has not refreshed for 3 s, its MAX_HEAT_TIME)."""

    hotend_min_temp: float = 5.0
    hotend_max_temp: float = 275.0
    bed_min_temp: float = 5.0
    bed_max_temp: float = 150.0
    hotend_heating_period: float = 40.0
    hotend_heating_gain: float = 2.0
    bed_heating_period: float = 60.0
    bed_heating_gain: float = 2.0
    hotend_hold_period: float = 40.0
    hotend_hold_drop: float = 4.0
    bed_hold_period: float = 20.0
    bed_hold_drop: float = 2.0
    wait_timeout: float = 900.0
    host_timeout: float = 5.0


@dataclass(frozen=True)
class HomingSettings:
    """Where a player finds its joints at the start of a job (``[homing]``): per joint, the side of
    its end stop (``endstop``: +1 at the joint's high end, -1 at its low end, 0 none: the joint is
    put at the rest pose by hand), the joint position where that switch trips and the speed it is
    approached at (joint units: rad or mm, per s). A player with end stops homes every joint that
    has one, then moves to the rest pose, then plays."""

    endstop: tuple = ()
    position: tuple = ()
    speed: tuple = ()

    @property
    def enabled(self) -> bool:
        return any(self.endstop)
