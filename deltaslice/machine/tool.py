"""The tool channel: an extruder or a laser, and everything that differs between them.

The last channel of every machine is its tool. What a stage needs of it (the
channel's counts, its limits, how high travels lift, how samples map to counts)
is asked of the tool object, so no stage branches on the tool's type.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Extruder:
    """Filament extruder. mm, mm/s, mm^3/s; the channel's value is the filament position (mm)."""

    nozzle_diameter: float
    filament_diameter: float
    max_volumetric_flow: float
    max_filament_acceleration: float
    retract_length: float
    retract_speed: float
    z_hop: float
    retract_min_travel: float
    counts_per_mm: float
    #: Temperatures deltaslice's slicer sets and waits for at the start, degrees C (bed 0: unheated).
    hotend_temperature: float = 200.0
    bed_temperature: float = 0.0
    #: Longest retraction an input may ask for, mm: filament pulled back below where it last extruded.
    max_retract_length: float = 10.0

    channel_kind = "extruder"
    channel_name = "filament"
    channel_unit = "mm"
    #: Events (EventKind names) set to 0 when every job ends: heaters and part fan off.
    off_events = ("hotend_set", "bed_set", "fan")
    #: What an input may ask of the tool: filament (G-code E words) and laser power (M3/M4).
    takes_filament = True
    takes_laser_power = False
    #: The channel's value is a position whose speed is limited, not a power level 0..1.
    channel_is_power = False
    #: Watts at full power (None: the tool burns nothing).
    full_power_w = None

    @property
    def filament_area(self) -> float:
        return math.pi * self.filament_diameter**2 / 4.0

    @property
    def max_filament_speed(self) -> float:
        """Filament feed speed at the maximum volumetric flow, mm/s."""
        return self.max_volumetric_flow / self.filament_area

    @property
    def counts_per_unit(self) -> float:
        return self.counts_per_mm

    def channel_limits(self) -> dict:
        """Position, velocity (working and idle) and acceleration limits of the channel.

        The melt-flow limit applies while extruding; a retract (tool off) moves cold
        filament and may reach the retract speed."""
        return dict(
            position_min=-math.inf,
            position_max=math.inf,
            velocity=self.max_filament_speed,
            idle_velocity=max(self.max_filament_speed, self.retract_speed),
            acceleration=self.max_filament_acceleration,
            jerk=math.nan,
        )

    def travel_lift(self, planning) -> float:
        """How far a travel lifts above the printed part, mm."""
        return planning.travel_lift

    def channel_values(self, e: np.ndarray, tool: np.ndarray) -> np.ndarray:
        """The channel's value per sample, (n,) float: the filament position, mm."""
        return e

    @staticmethod
    def from_channel(values: np.ndarray, before: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(e, tool) per sample from the channel's values: extruding where the filament advances
        (past ``before``, the value of the sample before these, at the first; None: not at the first)."""
        if not len(values):
            return values, np.zeros(0)
        prev = np.concatenate([[values[0] if before is None else before], values[:-1]])
        return values, (values > prev).astype(float)


@dataclass(frozen=True)
class Laser:
    """Laser module switched or PWM-dimmed by the controller; the channel's value is the
    power fraction 0..1."""

    max_power: float
    power_counts: float
    travel_height: float
    spot_size: float = 0.1  # mm: focused spot diameter, the default raster line pitch
    #: G-code S value of full power (GRBL's $30, default 1000).
    s_max: float = 1000.0

    channel_kind = "laser"
    channel_name = "laser"
    channel_unit = "0..1"
    off_events = ("laser_mode", "fan")  # M5 and the air assist off when every job ends
    takes_filament = False
    takes_laser_power = True
    #: The channel's value is the power, a fraction of full power (0..1, no rate limit).
    channel_is_power = True
    retract_min_travel = 0.0  # a laser never retracts: every travel lifts
    max_retract_length = 0.0  # nor takes filament to pull back

    @property
    def counts_per_unit(self) -> float:
        return self.power_counts

    def channel_limits(self) -> dict:
        """Power is a fraction of full power and may step (no rate limit)."""
        return dict(position_min=0.0, position_max=1.0, velocity=math.inf, idle_velocity=math.inf,
                    acceleration=math.inf, jerk=math.nan)

    def travel_lift(self, planning) -> float:
        return self.travel_height

    def channel_values(self, e: np.ndarray, tool: np.ndarray) -> np.ndarray:
        return tool

    @staticmethod
    def from_channel(values: np.ndarray, before: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(e, tool) per sample from the channel's values: no filament, the power as the tool state."""
        return np.zeros(len(values)), values

    @property
    def full_power_w(self) -> float:
        """Optical power at full duty, W (``max_power``): what a power fraction of 1 burns."""
        return self.max_power


Tool = Extruder | Laser
#: The tool classes by their channel's kind name (a stream's header names its tool so).
TOOL_KINDS = {cls.channel_kind: cls for cls in (Extruder, Laser)}


def tool_class(kind: str):
    """The tool class (:data:`TOOL_KINDS`) of a channel kind name; a name of no tool's (a joint's,
    in a stream header whose last channel is not a tool) gives Extruder: a count, working where it rises."""
    return TOOL_KINDS.get(kind, Extruder)
