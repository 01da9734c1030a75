"""G2/G3 arcs in the XY plane as chords within :data:`ARC_TOLERANCE`."""

from __future__ import annotations

import math

import numpy as np

from ..errors import GcodeError
from ..tolerances import RELATIVE_ROUNDOFF, SAME_LENGTH

#: Largest distance between an arc and its chords, mm.
ARC_TOLERANCE = 0.01
#: An I/J arc's end may be this far off its circle (mm, plus 0.1 % of the radius): slicers round to 3 decimals.
ARC_END_TOLERANCE = 0.01
#: Most chords one arc may become (a longer arc is refused, not a memory blow-up).
ARC_MAX_CHORDS = 1_000_000
#: Chords all of a file's arcs may become: a base and so many a line read. A 959-byte file of 40 full
#: circles of radius 1e9 mm asked for 28 million points and ran out of memory; a real arc's full
#: circle of 200 mm radius is about 300 chords.
ARC_CHORDS_BASE = 1_000_000
ARC_CHORDS_PER_LINE = 3_000


class _ArcBudget(Exception):
    """An arc needing more chords than the file's arcs have left (the reader says which line)."""

    def __init__(self, chords: int, radius: float):
        super().__init__(chords, radius)
        self.chords, self.radius = chords, radius


def _arc_points(p0, p1, ij, r_word, clockwise: bool, where: str, budget: int | None = None):
    """Points along a G2/G3 arc in the XY plane after p0, ending at p1 ((k, 3) mm).

    I/J arcs whose end is off the circle by more than :data:`ARC_END_TOLERANCE` are refused;
    an I/J arc whose end is its start is a full circle; an arc whose sagitta is within
    :data:`ARC_TOLERANCE` (a huge radius) is its chord."""
    x0, y0 = p0[0], p0[1]
    x1, y1 = p1[0], p1[1]
    dx, dy = x1 - x0, y1 - y0
    d = math.hypot(dx, dy)
    full = False
    if ij is not None:
        cx, cy = x0 + ij[0], y0 + ij[1]
        r0 = math.hypot(x0 - cx, y0 - cy)
        r1 = math.hypot(x1 - cx, y1 - cy)
        if not r0 > SAME_LENGTH:
            raise GcodeError(f"{where}: arc with zero radius (I and J are 0)")
        if abs(r1 - r0) > ARC_END_TOLERANCE + 1e-3 * r0:
            raise GcodeError(
                f"{where}: arc end ({x1:g}, {y1:g}) is {abs(r1 - r0):.4f} mm off the circle of radius {r0:.4f} "
                f"about ({cx:g}, {cy:g}) (tolerance {ARC_END_TOLERANCE + 1e-3 * r0:.4f} mm)"
            )
        full = d <= SAME_LENGTH
    elif r_word is not None:
        r = abs(r_word)
        if d <= SAME_LENGTH:
            raise GcodeError(f"{where}: an R arc cannot end where it starts (use I/J for a full circle)")
        if d > 2 * r * (1 + RELATIVE_ROUNDOFF) + 1e-6:
            raise GcodeError(f"{where}: arc radius R{r_word:g} cannot join its end points {d:.4f} mm apart")
        half = d / (2 * r)
        # the short arc (R > 0) bulges by the sagitta; a nearly straight one is its chord
        if r_word > 0 and r * (1 - math.sqrt(max(1 - half * half, 0.0))) <= ARC_TOLERANCE:
            return np.asarray([p1], float)
        h = r * math.sqrt(max(1 - half * half, 0.0))
        # centre to the left of the chord for CCW with R > 0
        sgn = (1 if not clockwise else -1) * (1 if r_word > 0 else -1)
        cx = (x0 + x1) / 2 - sgn * h * dy / d
        cy = (y0 + y1) / 2 + sgn * h * dx / d
        r0 = r1 = math.hypot(x0 - cx, y0 - cy)
    else:
        raise GcodeError(f"{where}: arc without I/J or R")
    a0 = math.atan2(y0 - cy, x0 - cx)
    if full:
        sweep = -2 * math.pi if clockwise else 2 * math.pi
    else:
        sweep = math.atan2(y1 - cy, x1 - cx) - a0
        if clockwise:
            if sweep >= -1e-12:
                sweep -= 2 * math.pi
        else:
            if sweep <= 1e-12:
                sweep += 2 * math.pi
        if abs(sweep) < math.pi and r0 * (1 - math.cos(sweep / 2)) <= ARC_TOLERANCE:
            return np.asarray([p1], float)
    # chord angle whose sagitta is ARC_TOLERANCE, in a form that does not round to 0 for a huge radius
    step = 4 * math.asin(math.sqrt(min(ARC_TOLERANCE / (2 * r0), 0.5)))
    k = math.ceil(abs(sweep) / step) if step > 0 else ARC_MAX_CHORDS + 1
    if k > ARC_MAX_CHORDS:
        raise GcodeError(f"{where}: arc of radius {r0:.6g} mm would need {k} chords (at most {ARC_MAX_CHORDS})")
    if budget is not None and k > budget:
        raise _ArcBudget(k, r0)
    k = max(1, k)
    t = np.arange(1, k + 1) / k
    ang = a0 + sweep * t
    rad = r0 + (r1 - r0) * t  # ends exactly at p1 when the end is slightly off the circle
    pts = np.column_stack([cx + rad * np.cos(ang), cy + rad * np.sin(ang), p0[2] + (p1[2] - p0[2]) * t])
    pts[-1] = p1
    if not np.all(np.isfinite(pts)):
        raise GcodeError(f"{where}: arc has no finite points (radius {r0:.6g} mm)")
    return pts
