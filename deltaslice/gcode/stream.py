"""A G-code file read once with its moves kept in a temporary file, handed over a stretch at a
time (:class:`GcodeStream`, made by ``gcode.open_gcode``)."""

from __future__ import annotations

import numpy as np

from ..errors import GcodeError
from ..toolpath import Toolpath, make_events
from .moves import (_columns, _dialect_note, _layer_heights, _layer_owners, _layer_stats, _moves, _new_layers,
                    _whole, _work)
from .reader import _RAW, _RAW_OFFSETS, _ReadState
from .source import _source_notes

class GcodeStream:
    """A G-code file read by :func:`open_gcode`: its moves in a temporary file, ``moves`` and
    ``layers`` of them. :meth:`chunks` gives consecutive Toolpaths of at most the chunk's moves
    (each starting where the one before ends, layers numbered through the file, every one's
    layer_z the file's, events indexed within their chunk): what
    :func:`deltaslice.planning.plan_stream` takes. A layer without a ``;Z:`` comment (Cura writes
    none) gets its height from its moves in a first pass over the temporary file; a file without
    layer comments (Slic3r, GRBL) gets its layers from the heights of its moves in two passes
    (:meth:`_find_layers`), both as the file read whole. A file read with ``center`` (the
    footprint of every move) comes as one chunk: the whole toolpath."""

    def __init__(self, state: _ReadState, spill, sizes: list, printer, shown: str, echo, center: bool):
        self._state, self._spill, self._sizes = state, spill, sizes
        self._printer, self._shown, self._echo, self._center = printer, shown, echo, center
        self.moves = state.n
        self.streamed = not center
        self._ratio = self._layer_z = None
        if self.streamed:
            self._layer_z = self._layer_heights() if state.have_layer_comments else self._find_layers()
        # layers of a file without layer comments are known once found (a centred one's: never here)
        self.layers = state.n_layers if state.have_layer_comments or self._layer_z is None else len(self._layer_z)
        if self.streamed:
            say = echo or (lambda _s: None)
            note = _dialect_note(printer, state)
            if note:
                say(f"{shown}: {note}")
            self._ratio = _source_notes(state.source, printer, shown, say, center)

    def close(self) -> None:
        self._spill.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _layer_heights(self) -> np.ndarray:
        """(L,) the layers' heights, mm: their ;Z: comments, and where one is missing, a pass over
        the moves (:func:`_layer_heights`, as the file read whole gives them)."""
        state = self._state
        if all(i in state.layer_z_comment for i in range(state.n_layers)):
            return _layer_heights(state, None)
        stats, start = None, state.start
        for xyz, cols in self._stretches():
            working = _work(state, self._printer, cols, start)[0]
            stats = _layer_stats(stats, cols.layer, xyz[:, 2], working, state.n_layers)
            start = xyz[-1]
        return _layer_heights(state, stats)

    def _find_layers(self) -> np.ndarray:
        """Layers from heights for a file without layer comments, as :func:`_layers_from_z` finds
        them in the whole file: a new layer at each working move higher than every one before
        (a pass forwards), the moves between layers belonging to the next working move's (a pass
        backwards). The layer of every move is written into the temporary file's layer column;
        returns the layers' heights (L,) mm."""
        state, printer = self._state, self._printer
        top, count, heights, starts, z_max, start = -np.inf, 0, [], [], -np.inf, state.start
        for b, (xyz, cols) in enumerate(self._stretches()):
            working = _work(state, printer, cols, start)[0]
            z = xyz[:, 2]
            new, top = _new_layers(z, working, top)
            lay_at = count - 1 + np.cumsum(new, dtype=np.int32)
            self._write_layer(b, lay_at)
            heights.extend(z[new].tolist())
            count += int(new.sum())
            z_max = max(z_max, float(z.max()))
            starts.append(start)
            start = xyz[-1]
        if count == 0:  # nothing works: one layer at the highest move
            for b, size in enumerate(self._sizes):
                self._write_layer(b, np.zeros(size, np.int32))
            return np.array([z_max])
        following = int(lay_at[-1])  # the next working move's layer after a block: after the last, the last move's
        for b in reversed(range(len(self._sizes))):
            raw = self._block(b)
            xyz = np.column_stack(raw[:3])
            lay_at = np.asarray(raw[6], dtype=np.int32)
            working = _work(state, printer, _moves(xyz, raw, lay_at), starts[b])[0]
            self._write_layer(b, _layer_owners(lay_at, working, following))
            if working.any():
                following = int(lay_at[int(np.argmax(working))])
        return np.array(heights)

    def _offset(self, b: int, column: int) -> int:
        """Where column ``column`` of block b starts in the temporary file (bytes)."""
        return sum(self._sizes[:b]) * _RAW_OFFSETS[-1] + self._sizes[b] * _RAW_OFFSETS[column]

    def _read_into(self, view: memoryview, offset: int) -> None:
        # every read and write says where (seek): the passes interleave them
        self._spill.seek(offset)
        if self._spill.readinto(view) != len(view):
            raise GcodeError(f"{self._shown}: its temporary file of moves was cut short")

    def _block(self, b: int) -> list:
        """_RAW's columns of block b (numpy arrays)."""
        out = []
        for k, (_name, code) in enumerate(_RAW):
            column = np.empty(self._sizes[b], np.dtype(code))
            self._read_into(memoryview(column).cast("B"), self._offset(b, k))
            out.append(column)
        return out

    def _write_layer(self, b: int, layer: np.ndarray) -> None:
        self._spill.seek(self._offset(b, 6))
        self._spill.write(np.ascontiguousarray(layer, np.int32).tobytes())

    def _stretches(self):
        """(xyz, _Moves) of each block of moves, in order."""
        for b in range(len(self._sizes)):
            raw = self._block(b)
            xyz = np.column_stack(raw[:3])
            yield xyz, _moves(xyz, raw, np.asarray(raw[6], dtype=np.int32))

    def whole(self) -> Toolpath:
        """All the moves as one Toolpath (:func:`read_gcode`'s), read a column at a time: the
        columns once, as reading the file whole holds them."""
        raw = [np.empty(self.moves, np.dtype(code)) for _name, code in _RAW]
        at = 0
        for b, size in enumerate(self._sizes):
            for k, column in enumerate(raw):
                self._read_into(memoryview(column[at : at + size]).cast("B"), self._offset(b, k))
            at += size
        # a stream said its notes while it was read
        return _whole(self._state, raw, self._printer, self._shown, None if self.streamed else self._echo, self._center)

    def chunks(self):
        """The moves as consecutive Toolpaths, a block at a time (see the class)."""
        if not self.streamed:
            yield self.whole()
            return
        state, printer, layer_z = self._state, self._printer, self._layer_z
        events = make_events(state.events)
        start, retracted, at = state.start, [0.0], 0
        for xyz, cols in self._stretches():
            n = len(xyz)
            working, e, tool, moved = _work(state, printer, cols, start)
            columns = _columns(state, printer, cols, working, e, tool, moved, cols.layer, layer_z, start, self._ratio,
                               retracted)
            last = at + n == self.moves
            ev = events[(events["index"] >= at) & ((events["index"] < at + n) | last)].copy()
            ev["index"] -= at
            yield Toolpath(start, *columns, layer_z, ev)
            start, at = xyz[-1], at + n
