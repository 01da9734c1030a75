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
    fraction of each limit kept in reserve (``limit_margin``), travel lift (mm) and the
    Jacobian condition number beyond which a pose counts as singular."""

    output_rate: float
    blend_tolerance: float
    limit_margin: float
    travel_lift: float
    singularity_limit: float


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
