"""PlanContext: what planning takes of a printer and of the command's options, built once.

The planner plans to the margin-reduced limits (``Printer.planned_limits``) and checks every run
against the printer's own (``machine_limits``); both come from here, never from the printer, so
every channel (joints, the tool channel, its retracts) keeps the same margin. The tool's meaning
is the Tool object's (``tool.takes_filament``, ``takes_laser_power``, ``off_events``): planning
asks it, and never compares its kind. Frozen and picklable: the worker processes get one.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .torque import TorqueLimits, torque_limits

SOLVERS = ("fast", "toppra")  # the speed-profile solvers: compiled reachability (default), toppra (reference)
SPEED_LIMITS = ("feed", "machine")  # the toolpath's feeds and the actuators' limits, or the limits alone


@dataclass(frozen=True, eq=False)
class PlanContext:
    """One plan's settings. kin: the printer's kinematics; planned_limits, machine_limits: the
    Limits of every channel (joints, then the tool channel) less ``limit_margin`` (what the planner
    plans to) and as the printer file gives them (what the stage-wise check holds, and what a
    message names); torque: the planned and real actuator limits (:class:`.torque.TorqueLimits`),
    or None; dynamics: the printer whose dynamics model :mod:`.torque` evaluates, None without
    torque limits; tool: the Tool (what its channel does); blend_tolerance mm; output_rate Hz;
    travel_speed mm/s (a travel without a feed of its own, the moves from and to rest);
    travel_lift mm (the tool's lift over the printed part); approach_height mm, approach_speed
    mm/s (the vertical moves onto the first point and off the last); rest_pose (J,) joint units;
    name: the printer's name (messages); speed_limit: "feed" or "machine"; solver: "fast" or
    "toppra"; jerk_limit: whether runs from rest to rest are re-timed within the jerk limits
    (:mod:`.jerk`)."""

    kin: object
    planned_limits: object
    machine_limits: object
    torque: TorqueLimits | None
    dynamics: object | None
    tool: object
    blend_tolerance: float
    output_rate: float
    travel_speed: float
    travel_lift: float
    approach_height: float
    approach_speed: float
    rest_pose: np.ndarray = field(repr=False)
    name: str
    speed_limit: str = "feed"
    solver: str = "fast"
    jerk_limit: bool = False

    @classmethod
    def of(cls, printer, speed_limit: str = "feed", solver: str = "fast") -> "PlanContext":
        """The context of ``printer`` for a plan with these options (checked by the caller)."""
        torque = torque_limits(printer)
        planning = printer.planning
        return cls(printer.kinematics(), printer.planned_limits(), printer.limits, torque,
                   printer if torque is not None else None, printer.tool, float(planning.blend_tolerance),
                   float(planning.output_rate), float(printer.slicing.travel_speed),
                   float(printer.tool.travel_lift(planning)), float(planning.approach_height),
                   float(planning.approach_speed), np.asarray(printer.rest_pose, float), printer.name,
                   speed_limit, solver, planning.jerk_limit == "on")

    def with_speed_limit(self, speed_limit: str) -> "PlanContext":
        """This context under another speed limit (the approach's vertical moves keep their feed)."""
        return self if speed_limit == self.speed_limit else replace(self, speed_limit=speed_limit)

    @property
    def n_joints(self) -> int:
        return self.kin.n_joints

    @property
    def plans_torque(self) -> bool:
        """Whether the solver plans the actuators' torque (the compiled solver, with torque limits)."""
        return self.torque is not None and self.solver == "fast"

    @property
    def retract_speed(self) -> float:
        """A retract's filament speed, mm/s: the tool's retract speed within the tool channel's
        planned idle limit (only an extruder retracts)."""
        return min(float(self.tool.retract_speed), self.planned_limits.tool_velocity_limits()[1])

    @property
    def retract_acceleration(self) -> float:
        """A retract's filament acceleration, mm/s^2: the tool channel's planned limit."""
        return float(self.planned_limits.acceleration[-1])
