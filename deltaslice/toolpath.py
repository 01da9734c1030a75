"""The Toolpath: the one data model between front ends (slicer, G-code reader,
image tracer) and the planner.

A toolpath is a flat, ordered list of straight moves, like G-code after parsing,
held as numpy arrays. Move ``i`` goes from ``xyz[i-1]`` (or ``start`` for ``i = 0``)
to ``xyz[i]``:

=========  ===========  =====  ===================================================
array      shape        dtype  meaning
=========  ===========  =====  ===================================================
xyz        (n, 3)       f8     end point of the move, bed frame, mm
feed       (n,)         f8     requested tool speed, mm/s (> 0)
e          (n,)         f8     filament pushed during the move, mm (negative: retract)
tool       (n,)         f8     0 off; 1 extruding; laser power as a fraction 0..1
role       (n,)         u1     :class:`Role` of the move
layer      (n,)         i4     layer index (0 = first layer), non-decreasing
=========  ===========  =====  ===================================================

plus ``start`` (3,) f8, mm, and ``layer_z`` (L,) f8, mm: the top of each layer.
A move with ``tool > 0`` is a working move; consecutive working moves form a
*run*, and everything between runs (travels, retracts, lifts) is a *travel*.
A zero-length move with ``e != 0`` is a retract or an unretract.

The object is frozen; the arrays are read-only views, so a Toolpath can be
shared between stages and processes without copies.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from .errors import DeltasliceError


class Role(enum.IntEnum):
    TRAVEL = 0
    EXTERNAL_PERIMETER = 1
    PERIMETER = 2
    INFILL = 3
    SOLID_INFILL = 4
    TOP_SOLID_INFILL = 5
    SKIRT = 6
    RETRACT = 7
    LASER = 8
    OTHER = 9
    OVERHANG_PERIMETER = 10  # a perimeter over air (slower)
    BRIDGE_INFILL = 11  # solid lines across air or over sparse infill, round bead of nozzle diameter
    GAP_FILL = 12  # variable-width lines along the medial axis of regions too narrow for a loop


@dataclass(frozen=True)
class Toolpath:
    start: np.ndarray
    xyz: np.ndarray
    feed: np.ndarray
    e: np.ndarray
    tool: np.ndarray
    role: np.ndarray
    layer: np.ndarray
    layer_z: np.ndarray

    def __post_init__(self):
        n = len(self.xyz)
        casts = {
            "start": (np.float64, (3,)),
            "xyz": (np.float64, (n, 3)),
            "feed": (np.float64, (n,)),
            "e": (np.float64, (n,)),
            "tool": (np.float64, (n,)),
            "role": (np.uint8, (n,)),
            "layer": (np.int32, (n,)),
        }
        for name, (dtype, shape) in casts.items():
            arr = np.array(getattr(self, name), dtype=dtype)
            if arr.shape != shape:
                raise DeltasliceError(f"Toolpath.{name}: expected shape {shape}, got {arr.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        lz = np.array(self.layer_z, dtype=np.float64).reshape(-1)
        lz.setflags(write=False)
        object.__setattr__(self, "layer_z", lz)
        if n:
            if not np.all(np.isfinite(self.xyz)) or not np.all(np.isfinite(self.e)):
                raise DeltasliceError("Toolpath: non-finite coordinate or extrusion")
            if not np.all(self.feed > 0):
                raise DeltasliceError("Toolpath: every move needs a feed rate > 0")
            if np.any(np.diff(self.layer) < 0):
                raise DeltasliceError("Toolpath: layer indices must not decrease")

    # -- construction ------------------------------------------------------------
    @classmethod
    def empty(cls, start=(0.0, 0.0, 0.0)) -> "Toolpath":
        z = np.zeros(0)
        return cls(np.asarray(start, float), np.zeros((0, 3)), z, z, z, z.astype(np.uint8), z.astype(np.int32), z)

    @classmethod
    def concatenate(cls, parts: list["Toolpath"]) -> "Toolpath":
        """Join toolpaths end to end (layers renumbered after each other)."""
        parts = [p for p in parts]
        if not parts:
            return cls.empty()
        offset, layers = 0, []
        for p in parts:
            layers.append(p.layer + offset)
            offset += len(p.layer_z)
        cat = np.concatenate
        return cls(
            parts[0].start,
            cat([p.xyz for p in parts]),
            cat([p.feed for p in parts]),
            cat([p.e for p in parts]),
            cat([p.tool for p in parts]),
            cat([p.role for p in parts]),
            cat(layers),
            cat([p.layer_z for p in parts]),
        )

    # -- views -------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.xyz)

    @property
    def n_layers(self) -> int:
        return len(self.layer_z)

    @property
    def starts(self) -> np.ndarray:
        """Start point of every move: (n, 3) f8, mm."""
        return np.concatenate([self.start[None], self.xyz[:-1]], axis=0) if len(self) else np.zeros((0, 3))

    @property
    def lengths(self) -> np.ndarray:
        """Length of every move: (n,) f8, mm."""
        return np.linalg.norm(self.xyz - self.starts, axis=1)

    @property
    def working(self) -> np.ndarray:
        """(n,) bool: moves with the tool on."""
        return self.tool > 0

    def runs(self) -> list[tuple[int, int]]:
        """Half-open index ranges ``[i, j)`` of maximal consecutive working moves."""
        w = np.concatenate([[False], self.working, [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(w))
        return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))

    def layer_slices(self) -> list[slice]:
        """One slice of moves per layer index 0..L-1 (empty slices for empty layers)."""
        bounds = np.searchsorted(self.layer, np.arange(self.n_layers + 1), side="left")
        return [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]

    def subset(self, sl: slice) -> "Toolpath":
        """Moves ``sl`` as a toolpath of their own (start = the point before them)."""
        i0 = sl.start or 0
        start = self.start if i0 == 0 else self.xyz[i0 - 1]
        return Toolpath(
            start, self.xyz[sl], self.feed[sl], self.e[sl], self.tool[sl], self.role[sl], self.layer[sl], self.layer_z
        )

    # -- totals ------------------------------------------------------------------
    def extruded_length(self) -> float:
        """Net filament pushed, mm (retracts and unretracts cancel)."""
        return float(self.e.sum())

    def extruded_volume(self, filament_diameter: float) -> float:
        """Volume of plastic deposited by working moves, mm^3."""
        return float(self.e[self.working].sum() * np.pi * filament_diameter**2 / 4)

    def summary(self) -> dict:
        work = self.working
        lengths = self.lengths
        return {
            "moves": len(self),
            "layers": self.n_layers,
            "working_length_mm": float(lengths[work].sum()),
            "travel_length_mm": float(lengths[~work].sum()),
            "filament_mm": float(self.e[work].sum()),
        }

    def equals(self, other: "Toolpath", atol: float = 1e-6) -> bool:
        """Same moves within ``atol`` (used by round-trip tests)."""
        if len(self) != len(other) or self.n_layers != other.n_layers:
            return False
        close = lambda a, b: np.allclose(a, b, atol=atol, rtol=0)  # noqa: E731
        return (
            close(self.xyz, other.xyz)
            and close(self.feed, other.feed)
            and close(self.e, other.e)
            and close(self.tool, other.tool)
            and np.array_equal(self.layer, other.layer)
            and close(self.layer_z, other.layer_z)
        )


class ToolpathBuilder:
    """Accumulates moves in Python lists of arrays and freezes them once.

    Front ends append whole polylines at a time (vectorised), never point by point.
    """

    def __init__(self, start=(0.0, 0.0, 0.0)):
        self.start = np.asarray(start, dtype=float)
        self.pos = self.start.copy()
        self._chunks: list[tuple] = []
        self.layer_z: list[float] = []

    @property
    def layer(self) -> int:
        return len(self.layer_z) - 1

    def new_layer(self, z: float) -> None:
        self.layer_z.append(float(z))

    def add(self, xyz, feed, e, tool, role) -> None:
        """Append moves to ``xyz`` ((k,3) mm) with per-move or scalar feed, e, tool, role."""
        xyz = np.atleast_2d(np.asarray(xyz, dtype=float))
        k = len(xyz)
        if k == 0:
            return
        b = lambda v, dt: np.broadcast_to(np.asarray(v, dtype=dt), (k,))  # noqa: E731
        self._chunks.append(
            (xyz, b(feed, float), b(e, float), b(tool, float), b(role, np.uint8), np.full(k, max(self.layer, 0), np.int32))
        )
        self.pos = xyz[-1].copy()

    def build(self) -> Toolpath:
        if not self._chunks:
            t = Toolpath.empty(self.start)
            return Toolpath(t.start, t.xyz, t.feed, t.e, t.tool, t.role, t.layer, np.asarray(self.layer_z, float))
        cols = list(zip(*self._chunks))
        return Toolpath(self.start, *(np.concatenate(c) for c in cols), np.asarray(self.layer_z, float))
