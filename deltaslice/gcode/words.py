"""Words of a G-code line: the lexer (a letter and its number per word), parameter checks, and
the names shared by the writer and the reader (role comments, the start tag)."""

from __future__ import annotations

import math
import re

from ..errors import GcodeError
from ..toolpath import Role

# Role <-> comment names (PrusaSlicer/Slic3r first, then Cura).
_ROLE_NAMES = {
    Role.EXTERNAL_PERIMETER: "External perimeter",
    Role.PERIMETER: "Perimeter",
    Role.INFILL: "Internal infill",
    Role.SOLID_INFILL: "Solid infill",
    Role.TOP_SOLID_INFILL: "Top solid infill",
    Role.SKIRT: "Skirt/Brim",
    Role.LASER: "Laser",
    Role.LASER_DYNAMIC: "Laser dynamic",
    Role.OTHER: "Custom",
    Role.OVERHANG_PERIMETER: "Overhang perimeter",
    Role.BRIDGE_INFILL: "Bridge infill",
    Role.GAP_FILL: "Gap fill",
    Role.SUPPORT: "Support material",
    Role.SUPPORT_INTERFACE: "Support material interface",
}
_TYPE_TO_ROLE = {name.upper(): role for role, name in _ROLE_NAMES.items()}
_TYPE_TO_ROLE.update(
    {
        "IRONING": Role.TOP_SOLID_INFILL,
        "SKIRT": Role.SKIRT,
        "BRIM": Role.SKIRT,
        # Cura
        "WALL-OUTER": Role.EXTERNAL_PERIMETER,
        "WALL-INNER": Role.PERIMETER,
        "FILL": Role.INFILL,
        "SKIN": Role.SOLID_INFILL,
        "TOP-SURFACE": Role.TOP_SOLID_INFILL,
        "PRIME-TOWER": Role.OTHER,
        "SUPPORT": Role.SUPPORT,
        "SUPPORT-INTERFACE": Role.SUPPORT_INTERFACE,
    }
)

_START_TAG = ";DELTASLICE_START:"

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?"
# A word: a letter and its number; a bare number (Slic3r's no-extrusion E); anything else is an error.
# Only a lower-case ``e`` right after digits is an exponent (``Y1e-05``): an upper-case E is the extruder word.
_TOKEN = re.compile(rf"([A-Za-z])[ \t]*({_NUM})?|({_NUM})|(\S)")
_COMMAND = re.compile(r"([GgMmTt])[ \t]*0*(\d+(?:\.\d+)?)")
_LINE_NUMBER = re.compile(r"^[Nn]\d+\s*")
_SETTING = re.compile(r"^;\s*([A-Za-z_][\w]*)\s*=\s*(.*?)\s*$")


def _words(s: str, where: str, line: str) -> list[tuple[str, str | None]]:
    """(LETTER, number text or None) per word; a bare number is ("", text)."""
    out = []
    for m in _TOKEN.finditer(s):
        letter, num, bare, bad = m.groups()
        if bad is not None:
            raise GcodeError(f"{where}: malformed line {line!r}: unexpected {bad!r} (expected words like G1 X10.5)")
        if bare is not None and m.start() > 0 and not s[m.start() - 1].isspace():
            # "X1.2.3": a number glued to the previous word is a malformed number, not a bare E
            prev = f"{out[-1][0]}{out[-1][1] or ''}" if out else ""
            raise GcodeError(f"{where}: {prev[:1]}{(prev[1:] + bare)!r} is not a number in {line!r}")
        out.append((letter.upper(), num) if letter is not None else ("", bare))
    return out


def _number(letter: str, text: str | None, where: str) -> float:
    shown = letter or "a bare number"
    if text is None:
        raise GcodeError(f"{where}: {shown} has no value")
    try:
        v = float(text)
    except ValueError:
        raise GcodeError(f"{where}: {letter}{text!r} is not a number") from None
    if not math.isfinite(v):
        raise GcodeError(f"{where}: {letter}{text} is not finite")
    return v


def _params(words, where: str, allowed: str | None) -> dict[str, float]:
    """Parameter words as LETTER -> value (a bare number is "E", flagged as "bare")."""
    out: dict[str, float] = {}
    for letter, num in words:
        key = letter or "E"
        if allowed is not None and letter and letter not in allowed:
            raise GcodeError(f"{where}: unexpected word {letter}{num or ''} (expected {', '.join(allowed)})")
        if key in out:
            raise GcodeError(f"{where}: {key} given twice")
        out[key] = _number(letter, num, where)
        if not letter:
            out["bare"] = 1.0
    return out
