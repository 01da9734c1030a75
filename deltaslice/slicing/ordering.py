"""Ordering and travels: nearest-neighbour order of paths, and the moves between them.

A *path* is a polyline to extrude with one role and width. Islands are visited
nearest first; inside an island, perimeters (innermost first, the external loop
last) then infill chains, each chain entered from whichever end is nearer.
Travels longer than ``retract_min_travel`` retract, lift by ``z_hop``, move,
lower and unretract, unless they stay inside the current island's infill
region (they cross no perimeter, so nothing oozes on the surface); shorter
ones just move.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from ..tolerances import SAME_LENGTH
from ..toolpath import Role
from .extrusion import feed_table, filament_per_mm


@dataclass
class Path:
    """A polyline to extrude. ``role`` and ``width`` are scalars or per segment
    ((k-1,) open, (k,) closed: segment i runs from vertex i to i+1 mod k);
    ``flow`` overrides the filament per mm (bridges: a round bead)."""

    points: np.ndarray  # (k, 2) polyline, mm
    role: int | np.ndarray
    width: float | np.ndarray
    closed: bool = False  # a loop: may start at any vertex (seam chosen when emitted)
    flow: float | np.ndarray | None = None

    def oriented(self, pts: np.ndarray, reverse: bool = False, start: int = 0) -> "Path":
        """This path's attributes lined up with ``pts`` (reversed, or a loop rolled to ``start``)."""

        def fix(v):
            if getattr(v, "ndim", 0) == 0:  # np.ndim makes an array of a Python number to ask
                return v
            return v[::-1] if reverse else np.concatenate([v[start:], v[:start]])  # np.roll(v, -start), cheaper

        return Path(pts, fix(self.role), fix(self.width), False, None if self.flow is None else fix(self.flow))


def nearest_order(paths: list[Path], position: np.ndarray, seam: str = "aligned") -> list[np.ndarray]:
    """Order ``paths`` greedily from ``position``; returns their polylines oriented to be printed.

    Open paths may be reversed; closed loops start at their seam (``aligned``: a
    fixed rear vertex; ``nearest``: the vertex nearest the current position).
    A loop per path (each step is one vectorised distance computation).
    """
    from .perimeters import loop_path, seam_index

    if not paths:
        return []
    pos = np.asarray(position[:2], float)
    heads = np.array([p.points[0] for p in paths])
    tails = np.array([p.points[-1] for p in paths])
    loop_seams = {}
    for i, p in enumerate(paths):
        if p.closed:
            j = seam_index(p.points, "aligned", pos) if seam == "aligned" else None
            loop_seams[i] = j
            if j is not None:
                heads[i] = tails[i] = p.points[j]
            else:
                c = p.points.mean(axis=0)
                heads[i] = tails[i] = c
    out = []
    # heads, then tails, in one array: argmin's first minimum takes a head before any tail as
    # close, as the comparison of the two minima did; the dead (and a loop's tail) at infinity
    n = len(paths)
    ends = np.concatenate([heads, tails])
    dead = np.zeros(2 * n, bool)
    dead[n:] = [p.closed for p in paths]
    for _ in range(n):
        d = np.sum((ends - pos) ** 2, axis=1)
        d[dead] = np.inf
        k = int(np.argmin(d))
        i = k % n
        dead[i] = dead[i + n] = True
        p = paths[i]
        if k >= n:
            pts = p.points[::-1]
            out.append((pts, p.oriented(pts, reverse=True)))
        else:
            if p.closed:
                j = loop_seams[i]
                if j is None:
                    j = seam_index(p.points, "nearest", pos)
                pts = loop_path(p.points, j)
            else:
                pts, j = p.points, 0
            out.append((pts, p.oriented(pts, start=j)))
        pos = pts[-1]
    return out


class MoveWriter:
    """Appends paths and the travels between them to a :class:`ToolpathBuilder`, a layer at a
    time: a layer's moves are gathered chunk by chunk (one per path or travel) and handed over
    in one call when the layer ends (the builder checks every call's columns, and a layer has
    hundreds of chunks). Call :meth:`finish` after the last layer."""

    def __init__(self, builder, settings, tool, filament_area: float):
        self.b = builder
        self.s = settings
        self.tool = tool
        self.area = filament_area
        self.retracted = False
        self.z = 0.0
        self.feeds = feed_table(settings, True)  # speed by role on this layer, mm/s
        self.extruded = False  # no retract before anything was extruded
        self.inside = None  # prepared shapely region a travel may cross without retracting
        self.pos = np.array(builder.pos, float)  # (3,) mm: where the last move gathered ends
        self._chunks = []  # (xyz (k, 3) mm, feed, e, tool, role): each a scalar or (k,)

    def _add(self, xyz: np.ndarray, feed, e, tool, role) -> None:
        self._chunks.append((xyz, feed, e, tool, role))
        self.pos = xyz[-1]

    def _flush(self) -> None:
        """The gathered moves to the builder, in one call."""
        if not self._chunks:
            return
        chunks, self._chunks = self._chunks, []
        lengths = np.array([len(c[0]) for c in chunks])
        ends = np.cumsum(lengths)
        xyz = np.concatenate([c[0] for c in chunks])

        def column(k, dtype):
            # the chunks' scalars repeated over their moves, then their arrays put in place
            values = [c[k] for c in chunks]
            arrays = [i for i, v in enumerate(values) if getattr(v, "ndim", 0)]  # numpy's ndim() costs ~2 us a call
            for i in arrays:
                values[i] = 0
            out = np.repeat(np.asarray(values, dtype), lengths)
            for i in arrays:
                out[ends[i] - lengths[i] : ends[i]] = chunks[i][k]
            return out

        self.b.add(xyz, column(1, float), column(2, float), column(3, float), column(4, np.uint8))

    def _stays_inside(self, a: np.ndarray, b: np.ndarray) -> bool:
        if self.inside is None:
            return False
        return bool(shapely.contains(self.inside, shapely.linestrings([a[:2], b[:2]])))

    def new_layer(self, z: float, first: bool) -> None:
        self._flush()
        self.b.new_layer(z)
        self.z = z
        self.feeds = feed_table(self.s, first)

    def finish(self) -> None:
        """After the last layer: the moves gathered to the builder, and the filament pulled
        back if it is not."""
        if self.retracted:
            self._add(self.pos[None], self.tool.retract_speed, self.tool.retract_length, 0.0, Role.RETRACT)
            self.retracted = False
        self._flush()

    def travel(self, xy: np.ndarray) -> None:
        s, t = self.s, self.tool
        target = np.array([xy[0], xy[1], self.z])
        dist = math.dist(target, self.pos)
        if dist < SAME_LENGTH:
            return
        long = dist > t.retract_min_travel and not self._stays_inside(self.pos, target)
        if long and t.retract_length > 0 and not self.retracted and self.extruded:
            self._add(self.pos[None], t.retract_speed, -t.retract_length, 0.0, Role.RETRACT)
            self.retracted = True
        lift = t.z_hop if long else 0.0
        if lift > 0:
            up = self.pos.copy()
            up[2] = max(up[2], self.z) + lift
            self._add(np.array([up, [target[0], target[1], up[2]]]), s.travel_speed, 0.0, 0.0, Role.TRAVEL)
        self._add(target[None], s.travel_speed, 0.0, 0.0, Role.TRAVEL)

    def extrude(self, pts: np.ndarray, role, width, height: float, flow=None) -> None:
        """Extrude along ``pts`` (k, 2) at the layer's speed for ``role``; role and width (mm)
        scalar or (k-1,); ``flow``: filament mm per mm of path, overriding the width's flow."""
        if len(pts) < 2:
            return
        self.travel(pts[0])
        if self.retracted:
            self._add(self.pos[None], self.tool.retract_speed, self.tool.retract_length, 0.0, Role.RETRACT)
            self.retracted = False
        d = pts[1:] - pts[:-1]
        seg = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])  # np.linalg.norm's sum, without its overhead
        keep = seg > 1e-6
        every = bool(keep.all())
        if not every and not keep.any():
            return

        def per_seg(v):
            # a scalar stays one (repeated when the layer is handed over)
            if getattr(v, "ndim", 0) == 0:  # np.ndim makes an array of a Python number to ask
                return v
            v = np.asarray(v)
            return v if every else v[keep]

        m = len(seg) if every else int(keep.sum())
        xyz = np.empty((m, 3))
        xyz[:, :2] = pts[1:] if every else pts[1:][keep]
        xyz[:, 2] = self.z
        if flow is not None:
            fpm = per_seg(flow)
        else:
            fpm = filament_per_mm(per_seg(width), height, self.area, self.s.extrusion_multiplier)
        role = per_seg(role)
        feed = self.feeds[role.astype(np.intp)] if getattr(role, "ndim", 0) else float(self.feeds[int(role)])
        self._add(xyz, feed, (seg if every else seg[keep]) * fpm, 1.0, role)
        self.extruded = True
