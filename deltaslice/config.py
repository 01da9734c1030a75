"""Typed access to one TOML table of a printer file, in the manner of Klipper's config getters.

Every failure names the file, the ``[section] key``, the value and the bound it broke. The
machine reader (:mod:`deltaslice.machine.reader`) and every kinematics family's
``read_geometry`` use these getters, so a family file reads its own ``[kinematics]`` keys.

Given a :class:`Problems` collector, a section records each problem and goes on (a getter
returns a stand-in value), so one :class:`~deltaslice.errors.PrinterFileError` lists every
problem of a file at once; an unknown key is named with the nearest valid key. Each getter
call can be recorded (:func:`recording`): ``docs/gen_printer_file.py`` builds the printer-file
reference from those records, so the reference is the reader's own calls.
"""

from __future__ import annotations

import contextlib
import difflib
import math
from dataclasses import dataclass
from typing import Any

from .errors import PrinterFileError

MAGNITUDE = 1e12  # no length, rate or count of a printer is this large; 1e160 would overflow the geometry


@dataclass(frozen=True)
class KeySpec:
    """One getter call: what the reader asked of a key (for the generated reference)."""

    section: str
    key: str
    kind: str  # float, floats, int, str, list
    required: bool
    default: Any
    above: float | None = None
    minval: float | None = None
    maxval: float | None = None
    choices: tuple | None = None


_recorders: list[list] = []


@contextlib.contextmanager
def recording():
    """Collect a :class:`KeySpec` for every getter call made inside the block."""
    calls: list[KeySpec] = []
    _recorders.append(calls)
    try:
        yield calls
    finally:
        _recorders.remove(calls)


class _Stop(PrinterFileError):
    """A recorded problem that stops the current section (the file's error is raised later)."""


class Problems:
    """The problems of one printer file, collected across its sections."""

    def __init__(self, path: str, overridden=()):
        self.path = path
        self.items: list[tuple[str, str | None, str, bool]] = []  # (section, key, message, is_missing)
        self.suggested: set[tuple[str, str]] = set()
        # (section, key) set on the command line (--set section.key=value): their problems are
        # reported as the --set's, not as the file's
        self.overridden: set[tuple[str, str]] = {tuple(k) for k in overridden}

    def is_overridden(self, section, key) -> bool:
        return key is not None and (section, key) in self.overridden

    def add(self, section, key, message, missing=False):
        if key is not None and any(s == section and k == key for s, k, _m, _x in self.items):
            return  # a check derived from a value already reported (its stand-in) says nothing new
        self.items.append((section, key, message, missing))

    def messages(self) -> list[str]:
        return [m for s, k, m, missing in self.items if not (missing and (s, k) in self.suggested)]

    def raise_if_any(self) -> None:
        msgs = self.messages()
        if msgs and all(self.is_overridden(s, k) for s, k, _m, _x in self.items):  # the command line's, not the file's
            if len(msgs) == 1:
                raise PrinterFileError(f"{msgs[0]} (printer file {self.path})")
            raise PrinterFileError(f"{len(msgs)} problems with --set (printer file {self.path}):\n"
                                   + "\n".join(f"  {m}" for m in msgs))
        if len(msgs) == 1:
            raise PrinterFileError(f"{self.path}: {msgs[0]}")
        if msgs:
            raise PrinterFileError(f"{self.path}: {len(msgs)} problems:\n" + "\n".join(f"  {m}" for m in msgs))


class Section:
    """Typed access to one TOML table, in the manner of Klipper's config getters:
    every failure names the file, the key, the value and the bound."""

    def __init__(self, path: str, name: str, data: Any, problems: Problems | None = None):
        self.path = path
        self.name = name
        self.problems = problems
        self.used: set[str] = set()
        self.data = data if isinstance(data, dict) else {}
        if not isinstance(data, dict):
            self.fail(None, data, "a table")

    def _where(self, key: str | None) -> str:
        if self.problems is not None and self.problems.is_overridden(self.name, key):
            return f"--set {self.name}.{key}"
        return f"[{self.name}]" if key is None else f"[{self.name}] {key}"

    def fail(self, key, value, expected):
        """Report a problem with ``key``: raise at once, or record it and stop the section."""
        shown = "missing" if value is MISSING else f"= {_shown(value)}"
        message = f"{self._where(key)} {shown}: expected {expected}"
        if self.problems is None:
            raise PrinterFileError(f"{self.path}: {message}")
        self.problems.add(self.name, key, message, missing=value is MISSING)
        raise _Stop(message)

    def _record(self, key, kind, required, default, **bounds):
        if _recorders:
            spec = KeySpec(self.name, key, kind, required, None if default is MISSING else default, **bounds)
            for calls in _recorders:
                calls.append(spec)

    def _soft(self, fn, fallback):
        """Run a getter; with a collector, a problem is recorded and ``fallback`` returned."""
        if self.problems is None:
            return fn()
        try:
            return fn()
        except _Stop:
            return fallback

    def get(self, key, default):
        self.used.add(key)
        if key in self.data:
            return self.data[key]
        if default is MISSING:
            self.fail(key, MISSING, "a value (required key)")
        return default

    def getstr(self, key, default=None, choices=None, required=True):
        self._record(key, "str", required, default, choices=tuple(choices) if choices else None)

        def read():
            value = self.get(key, MISSING if required else default)
            if value is None and not required and key not in self.data:
                return None
            if not isinstance(value, str):
                self.fail(key, value, "a string")
            if choices is not None and value not in choices:
                close = difflib.get_close_matches(value, list(choices), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                self.fail(key, value, "one of " + ", ".join(choices) + hint)
            return value

        return self._soft(read, (list(choices)[0] if choices else default or ""))

    def getfloat(self, key, default=None, *, required=None, above=None, minval=None, maxval=None):
        required = default is None if required is None else required
        self._record(key, "float", required, default, above=above, minval=minval, maxval=maxval)

        def read():
            value = self.get(key, MISSING if required else default)
            if value is None and key not in self.data:
                return None
            return self._check_float(key, value, above, minval, maxval)

        return self._soft(read, _fallback(default, above, minval, maxval))

    def _check_float(self, key, value, above, minval, maxval):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, value, "a number")
        try:
            value = float(value)
        except OverflowError:  # TOML integers have no bound: one of 310 digits is beyond any float
            self.fail(key, value, f"a number of magnitude <= {MAGNITUDE:g} (mm, s, degrees)")
        if not math.isfinite(value):
            self.fail(key, value, "a finite number")
        if above is not None and not value > above:
            self.fail(key, value, f"a number > {above:g}")
        if minval is not None and value < minval:
            self.fail(key, value, f"a number >= {minval:g}")
        if maxval is not None and value > maxval:
            self.fail(key, value, f"a number <= {maxval:g}")
        if abs(value) > MAGNITUDE:
            self.fail(key, value, f"a number of magnitude <= {MAGNITUDE:g} (mm, s, degrees)")
        return value

    def getint(self, key, default=None, *, minval=None, maxval=None, choices=None):
        self._record(key, "int", default is None, default, minval=minval, maxval=maxval,
                     choices=tuple(choices) if choices else None)

        def read():
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

        fallback = default if default is not None else (choices[0] if choices else (minval if minval is not None else 1))
        return self._soft(read, fallback)

    def getfloats(self, key, n, default=None, *, above=None, minval=None, maxval=None):
        self._record(key, "floats", default is None, default, above=above, minval=minval, maxval=maxval)

        def read():
            value = self.get(key, MISSING if default is None else default)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                value = [value] * n
            if not isinstance(value, list) or len(value) != n:
                self.fail(key, value, f"a list of {n} numbers (one per joint) or one number")
            return tuple(self._check_float(key, v, above, minval, maxval) for v in value)

        fb = default if isinstance(default, (list, tuple)) and len(default) == n else [_fallback(default, above, minval, maxval)] * n
        return self._soft(read, tuple(float(v) for v in fb))

    def check_unknown(self):
        """Refuse keys no getter asked for, each named with the nearest valid key."""
        unknown = sorted(set(self.data) - self.used)
        valid = sorted(self.used)
        for key in unknown:
            close = difflib.get_close_matches(key, valid, n=1, cutoff=0.6)
            hint = f": did you mean {close[0]!r}?" if close else ""
            message = f"[{self.name}] unknown key {key!r}{hint} (expected one of {', '.join(valid)})"
            if self.problems is not None and self.problems.is_overridden(self.name, key):
                message = f"--set {self.name}.{key}: no key {key!r} in [{self.name}]{hint} (expected one of {', '.join(valid)})"
            if self.problems is None:
                raise PrinterFileError(f"{self.path}: {message}")
            self.problems.add(self.name, key, message)
            if close:
                self.problems.suggested.add((self.name, close[0]))


SHOWN_CHARS = 80  # a value quoted in a message longer than this is cut: the message stays one readable line


def _shown(value) -> str:
    """A value as a message quotes it: repr, an integer of many digits by its length, a long repr cut."""
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) >= 10**20:
        return f"{'-' if value < 0 else ''}{str(abs(value))[:3]}... (an integer of {len(str(abs(value)))} digits)"
    text = repr(value)
    return text if len(text) <= SHOWN_CHARS else f"{text[:SHOWN_CHARS - 3]}..."


def _fallback(default, above, minval, maxval) -> float:
    """A stand-in value within the bounds, so reading goes on after a recorded problem."""
    if isinstance(default, (int, float)) and not isinstance(default, bool) and abs(default) <= MAGNITUDE:
        return float(default)  # a default derived from another key's value of 310 digits is not a float
    if minval is not None:
        return float(minval)
    if above is not None:
        return float(above) + 1.0 if maxval is None or above + 1.0 <= maxval else (above + maxval) / 2
    return 1.0 if maxval is None or maxval >= 1.0 else float(maxval)


class _Missing:
    def __repr__(self):
        return "<missing>"


MISSING = _Missing()
