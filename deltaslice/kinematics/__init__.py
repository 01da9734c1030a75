"""Kinematics families, one module each, as Klipper keeps ``klippy/kinematics/``.

A family module holds everything about one kind of machine: ``FAMILY`` (its name in
a printer file's ``[kinematics] family``), its geometry dataclass, ``read_geometry``
(how the ``[kinematics]`` table is read and validated) and its kinematics class
(``KINEMATICS``, following the contract in :mod:`.base`). Adding a family is adding
a module here: families are discovered by name, nothing else lists them.
"""

from __future__ import annotations

import functools
import importlib
import pkgutil

from .base import Kinematics

__all__ = ["Kinematics", "FAMILIES", "family", "make_kinematics"]

_NOT_FAMILIES = {"base", "workspace"}


@functools.cache
def _modules() -> dict:
    out = {}
    for info in pkgutil.iter_modules(__path__):
        if info.name in _NOT_FAMILIES or info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        out[module.FAMILY] = module
    return out


FAMILIES = tuple(sorted(_modules()))


def family(name: str):
    """The family module called ``name`` (``rotary_delta``, ``linear_delta``, ...). KeyError if none."""
    return _modules()[name]


def make_kinematics(geometry, position_min, position_max, singularity_limit: float = 50.0) -> Kinematics:
    """Build the kinematics object for a family's geometry dataclass.

    position_min, position_max: (J,) float, joint units (rad or mm)."""
    module = importlib.import_module(type(geometry).__module__)
    return module.KINEMATICS(geometry, position_min, position_max, singularity_limit)
