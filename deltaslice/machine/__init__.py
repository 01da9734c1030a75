"""The machine: the one contract of a printer or engraver.

``load_printer(path)`` (alias ``load_machine``) reads and validates a printer file into a
frozen :class:`Printer` holding the kinematics (built once), the :class:`Limits` of every
channel, the tool, the bed and the default settings. Stages take what they need of it.
``load_printer(path, reach_checks=False)`` leaves out the checks that need the compiled
kinematics; ``check_reach(printer)`` does them (a compile does them while its slicing
workers start).
"""

from __future__ import annotations

from .dynamics import ActuatorCurves, Dynamics
from .limits import ChannelLimits, LimitMonitor, Limits
from .printer import Printer
from .reader import ACTUATOR_KINDS, check_reach, load_printer, printer_from_dict
from .settings import Bed, HomingSettings, PlanningSettings, SafetySettings, SlicingSettings
from .tool import Extruder, Laser, Tool

load_machine = load_printer
Machine = Printer

__all__ = [
    "ACTUATOR_KINDS", "ActuatorCurves", "Bed", "ChannelLimits", "Dynamics", "Extruder", "HomingSettings", "Laser",
    "LimitMonitor", "Limits", "Machine", "PlanningSettings", "Printer", "SafetySettings", "SlicingSettings", "Tool",
    "check_reach", "load_machine", "load_printer", "printer_from_dict",
]
