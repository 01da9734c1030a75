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

plus ``start`` (3,) f8, mm, ``layer_z`` (L,) f8, mm: the top of each layer, and
``events``: a structured array (m,) of :data:`EVENT_DTYPE` (``index`` i8: the move
before which the event applies, ``len(xyz)`` for the end; ``kind`` u1: an
:class:`EventKind`; ``value`` f8: degrees C, fan 0..255 or laser mode 0/3/4), sorted
by index, several at one index in their order: heaters, fans and laser mode changes.
A move with ``tool > 0`` is a working move; consecutive working moves form a
*run*, and everything between runs (travels, retracts, lifts) is a *travel*.
A zero-length move with ``e != 0`` is a retract or an unretract.
Laser moves (roles ``LASER`` and ``LASER_DYNAMIC``) with ``tool = 0`` belong to the
run around them (raster overscan, short white gaps): the planner does not stop there.

The object is frozen; the arrays are read-only views, so a Toolpath can be
shared between stages and processes without copies.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from .errors import DeltasliceError
from .tolerances import SAME_LENGTH


class EventKind(enum.IntEnum):
    """Timed machine events (codes as in the stream's event record, docs/stream-format.md)."""

    HOTEND_SET = 1  # M104, degrees C
    HOTEND_WAIT = 2  # M109, degrees C
    BED_SET = 3  # M140, degrees C
    BED_WAIT = 4  # M190, degrees C
    FAN = 5  # M106/M107, 0..255
    LASER_MODE = 6  # M5 = 0, M3 = 3 (constant power), M4 = 4 (dynamic power)


#: Lower-case names used in text outputs (CSV comments, decode).
EVENT_NAMES = {k: k.name.lower() for k in EventKind}
EVENT_DTYPE = np.dtype([("index", np.int64), ("kind", np.uint8), ("value", np.float64)])
WAIT_KINDS = (EventKind.HOTEND_WAIT, EventKind.BED_WAIT)


def make_events(rows=()) -> np.ndarray:
    """A read-only events array from ``(index, kind, value)`` rows, stably sorted by index."""
    ev = np.array([tuple(r) for r in rows], dtype=EVENT_DTYPE) if len(rows) else np.zeros(0, EVENT_DTYPE)
    ev = ev[np.argsort(ev["index"], kind="stable")]
    ev.setflags(write=False)
    return ev


class Role(enum.IntEnum):
    TRAVEL = 0
    EXTERNAL_PERIMETER = 1
    PERIMETER = 2
    INFILL = 3
    SOLID_INFILL = 4
    TOP_SOLID_INFILL = 5
    SKIRT = 6
    RETRACT = 7
    LASER = 8  # laser at the move's power (GRBL M3)
    OTHER = 9
    LASER_DYNAMIC = 10  # laser power scaled by the tool's actual speed over the move's feed (GRBL M4)
    OVERHANG_PERIMETER = 11  # a perimeter over air (slower)
    BRIDGE_INFILL = 12  # solid lines across air or over sparse infill, round bead of nozzle diameter
    GAP_FILL = 13  # variable-width lines along the medial axis of regions too narrow for a loop
    SUPPORT = 14  # support under overhangs: sparse lines, not part of the part
    SUPPORT_INTERFACE = 15  # the dense top layers of a support, right under the part


MIN_FEED = 1e-3  # mm/s (0.06 mm/min): slower is a units mistake, and a print of years
MAX_FEED = 1e5  # mm/s


def _column(name, value, dtype):
    """``value`` as an array of ``dtype``; DeltasliceError naming ``name`` for anything that is
    not real numbers of that kind (None, strings, complex numbers, out-of-range integers).
    An array of that dtype that owns its data and is read-only is taken as it is (another
    toolpath's column, or a reader's that it gives away): nothing can change it, so no copy."""
    if (isinstance(value, np.ndarray) and value.dtype == dtype and value.base is None and not value.flags.writeable
            and value.flags.c_contiguous):
        return value
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise DeltasliceError(f"{name}: expected numbers: {exc}") from None
    if raw.dtype.kind not in "biuf":
        raise DeltasliceError(f"{name}: expected real numbers, got {raw.dtype} values")
    if np.dtype(dtype).kind in "iu" and raw.size:
        if raw.dtype.kind == "f" and not np.all(np.isfinite(raw) & (raw == np.round(raw))):
            raise DeltasliceError(f"{name}: expected whole numbers")
        info = np.iinfo(dtype)
        if raw.min() < info.min or raw.max() > info.max:
            raise DeltasliceError(f"{name}: values {raw.min()}..{raw.max()} outside {info.min}..{info.max}")
    return np.array(raw, dtype=dtype)


def _check_range(name, x, lo, hi, what):
    bad = ~((x >= lo) & (x <= hi))
    if bad.any():
        i = int(np.argmax(bad))
        raise DeltasliceError(f"Toolpath.{name}: move {i}: {float(x[i]):g} outside {lo:g}..{hi:g} {what}")


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
    events: np.ndarray | None = None

    def __post_init__(self):
        xyz = _column("Toolpath.xyz", self.xyz, np.float64)
        if xyz.ndim != 2:
            raise DeltasliceError(f"Toolpath.xyz: expected shape (n, 3), got {xyz.shape}")
        n = len(xyz)
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
            arr = _column(f"Toolpath.{name}", getattr(self, name), dtype)
            if arr.shape != shape:
                raise DeltasliceError(f"Toolpath.{name}: expected shape {shape}, got {arr.shape}")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        lz = _column("Toolpath.layer_z", self.layer_z, np.float64).reshape(-1)
        if not np.all(np.isfinite(lz)):
            raise DeltasliceError("Toolpath.layer_z: non-finite layer height")
        lz.setflags(write=False)
        object.__setattr__(self, "layer_z", lz)
        ev = make_events() if self.events is None else np.asarray(self.events)
        if ev.dtype != EVENT_DTYPE:
            ev = make_events([tuple(r) for r in ev])
        if len(ev):
            if np.any(ev["index"] < 0) or np.any(ev["index"] > n) or np.any(np.diff(ev["index"]) < 0):
                raise DeltasliceError(f"Toolpath.events: indices must be sorted within 0..{n}")
            if not np.all(np.isin(ev["kind"], [int(k) for k in EventKind])) or not np.all(np.isfinite(ev["value"])):
                raise DeltasliceError("Toolpath.events: unknown kind or non-finite value")
        ev = ev.copy()
        ev.setflags(write=False)
        object.__setattr__(self, "events", ev)
        if not np.all(np.isfinite(self.start)):
            raise DeltasliceError(f"Toolpath.start: {self.start.tolist()}: expected a finite point (x, y, z), mm")
        if n:
            if not np.all(np.isfinite(self.xyz)) or not np.all(np.isfinite(self.e)):
                raise DeltasliceError("Toolpath: non-finite coordinate or extrusion")
            _check_range("feed", self.feed, MIN_FEED, MAX_FEED, "mm/s (a feed this slow or fast is a units mistake)")
            _check_range("tool", self.tool, 0.0, 1.0, "(0 off, 1 full extrusion or laser power)")
            bad_role = ~np.isin(self.role, [int(r) for r in Role])
            if bad_role.any():
                i = int(np.argmax(bad_role))
                raise DeltasliceError(f"Toolpath.role: move {i}: {int(self.role[i])} is not a Role (0..{max(Role)})")
            if np.any(np.diff(self.layer) < 0):
                raise DeltasliceError("Toolpath: layer indices must not decrease")
            if self.layer.min() < 0 or (len(lz) and self.layer.max() >= len(lz)) or (not len(lz) and self.layer.max() > 0):
                raise DeltasliceError(
                    f"Toolpath.layer: indices {int(self.layer.min())}..{int(self.layer.max())} outside the "
                    f"{len(lz)} layer heights in layer_z")

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
        offsets = np.cumsum([0] + [len(p.layer_z) for p in parts[:-1]])
        return cls._joined(parts, np.concatenate([p.layer + int(k) for p, k in zip(parts, offsets)]),
                           np.concatenate([p.layer_z for p in parts]))

    def then(self, other: "Toolpath") -> "Toolpath":
        """This toolpath's moves followed by ``other``'s, which starts where this one ends: one
        stretch of a print handed over in chunks (layers keep their numbers; the layer heights
        are the longer list of the two)."""
        if len(self) and not np.allclose(other.start, self.xyz[-1], rtol=0, atol=SAME_LENGTH):
            raise DeltasliceError(f"Toolpath.then: the next stretch starts at {other.start.tolist()}, "
                                  f"not where this one ends ({self.xyz[-1].tolist()})")
        return Toolpath._joined([self, other], np.concatenate([self.layer, other.layer]),
                                max(self.layer_z, other.layer_z, key=len))

    @classmethod
    def _joined(cls, parts: list["Toolpath"], layer: np.ndarray, layer_z: np.ndarray) -> "Toolpath":
        """The parts' moves end to end from the first one's start, their events re-indexed, with the
        given layer column and heights."""
        events, moves = [], 0
        for p in parts:
            ev = p.events.copy()
            ev["index"] += moves
            events.append(ev)
            moves += len(p)
        cat = np.concatenate
        return cls(parts[0].start, cat([p.xyz for p in parts]), cat([p.feed for p in parts]), cat([p.e for p in parts]),
                   cat([p.tool for p in parts]), cat([p.role for p in parts]), layer, layer_z, cat(events))

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
        i0, i1, _ = sl.indices(len(self))
        start = self.start if i0 == 0 else self.xyz[i0 - 1]
        ev = self.events[(self.events["index"] >= i0) & (self.events["index"] <= i1)].copy()
        ev["index"] -= i0
        return Toolpath(
            start, self.xyz[sl], self.feed[sl], self.e[sl], self.tool[sl], self.role[sl], self.layer[sl], self.layer_z, ev
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
            and np.array_equal(self.events["index"], other.events["index"])
            and np.array_equal(self.events["kind"], other.events["kind"])
            and close(self.events["value"], other.events["value"])
        )

    def with_events(self, events) -> "Toolpath":
        """The same moves with ``events`` (rows or an :data:`EVENT_DTYPE` array)."""
        ev = events if isinstance(events, np.ndarray) and events.dtype == EVENT_DTYPE else make_events(events)
        return Toolpath(self.start, self.xyz, self.feed, self.e, self.tool, self.role, self.layer, self.layer_z, ev)


class ToolpathBuilder:
    """Accumulates moves in Python lists of arrays and freezes them once.

    Front ends append whole polylines at a time (vectorised), never point by point.
    """

    def __init__(self, start=(0.0, 0.0, 0.0)):
        start = _column("ToolpathBuilder: start", start, np.float64)
        if start.shape != (3,) or not np.all(np.isfinite(start)):
            raise DeltasliceError(f"ToolpathBuilder: start = {start.tolist()}: expected a finite point (x, y, z), mm")
        self.start = start
        self.pos = self.start.copy()
        self._chunks: list[tuple] = []
        self._events: list[tuple] = []
        self._n = 0
        self.layer_z: list[float] = []

    @property
    def layer(self) -> int:
        return len(self.layer_z) - 1

    def new_layer(self, z: float) -> None:
        z = _column("ToolpathBuilder.new_layer: z", z, np.float64)
        if z.shape != () or not np.isfinite(z):
            raise DeltasliceError(f"ToolpathBuilder.new_layer: z = {z!r}: expected one finite height, mm")
        self.layer_z.append(float(z))

    def add(self, xyz, feed, e, tool, role) -> None:
        """Append moves to ``xyz`` ((k,3) mm) with per-move or scalar feed, e, tool, role."""
        xyz = _column("ToolpathBuilder.add: xyz", xyz, np.float64)
        if xyz.size == 0:
            return
        if xyz.ndim == 1 and xyz.shape == (3,):
            xyz = xyz[None]
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise DeltasliceError(f"ToolpathBuilder.add: xyz: expected shape (k, 3) mm, got {xyz.shape}")
        k = len(xyz)
        if k == 0:
            return

        def b(v, dt):
            # one number for the whole chunk (travels, retracts, a path's tool): no checks to run
            # beyond its type and range (the slicer adds thousands of chunks)
            if (isinstance(v, int) and 0 <= v <= 255) or (dt is float and isinstance(v, float)):
                return np.full(k, v, dt)
            arr = _column(f"ToolpathBuilder.add: {_names[dt]}", v, dt)
            try:
                return np.broadcast_to(arr, (k,))
            except ValueError:
                raise DeltasliceError(f"ToolpathBuilder.add: expected one value or {k} values, got shape {arr.shape}") from None

        _names = {float: "feed, e or tool", np.uint8: "role"}
        self._chunks.append(
            (xyz, b(feed, float), b(e, float), b(tool, float), b(role, np.uint8), np.full(k, max(self.layer, 0), np.int32))
        )
        self.pos = xyz[-1].copy()
        self._n += k

    def event(self, kind, value) -> None:
        """A timed event (:class:`EventKind`) before the next move added (or at the end)."""
        self._events.append((self._n, int(EventKind(kind)), float(value)))

    def build(self) -> Toolpath:
        if not self._chunks:
            t = Toolpath.empty(self.start)
            return Toolpath(t.start, t.xyz, t.feed, t.e, t.tool, t.role, t.layer, np.asarray(self.layer_z, float),
                            make_events(self._events))
        cols = list(zip(*self._chunks))
        return Toolpath(self.start, *(np.concatenate(c) for c in cols), np.asarray(self.layer_z, float),
                        make_events(self._events))


SMALL_EXTENT = 0.5  # mm: a whole part narrower than a line of filament is a part in other units
FAST_FEED = 1000.0  # mm/s: beyond any printer; G-code feeds in mm/min (1800-6000) land here


def unit_notes(toolpath: Toolpath) -> list[str]:
    """What in a toolpath looks like another unit or origin, one sentence each: heights below the
    bed, a part smaller than a line of filament (coordinates in metres?), feeds beyond any printer
    (mm/min?). Planned as given; a library caller hears of them (:class:`ToolpathWarning`)."""
    notes = []
    if len(toolpath.layer_z) and float(toolpath.layer_z.min()) < 0:
        i = int(np.argmin(toolpath.layer_z))
        notes.append(f"Toolpath.layer_z: layer {i} at z = {float(toolpath.layer_z[i]):g} mm is below the bed surface "
                     "(z is measured up from the bed in the bed frame): heights measured down, or from another origin?")
    work = toolpath.working
    if work.any():
        pts = np.concatenate([toolpath.starts[work], toolpath.xyz[work]])
        span = np.ptp(pts[:, :2], axis=0)
        if float(span.max()) < SMALL_EXTENT:
            notes.append(f"Toolpath.xyz: the work spans {span[0]:.3g} x {span[1]:.3g} mm, narrower than a line of "
                         "filament: coordinates in metres? (deltaslice takes mm)")
    if len(toolpath.feed) and float(toolpath.feed.max()) > FAST_FEED:
        notes.append(f"Toolpath.feed: feeds up to {float(toolpath.feed.max()):g} mm/s, beyond any printer: in mm/min? "
                     "(deltaslice takes mm/s)")
    return notes


def centred(toolpath: Toolpath) -> tuple[Toolpath, np.ndarray]:
    """The toolpath moved in x-y so its footprint (the bounding box of its working moves, or of
    all moves when none works) is centred on the bed origin, and the shift (2,) mm.

    The source machine's own positioning before the first and after the last working move
    (homing corners, parking) keeps its heights but not its x-y: those moves stay above the
    part's first and last points, so centring never sends the tool to another machine's corner.
    The start point (where the tool is before the job) is unchanged."""
    tp = toolpath
    if len(tp) == 0:
        return tp, np.zeros(2)
    work = tp.working
    starts = tp.starts
    pts = np.concatenate([starts[work], tp.xyz[work]]) if work.any() else np.concatenate([tp.start[None], tp.xyz])
    lo, hi = pts[:, :2].min(axis=0), pts[:, :2].max(axis=0)
    shift = -(lo + hi) / 2
    xyz = tp.xyz.copy()
    xyz[:, :2] += shift
    if work.any():
        first, last = int(np.argmax(work)), len(tp) - 1 - int(np.argmax(work[::-1]))
        xyz[:first, :2] = starts[first, :2] + shift
        xyz[last + 1 :, :2] = xyz[last, :2]
    moved = Toolpath(tp.start, xyz, tp.feed, tp.e, tp.tool, tp.role, tp.layer, tp.layer_z, tp.events)
    return moved, shift


def fits_centred(toolpath: Toolpath, printer) -> bool:
    """True when every point of the toolpath, centred by :func:`centred`, is within the
    printer's work envelope and reach (what ``--center`` would give)."""
    tp, _ = centred(toolpath)
    pts = np.concatenate([tp.start[None], tp.xyz])
    return bool(printer.bed.contains(pts).all() and printer.kinematics().reachable(pts).all())
