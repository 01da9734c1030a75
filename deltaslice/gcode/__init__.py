"""G-code in and out.

``gcode_text`` writes a :class:`~deltaslice.toolpath.Toolpath` as RepRap G-code
(absolute E with M82, ``G92 E0`` at the start, ``;LAYER:n`` / ``;Z:`` comments,
PrusaSlicer-style ``;TYPE:`` comments, feeds in mm/min, G0 travels, G1 work)
as text. ``read_gcode`` reads what PrusaSlicer, Slic3r, Cura and deltaslice
write back into a Toolpath: G0/G1, G2/G3 arcs (linearised within
:data:`ARC_TOLERANCE`), G90/G91, M82/M83, G92, G20/G21, modal feed, layer and
role comments. Writing then reading gives back the same Toolpath.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from ..errors import GcodeError
from ..toolpath import Toolpath
from .arcs import ARC_END_TOLERANCE, ARC_TOLERANCE
from .moves import _whole
from .reader import DEFAULT_FEED, MAX_MOVE_FILAMENT, _Reader, _ReadState
from .stream import GcodeStream
from .write import gcode_text

__all__ = ["ARC_END_TOLERANCE", "ARC_TOLERANCE", "CHUNK_MOVES", "DEFAULT_FEED", "MAX_MOVE_FILAMENT", "PROGRESS_LINES",
           "GcodeError", "GcodeStream", "gcode_text", "open_gcode", "parse_gcode", "read_gcode"]

#: Lines between progress reports (a 60 MB spiral vase has 1.5 M).
PROGRESS_LINES = 50_000


def read_gcode(path, *, printer=None, echo=None, center=False, progress=None) -> Toolpath:
    """Read a G-code file into a Toolpath (bed frame = the file's frame, mm).

    printer: optional; gives the feed used before the file sets one, the flow model for
    files without extrusion amounts, the laser's S scale, and the machine the file's own
    settings are compared with. echo: ``callable(str)`` receiving notes (skipped commands,
    dialect, settings that differ). center: move the part's footprint (its working
    moves) to the bed centre. progress: callable(lines read, lines) or None.
    Raises :class:`GcodeError` naming the line on bad input.
    """
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise GcodeError(f"read_gcode: path: expected a file path, got {type(path).__name__} {path!r:.60}")
    if not isinstance(center, bool):
        raise GcodeError(f"read_gcode: center = {center!r:.60}: expected True or False")
    path = Path(path)
    shown = str(path)
    try:
        with open(path, "rb") as f:
            n_lines, prusa_layers = _scan(f)
            f.seek(0)
            return _parse(_file_lines(f, shown), n_lines, prusa_layers, name=shown, printer=printer, echo=echo,
                          center=center, progress=progress)
    except FileNotFoundError:
        raise GcodeError(f"{shown}: no such file") from None
    except OSError as exc:
        raise GcodeError(f"{shown}: cannot read: {exc}") from None


#: moves a stretch of a streamed file holds (open_gcode): about 4 MB of columns
CHUNK_MOVES = 65536


def open_gcode(path, *, printer=None, echo=None, center=False, progress=None, chunk: int | None = None) -> "GcodeStream":
    """Read a G-code file once, keeping its moves in a temporary file rather than in memory, to be
    handed over a stretch at a time (:meth:`GcodeStream.chunks`) or whole (:meth:`GcodeStream.whole`,
    the Toolpath :func:`read_gcode` gives). The options are :func:`read_gcode`'s; the notes are said
    while reading, once. chunk: moves a stretch holds (default CHUNK_MOVES; the stretch ends after
    the move that fills it, all the chords of an arc)."""
    chunk = CHUNK_MOVES if chunk is None else chunk
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise GcodeError(f"open_gcode: path: expected a file path, got {type(path).__name__} {path!r:.60}")
    if not isinstance(chunk, int) or chunk < 1:
        raise GcodeError(f"open_gcode: chunk = {chunk!r}: expected a positive number of moves")
    path = Path(path)
    shown = str(path)
    spill = tempfile.TemporaryFile(prefix="deltaslice-moves-")
    sizes = []

    def sink(raw):
        sizes.append(len(raw[0]))
        try:
            for column in raw:
                spill.write(column)
        except OSError as exc:
            raise GcodeError(f"{shown}: cannot keep its moves in a temporary file ({tempfile.gettempdir()}, 56 bytes "
                             f"a move; set TMPDIR to another directory): {exc.strerror or exc}") from None

    try:
        try:
            with open(path, "rb") as f:
                n_lines, prusa_layers = _scan(f)
                f.seek(0)
                state = _read(_file_lines(f, shown), n_lines, prusa_layers, name=shown, printer=printer, echo=echo,
                              progress=progress, sink=sink, block=chunk)
        except FileNotFoundError:
            raise GcodeError(f"{shown}: no such file") from None
        except OSError as exc:
            raise GcodeError(f"{shown}: cannot read: {exc}") from None
    except BaseException:
        spill.close()
        raise
    return GcodeStream(state, spill, sizes, printer, shown, echo, center)


SCAN_BLOCK = 1 << 20


def _scan(f) -> tuple[int, bool]:
    """(lines, whether PrusaSlicer's ;LAYER_CHANGE comment occurs) of a binary file, read a block
    at a time: the parser needs both before the first line."""
    tag = b";LAYER_CHANGE"
    lines, found, tail = 1, False, b""
    while block := f.read(SCAN_BLOCK):
        lines += block.count(b"\n")
        found = found or tag in tail + block
        tail = block[-len(tag):]
    return lines, found


def _file_lines(f, shown: str):
    """The lines of a binary file as text (UTF-8), one at a time, without their newline, and an
    empty last line after a final newline, as :func:`_iter_lines` gives them: a 60 MB file is
    never held whole (it would be 60 MB of text while its moves' arrays are built)."""
    line_no, offset, last = 0, 0, b"\n"
    for raw in f:
        line_no += 1
        try:
            line = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise GcodeError(f"{shown}:{line_no}: not text (byte {offset + exc.start}): expected G-code") from None
        offset += len(raw)
        last = raw
        yield line[:-1] if line.endswith("\n") else line
    if last.endswith(b"\n"):
        yield ""


def _iter_lines(text: str):
    """The lines of text one at a time (a list of a 60 MB file's 1.5 M lines would take 150 MB)."""
    start = 0
    while True:
        end = text.find("\n", start)
        if end < 0:
            yield text[start:]
            return
        yield text[start:end]
        start = end + 1


def parse_gcode(text: str, *, name: str = "<gcode>", printer=None, echo=None, center=False, progress=None) -> Toolpath:
    """Parse G-code text (see :func:`read_gcode`). progress: callable(lines done, lines) or None."""
    return _parse(_iter_lines(text), text.count("\n") + 1, ";LAYER_CHANGE" in text, name=name, printer=printer,
                  echo=echo, center=center, progress=progress)


def _parse(lines, n_lines: int, prusa_layers: bool, *, name, printer, echo, center, progress) -> Toolpath:
    """:func:`parse_gcode` of ``lines`` (an iterator of the text's lines, n_lines of them);
    prusa_layers: whether a ``;LAYER_CHANGE`` comment occurs anywhere."""
    state = _read(lines, n_lines, prusa_layers, name=name, printer=printer, echo=echo, progress=progress)
    raw, state.kept = list(state.kept), None
    return _whole(state, raw, printer, name, echo, center)


def _read(lines, n_lines: int, prusa_layers: bool, *, name, printer, echo, progress, sink=None, block: int = 0) -> _ReadState:
    """Read ``lines`` into per-move columns: handed to ``sink`` (a callable taking _RAW's arrays)
    every ``block`` moves and at the end when given, else kept in the returned state."""
    if progress is not None and not callable(progress):
        raise GcodeError(f"{name}: progress: expected a callable(done, total) or None, got {type(progress).__name__}")
    reader = _Reader(name, prusa_layers, printer, sink, block)
    for line_no, line in enumerate(lines, 1):
        if progress is not None and line_no % PROGRESS_LINES == 0:
            progress(line_no, n_lines)
        reader.line(line_no, line)
    reader.say_skipped(echo)
    if progress is not None:
        progress(n_lines, n_lines)
    return reader.state()
