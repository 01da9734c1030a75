"""Kinematics families. Each is one module with one class following :mod:`.base`."""

from __future__ import annotations

from .base import Kinematics
from .cartesian import Cartesian
from .five_bar import FiveBar
from .linear_delta import LinearDelta
from .rotary_delta import RotaryDelta

__all__ = ["Kinematics", "RotaryDelta", "LinearDelta", "FiveBar", "Cartesian", "make_kinematics"]


def make_kinematics(geometry, position_min, position_max, singularity_limit: float = 50.0) -> Kinematics:
    """Build the kinematics object for a geometry dataclass (see :mod:`deltaslice.printer`)."""
    from ..printer import CartesianGeometry, FiveBarGeometry, LinearDeltaGeometry, RotaryDeltaGeometry

    cls = {
        RotaryDeltaGeometry: RotaryDelta,
        LinearDeltaGeometry: LinearDelta,
        FiveBarGeometry: FiveBar,
        CartesianGeometry: Cartesian,
    }[type(geometry)]
    return cls(geometry, position_min, position_max, singularity_limit)
