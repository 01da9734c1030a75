"""The Printer: one frozen, validated description of a machine, built once at load."""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from ..kinematics import Kinematics
from .dynamics import Dynamics
from .limits import ChannelLimits, Limits
from .settings import Bed, HomingSettings, PlanningSettings, SafetySettings, SlicingSettings
from .tool import Tool


@dataclass(frozen=True)
class Printer:
    """A validated printer file. Frozen: share it freely between stages and processes.

    ``kinematics`` is built once from the geometry, the joint position limits and the
    singularity limit; ``limits`` holds every channel's limits and counts (joints, then
    the tool channel); ``rest_pose`` (J,) joint units: where every trajectory starts and ends;
    ``sensor_table`` per joint: ``((reading, joint value), ...)`` sorted by reading, joint units
    (rad or mm), () for a joint without an absolute sensor; ``dynamics``: the ``[dynamics]`` table
    (masses and actuator curves), None where the file has none; ``safety``: the players' heater
    protection and host time-out (``[safety]``); ``homing``: their end stops (``[homing]``)."""

    name: str
    path: str
    description: str
    family: str
    geometry: object
    limits: Limits
    actuator: str
    tool: Tool
    bed: Bed
    slicing: SlicingSettings
    planning: PlanningSettings
    kinematics_: Kinematics = field(repr=False, compare=False)
    rest_pose: np.ndarray = field(repr=False, compare=False, default=None)
    sensor_table: tuple = ()
    dynamics: Dynamics | None = None
    sources: dict = field(default_factory=dict, compare=False, hash=False)
    # False for a printer read with load_printer(reach_checks=False) and not yet through
    # machine.check_reach: its rest pose may be unset and nothing plans with it
    reach_checked: bool = field(default=True, repr=False, compare=False)
    # what the firmware players guard (heater limits, host time-out): not the trajectory's
    safety: SafetySettings = field(default_factory=SafetySettings, compare=False)
    homing: HomingSettings = field(default_factory=HomingSettings, compare=False)

    @property
    def n_joints(self) -> int:
        return self.limits.n_joints

    @property
    def joints(self) -> tuple[ChannelLimits, ...]:
        """Each joint's limits and counts (views of :attr:`limits`)."""
        return self.limits.joints

    @property
    def is_laser(self) -> bool:
        return self.tool.channel_kind == "laser"

    def kinematics(self) -> Kinematics:
        """The kinematics object of this printer's family (built once, at load)."""
        return self.kinematics_

    def joint_torques(self, q, qd, qdd) -> np.ndarray:
        """Joint torques (N m) or forces (N), (N, J), that move the joints along q (N, J) rad or mm
        with velocities qd and accelerations qdd (per s, per s^2), from the family's inverse
        dynamics with this printer's masses. ValueError where the file has no ``[dynamics]``."""
        if self.dynamics is None:
            raise ValueError(f"{self.name} has no [dynamics] table")
        return self.kinematics_.inverse_dynamics(self.dynamics.masses, q, qd, qdd)

    def torque_path_coefficients(self, q, dq, ddq, points=None):
        """The joint torques along a path q(s) as ``A sdd + B sd^2 + C`` (the form of the planner's
        acceleration constraint): q, dq = dq/ds, ddq = d2q/ds2 (N, J), points (N, 3) mm the tool
        tips at q (forward kinematics when not given) -> (A, B, C), each (N, J) N m or N, from the
        family's ``torque_coefficients``. ValueError where the file has no ``[dynamics]``."""
        if self.dynamics is None:
            raise ValueError(f"{self.name} has no [dynamics] table")
        kin = self.kinematics_
        points = kin.forward(q) if points is None else points
        return kin.torque_coefficients(self.dynamics.masses, points, q, dq, ddq)

    def joint_from_sensor(self, joint: int, readings) -> np.ndarray:
        """Joint values (joint units) of raw sensor readings of one joint, interpolated
        piecewise-linearly in ``sensor_table`` and extrapolated along its end segments.
        readings: (n,) float -> (n,) float. Raises ValueError for a joint without a table."""
        table = self.sensor_table[joint] if self.sensor_table else ()
        if not table:
            raise ValueError(f"joint {joint + 1} of {self.name} has no sensor_table")
        r, v = np.array(table).T
        x = np.asarray(readings, dtype=float)
        out = np.interp(x, r, v)
        lo, hi = x < r[0], x > r[-1]
        out[lo] = v[0] + (x[lo] - r[0]) * (v[1] - v[0]) / (r[1] - r[0])
        out[hi] = v[-1] + (x[hi] - r[-1]) * (v[-1] - v[-2]) / (r[-1] - r[-2])
        return out

    def planned_limits(self) -> Limits:
        """The limits the planner plans to: every rate limit times ``1 - limit_margin``. Made once
        (the planner asks for them for every move it plans)."""
        planned = self.__dict__.get("_planned_limits")
        if planned is None:
            planned = self.limits.scaled(1.0 - self.planning.limit_margin)
            object.__setattr__(self, "_planned_limits", planned)  # a cache of a frozen value, not a field
        return planned

    def planned_actuators(self):
        """The actuator curves the planner plans to: every torque (force) times ``1 - limit_margin``,
        as :meth:`planned_limits` scales the rate limits. None without ``[dynamics]``."""
        if self.dynamics is None:
            return None
        return self.dynamics.actuators.scaled(1.0 - self.planning.limit_margin)

    def fingerprint(self) -> int:
        """A 32-bit CRC of the geometry and joint counts: a stream compiled for one
        printer is refused by another."""
        J = self.n_joints
        counts = [(float(c), float(z)) for c, z in zip(self.limits.counts_per_unit[:J], self.limits.zero_count[:J])]
        return zlib.crc32(repr((self.family, self.geometry, counts)).encode())
