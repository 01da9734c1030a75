"""Typed access to one TOML table of a printer file, in the manner of Klipper's config getters.

Every failure raises :class:`~deltaslice.errors.PrinterFileError` naming the file, the
``[section] key``, the value and the bound it broke. The machine reader
(:mod:`deltaslice.machine.reader`) and every kinematics family's ``read_geometry``
use these getters, so a family file reads its own ``[kinematics]`` keys.
"""

from __future__ import annotations

import math
from typing import Any

from .errors import PrinterFileError


class Section:
    """Typed access to one TOML table, in the manner of Klipper's config getters:
    every failure names the file, the key, the value and the bound."""

    def __init__(self, path: str, name: str, data: Any):
        self.path = path
        self.name = name
        if not isinstance(data, dict):
            self.fail(None, data, "a table")
        self.data = data
        self.used: set[str] = set()

    def _where(self, key: str | None) -> str:
        return f"[{self.name}]" if key is None else f"[{self.name}] {key}"

    def fail(self, key, value, expected):
        shown = "missing" if value is MISSING else f"= {value!r}"
        raise PrinterFileError(f"{self.path}: {self._where(key)} {shown}: expected {expected}")

    def get(self, key, default):
        self.used.add(key)
        if key in self.data:
            return self.data[key]
        if default is MISSING:
            self.fail(key, MISSING, "a value (required key)")
        return default

    def getstr(self, key, default=None, choices=None, required=True):
        value = self.get(key, MISSING if required else default)
        if value is None and not required:
            return None
        if not isinstance(value, str):
            self.fail(key, value, "a string")
        if choices is not None and value not in choices:
            self.fail(key, value, "one of " + ", ".join(choices))
        return value

    def getfloat(self, key, default=None, *, required=None, above=None, minval=None, maxval=None):
        required = default is None if required is None else required
        value = self.get(key, MISSING if required else default)
        if value is None:
            return None
        return self._check_float(key, value, above, minval, maxval)

    def _check_float(self, key, value, above, minval, maxval):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, value, "a number")
        value = float(value)
        if not math.isfinite(value):
            self.fail(key, value, "a finite number")
        if above is not None and not value > above:
            self.fail(key, value, f"a number > {above:g}")
        if minval is not None and value < minval:
            self.fail(key, value, f"a number >= {minval:g}")
        if maxval is not None and value > maxval:
            self.fail(key, value, f"a number <= {maxval:g}")
        return value

    def getint(self, key, default=None, *, minval=None, maxval=None, choices=None):
        value = self.get(key, MISSING if default is None else default)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, value, "an integer")
        if minval is not None and value < minval:
            self.fail(key, value, f"an integer >= {minval}")
        if maxval is not None and value > maxval:
            self.fail(key, value, f"an integer <= {maxval}")
        if choices is not None and value not in choices:
            self.fail(key, value, "one of " + ", ".join(map(str, choices)))
        return value

    def getfloats(self, key, n, default=None, *, above=None, minval=None, maxval=None):
        value = self.get(key, MISSING if default is None else default)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value] * n
        if not isinstance(value, list) or len(value) != n:
            self.fail(key, value, f"a list of {n} numbers (one per joint) or one number")
        return tuple(self._check_float(key, v, above, minval, maxval) for v in value)

    def check_unknown(self):
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            raise PrinterFileError(
                f"{self.path}: [{self.name}] unknown key {unknown[0]!r}: expected one of "
                + ", ".join(sorted(self.used))
            )


class _Missing:
    def __repr__(self):
        return "<missing>"


MISSING = _Missing()
