"""Planned pieces kept on disk instead of in memory, for prints too long to hold.

A print's pieces take about a kilobyte per move (grids, blended paths); a 1.5 M-move spiral vase
would hold gigabytes. :class:`PieceSpool` is the list the planner appends to instead: each batch
of pieces is pickled to an anonymous temporary file as it is planned, and read back batch by batch
when the trajectory is sampled (in order, so each batch is read once). What the trajectory needs of
every piece without sampling it (duration, filament, active time, kind) stays in memory, a few
numbers a piece.
"""

from __future__ import annotations

import os
import pickle
import tempfile
from array import array
from bisect import bisect_right

import numpy as np

from .pieces import PieceBatch

#: moves in a toolpath above which ``plan`` spools its pieces (about 200 MB of pieces in memory)
SPOOL_MOVES = 200_000
#: pieces are pickled together until this many grid points (a few MB) or BATCH_PIECES pieces wait:
#: one batch a job would cost a pickle call and two index entries for every travel
BATCH_POINTS = 20_000
BATCH_PIECES = 512


class PieceSpool:
    """A sequence of pieces in a temporary file (deleted when closed or collected).

    ``extend(pieces)`` adds pieces, written a batch at a time (BATCH_POINTS, BATCH_PIECES);
    ``spool[i]`` and iteration read batches back, keeping the last one read. ``durations``,
    ``filament_totals``, ``active_times`` (float arrays) and ``kinds`` are kept per piece in
    memory."""

    def __init__(self):
        self._file = tempfile.TemporaryFile(prefix="deltaslice-pieces-")
        self._offsets = array("q", [0])  # file offset of each batch, and the end
        self._first = array("q", [0])  # index of each batch's first piece, and the count written
        self._pending, self._pending_points = [], 0
        self.durations = array("d")
        self.filament_totals = array("d")
        self.active_times = array("d")
        self.kinds: list[str] = []
        self._cached = (-1, [])

    def extend(self, pieces) -> None:
        for p in pieces:
            self.durations.append(p.duration)
            self.filament_totals.append(p.filament_total)
            self.active_times.append(p.active_time)
            self.kinds.append(p.kind)
            self._pending.append(p)
            self._pending_points += len(getattr(p, "x", ())) + 1
        if self._pending_points >= BATCH_POINTS or len(self._pending) >= BATCH_PIECES:
            self._flush()

    def _flush(self) -> None:
        if not self._pending:
            return
        self._file.seek(self._offsets[-1])
        pickle.dump(PieceBatch([self._pending]), self._file, protocol=pickle.HIGHEST_PROTOCOL)
        self._file.flush()  # batches are read back with os.pread, past the file object's buffer
        self._offsets.append(self._file.tell())
        self._first.append(self._first[-1] + len(self._pending))
        self._pending, self._pending_points = [], 0

    def append(self, piece) -> None:
        self.extend([piece])

    def __len__(self) -> int:
        return self._first[-1] + len(self._pending)

    def sync(self) -> None:
        """Write out the pieces still waiting, so a forked process reads every piece from the file."""
        self._flush()

    def _batch(self, b: int) -> list:
        if self._cached[0] != b:
            # read at an offset, not seek-then-read: forked samplers share the file position
            lo, hi = self._offsets[b], self._offsets[b + 1]
            self._cached = (b, pickle.loads(os.pread(self._file.fileno(), hi - lo, lo)).groups[0])
        return self._cached[1]

    def __getitem__(self, i: int):
        n = len(self)
        if isinstance(i, (int, np.integer)) and -n <= i < n:
            self._flush()
            i = int(i) % n
            b = bisect_right(self._first, i) - 1
            return self._batch(b)[i - self._first[b]]
        raise IndexError(f"piece {i!r} of {n}")

    def __iter__(self):
        self._flush()
        for b in range(len(self._first) - 1):
            yield from self._batch(b)

    def close(self) -> None:
        self._cached = (-1, [])
        self._pending = []
        self._file.close()

    def __getstate__(self):
        raise TypeError("a PieceSpool lives in one process (its pieces are in a temporary file)")
