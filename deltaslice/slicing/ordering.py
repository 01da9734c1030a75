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

from dataclasses import dataclass

import numpy as np
import shapely

from ..toolpath import Role


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
            if np.ndim(v) == 0:
                return v
            return v[::-1] if reverse else np.roll(v, -start)

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
    alive = np.ones(len(paths), bool)
    for _ in range(len(paths)):
        idx = np.flatnonzero(alive)
        dh = np.sum((heads[idx] - pos) ** 2, axis=1)
        dt = np.sum((tails[idx] - pos) ** 2, axis=1)
        closed = np.array([paths[i].closed for i in idx])
        dt[closed] = np.inf
        best_h, best_t = int(np.argmin(dh)), int(np.argmin(dt))
        if dt[best_t] < dh[best_h]:
            i = int(idx[best_t])
            pts = paths[i].points[::-1]
            alive[i] = False
            out.append((pts, paths[i].oriented(pts, reverse=True)))
            pos = pts[-1]
            continue
        else:
            i = int(idx[best_h])
            p = paths[i]
            if p.closed:
                j = loop_seams[i]
                if j is None:
                    j = seam_index(p.points, "nearest", pos)
                pts = loop_path(p.points, j)
            else:
                pts, j = p.points, 0
        alive[i] = False
        out.append((pts, paths[i].oriented(pts, start=j)))
        pos = pts[-1]
    return out


class MoveWriter:
    """Appends paths and the travels between them to a :class:`ToolpathBuilder`,
    chunk by chunk (one array per path)."""

    def __init__(self, builder, settings, tool, filament_area: float):
        self.b = builder
        self.s = settings
        self.tool = tool
        self.area = filament_area
        self.retracted = False
        self.z = 0.0
        self.first_layer = True
        self.extruded = False  # no retract before anything was extruded
        self.inside = None  # prepared shapely region a travel may cross without retracting

    def _stays_inside(self, a: np.ndarray, b: np.ndarray) -> bool:
        if self.inside is None:
            return False
        return bool(self.inside.contains(shapely.LineString([a[:2], b[:2]])))

    def new_layer(self, z: float, first: bool) -> None:
        self.b.new_layer(z)
        self.z = z
        self.first_layer = first

    def travel(self, xy: np.ndarray) -> None:
        b, s, t = self.b, self.s, self.tool
        target = np.array([xy[0], xy[1], self.z])
        dist = float(np.linalg.norm(target - b.pos))
        if dist < 1e-9:
            return
        long = dist > t.retract_min_travel and not self._stays_inside(b.pos, target)
        if long and t.retract_length > 0 and not self.retracted and self.extruded:
            b.add(b.pos, t.retract_speed, -t.retract_length, 0.0, Role.RETRACT)
            self.retracted = True
        lift = t.z_hop if long else 0.0
        if lift > 0:
            up = b.pos.copy()
            up[2] = max(up[2], self.z) + lift
            b.add(up, s.travel_speed, 0.0, 0.0, Role.TRAVEL)
            b.add([target[0], target[1], up[2]], s.travel_speed, 0.0, 0.0, Role.TRAVEL)
        b.add(target, s.travel_speed, 0.0, 0.0, Role.TRAVEL)

    def extrude(self, pts: np.ndarray, role, width, height: float, feed, flow=None) -> None:
        """Extrude along ``pts`` (k, 2); role, width (mm) and feed (mm/s) scalar or (k-1,);
        ``flow``: filament mm per mm of path, overriding the width's flow."""
        from .extrusion import filament_per_mm

        if len(pts) < 2:
            return
        self.travel(pts[0])
        b = self.b
        if self.retracted:
            b.add(b.pos, self.tool.retract_speed, self.tool.retract_length, 0.0, Role.RETRACT)
            self.retracted = False
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        keep = seg > 1e-6
        if not keep.any():
            return
        xyz = np.column_stack([pts[1:][keep], np.full(int(keep.sum()), self.z)])
        n = len(seg)
        per_seg = lambda v: np.broadcast_to(np.asarray(v, float), (n,))[keep]  # noqa: E731
        if flow is not None:
            fpm = per_seg(flow)
        else:
            fpm = filament_per_mm(per_seg(width), height, self.area, self.s.extrusion_multiplier)
        e = seg[keep] * fpm
        b.add(xyz, per_seg(feed), e, 1.0, per_seg(role).astype(np.uint8))
        self.extruded = True
