"""Reading the binary stream back: block records decoded (:func:`decode_block`), a stream read
record by record with its CRCs checked (:class:`StreamReader`), counts, units and the text dump
(:func:`decode_to_text`)."""

from __future__ import annotations

import struct
import zlib

import numpy as np

from ..errors import StreamError
from ..machine.tool import tool_class
from ..samples import Samples
from ..toolpath import EVENT_NAMES, EventKind
from . import csv as csvfmt
from .stream_format import (_EVENT, _FIXED, END_LEN, EVENT_LEN, KIND_UNITS, MAGIC, MAX_BLOCK_SAMPLES, REC_BLOCK,
                            REC_END, REC_EVENT, VERSION_EVENTS, StreamHeader, _read_varint, _unzz1, event_value,
                            parse_header, unzigzag)


def decode_block(rec: bytes, n_channels: int) -> np.ndarray:
    """Counts (n, C) int64 of one block record whose CRC was checked. Raises ValueError
    when its inner structure is inconsistent."""
    length, n = struct.unpack_from("<HH", rec, 1)
    end = length - 4
    pos = 5
    plans = []
    for _c in range(n_channels):
        if pos >= end:
            raise ValueError("channel headers run past the record")
        mode = rec[pos]
        pos += 1
        order, width = mode >> 6, mode & 0x3F
        if order not in (1, 2) or width > 32:
            raise ValueError(f"invalid channel mode byte 0x{mode:02x}")
        x0, pos = _read_varint(rec, pos, end)
        v0 = 0
        if order == 2:
            v0, pos = _read_varint(rec, pos, end)
        plans.append((order, width, _unzz1(x0), _unzz1(v0)))
    if n < 1:
        raise ValueError("block holds no samples")
    row_bits = sum(p[1] for p in plans)
    need = ((n - 1) * row_bits + 7) // 8
    if end - pos != need:
        raise ValueError(f"payload is {end - pos} bytes, {need} expected for {n} samples of {row_bits} bits")
    out = np.empty((n, n_channels), dtype=np.int64)
    if row_bits and n > 1:
        bits = np.unpackbits(np.frombuffer(rec, dtype=np.uint8, count=need, offset=pos), bitorder="little")
        bits = bits[: (n - 1) * row_bits].reshape(n - 1, row_bits)
    off = 0
    for c, (order, width, x0, v0) in enumerate(plans):
        if width and n > 1:
            weights = np.uint64(1) << np.arange(width, dtype=np.uint64)
            r = unzigzag((bits[:, off : off + width].astype(np.uint64) * weights).sum(axis=1, dtype=np.uint64))
            off += width
        else:
            r = np.zeros(n - 1, dtype=np.int64)
        if order == 2:
            r = v0 + np.cumsum(r)
        out[0, c] = x0
        out[1:, c] = x0 + np.cumsum(r)
    return out


# --------------------------------------------------------------------------- reader


class StreamReader:
    """Reads a stream from a binary file object. ``header`` after construction;
    :meth:`blocks` yields ``(block_index, first_sample_index, counts (n, C) int64)``
    and raises :class:`StreamError` at the first bad record, before yielding any
    sample of it. Event records met on the way are appended to :attr:`events` as
    ``(sample_index, kind, value)`` (value in degrees C, fan 0..255, laser mode)."""

    def __init__(self, f, name: str = "stream"):
        self.f = f
        self.name = name
        fixed = f.read(_FIXED.size)
        if len(fixed) < 8 or fixed[:8] != MAGIC:
            raise StreamError(f"{name}: not a deltaslice stream (bad magic at byte offset 0)")
        if len(fixed) < _FIXED.size:
            raise StreamError(f"{name}: truncated header ({len(fixed)} bytes)")
        hlen = _FIXED.unpack(fixed)[2]
        rest = f.read(max(0, hlen - _FIXED.size))
        data = fixed + rest
        self.header = parse_header(data, name)
        self.offset = len(data)
        self.crc = zlib.crc32(data)
        self.events: list[tuple[int, int, float]] = []

    def _fail(self, block: int, offset: int, what: str):
        raise StreamError(f"{self.name}: block {block} at byte offset {offset}: {what}")

    def blocks(self):
        nch = self.header.n_channels
        index, sample = 0, 0
        while True:
            at = self.offset
            head = self.f.read(3)
            if len(head) == 0:
                self._fail(index, at, f"stream truncated: ends after {index} blocks ({sample} samples) without an end record")
            if head[0] == REC_END:
                rest = self.f.read(END_LEN - len(head))
                rec = head + rest
                if len(rec) < END_LEN:
                    self._fail(index, at, "stream truncated inside the end record")
                _t, length, total, stream_crc, crc = struct.unpack("<BHIII", rec)
                if zlib.crc32(rec[:-4]) != crc or length != END_LEN:
                    self._fail(index, at, "end record corrupt (CRC mismatch)")
                if total != sample:
                    self._fail(index, at, f"end record counts {total} samples, the blocks hold {sample}")
                if stream_crc != self.crc:
                    self._fail(index, at, f"whole-stream CRC mismatch (stored 0x{stream_crc:08x}, computed 0x{self.crc:08x})")
                if self.f.read(1):
                    self._fail(index, at + END_LEN, "unexpected bytes after the end record")
                return
            if head[0] == REC_EVENT:
                rec = head + self.f.read(EVENT_LEN - len(head))
                if len(rec) < EVENT_LEN:
                    self._fail(index, at, "stream truncated inside an event record")
                _t, length, i, kind, stored = _EVENT.unpack_from(rec)
                if length != EVENT_LEN or zlib.crc32(rec[:12]) != struct.unpack_from("<I", rec, 12)[0]:
                    self._fail(index, at, "event record corrupt (CRC mismatch or length)")
                if self.header.version < VERSION_EVENTS:
                    self._fail(index, at, f"event record in a version {self.header.version} stream")
                if kind not in (1, 2, 3, 4, 5, 6) or i != sample:
                    self._fail(index, at, f"event kind {kind} at sample {i}: expected kind 1..6 before sample {sample}")
                self.events.append((i, kind, event_value(kind, stored)))
                self.crc = zlib.crc32(rec, self.crc)
                self.offset += EVENT_LEN
                continue
            if head[0] != REC_BLOCK:
                self._fail(index, at, f"unknown record type 0x{head[0]:02x} (corrupt or out of sync)")
            if len(head) < 3:
                self._fail(index, at, "stream truncated inside a block header")
            length = struct.unpack_from("<H", head, 1)[0]
            if not 5 + 2 * nch + 4 <= length <= self.header.max_record:
                self._fail(index, at, f"block length {length} outside {5 + 2 * nch + 4}..{self.header.max_record} (corrupt)")
            rest = self.f.read(length - 3)
            rec = head + rest
            if len(rec) < length:
                self._fail(index, at, f"stream truncated inside the block ({len(rec)} of {length} bytes)")
            stored = struct.unpack_from("<I", rec, length - 4)[0]
            computed = zlib.crc32(memoryview(rec)[: length - 4])
            if stored != computed:
                self._fail(index, at, f"CRC mismatch (stored 0x{stored:08x}, computed 0x{computed:08x}): block is corrupt")
            n = struct.unpack_from("<H", rec, 3)[0]
            if n > MAX_BLOCK_SAMPLES:
                self._fail(index, at, f"the block declares {n} samples, more than the {MAX_BLOCK_SAMPLES} a block "
                                      "holds (not a stream deltaslice wrote)")
            try:
                counts = decode_block(rec, nch)
            except ValueError as exc:
                self._fail(index, at, f"inconsistent block: {exc}")
            self.crc = zlib.crc32(rec, self.crc)
            self.offset += length
            yield index, sample, counts
            index += 1
            sample += len(counts)


def read_counts(f, name: str = "stream") -> tuple[StreamHeader, np.ndarray]:
    """Header and all counts (n, C) int64 of a stream read from the binary file ``f``."""
    reader = StreamReader(f, name)
    parts = [c for _i, _s, c in reader.blocks()]
    counts = np.concatenate(parts) if parts else np.zeros((0, reader.header.n_channels), dtype=np.int64)
    return reader.header, counts


class UnitConverter:
    """Counts -> Samples using only the stream header (carries the extruder's last
    position across blocks so the derived tool column is continuous)."""

    def __init__(self, header: StreamHeader):
        self.h = header
        ch = header.channels
        self.cpu = np.array([c.counts_per_unit for c in ch[:-1]])
        self.zero = np.array([c.zero_count for c in ch[:-1]])
        self.tool = tool_class(header.tool_kind)  # what the tool channel's values mean
        self.last = None

    def __call__(self, counts: np.ndarray, first: int) -> Samples:
        h = self.h
        n = len(counts)
        t = (first + np.arange(n)) * 1000.0 / h.rate_mhz
        q = (counts[:, :-1] - self.zero) / self.cpu
        values = counts[:, -1] / h.channels[-1].counts_per_unit
        e, tool = self.tool.from_channel(values, self.last)
        if n:
            self.last = values[-1]
        return Samples(t, q, e, tool)


def read_stream(f, name: str = "stream") -> tuple[dict, Samples]:
    """(metadata, Samples in joint units) of a stream read from the binary file ``f``. The
    metadata's ``"events"`` entry (only when the stream has event records) is a tuple of
    ``(sample_index, kind, value)``, value in degrees C, fan 0..255 or laser mode 0/3/4."""
    reader = StreamReader(f, name)
    parts = [c for _i, _s, c in reader.blocks()]
    header = reader.header
    counts = np.concatenate(parts) if parts else np.zeros((0, header.n_channels), dtype=np.int64)
    meta = stream_metadata(header)
    if reader.events:
        meta["events"] = tuple(reader.events)
    return meta, UnitConverter(header)(counts, 0)


def stream_metadata(header: StreamHeader) -> dict[str, str]:
    meta = {
        "format": "stream",
        "printer": header.printer_name,
        "fingerprint": f"0x{header.fingerprint:08x}",
        "rate_hz": f"{header.rate:.10g}",
        "channels": ", ".join(c.kind_name for c in header.channels),
        "version": str(header.version),
    }
    meta.update(header.metadata)
    return meta


def format_count_lines(first: int, counts: np.ndarray) -> str:
    """The text of ``deltaslice decode``: ``index c1 ... cC`` per sample, single spaces, '\\n'."""
    n, nch = counts.shape
    if n == 0:
        return ""
    table = np.empty((n, nch + 1), dtype=np.int64)
    table[:, 0] = first + np.arange(n)
    table[:, 1:] = counts
    return (("%d " * nch + "%d\n") * n) % tuple(table.ravel().tolist())


def decode_to_text(f, out, units: bool = False, printer=None, name: str = "stream") -> int:
    """Print the samples of the stream read from binary file ``f`` to the text file ``out``;
    returns the sample count.

    Without ``units``: one line per sample, ``index c1 ... cC`` (integer counts), and a line
    ``# event i=... kind=... value=...`` before the sample an event applies to.
    With ``units``: exactly the setpoints CSV format (see :mod:`deltaslice.emit.csv`).
    printer: a loaded Printer the stream must have been compiled for (fingerprint), or None.
    Samples of blocks before a bad one are printed before the StreamError is raised.
    """
    reader = StreamReader(f, name)
    h = reader.header
    if printer is not None and printer.fingerprint() != h.fingerprint:
        raise StreamError(
            f"{name}: stream compiled for printer {h.printer_name!r} (fingerprint 0x{h.fingerprint:08x}), "
            f"not {printer.name!r} (0x{printer.fingerprint():08x})"
        )
    conv = UnitConverter(h)
    if units:
        joint_units = [KIND_UNITS[c.kind] for c in h.channels[:-1]]
        out.write(csvfmt.comment_lines(h.printer_name, h.fingerprint, h.rate, joint_units, h.metadata))
    total = 0
    shown = 0

    def events_before(limit):
        nonlocal shown
        for i, kind, value in reader.events[shown:]:
            if i > limit:
                break
            out.write(csvfmt.event_line(i, kind, value, h.rate) if units else
                      f"# event i={i} kind={EVENT_NAMES[EventKind(kind)]} value={value:.10g}\n")
            shown += 1

    for _i, first, counts in reader.blocks():
        events_before(first)
        if units:
            s = conv(counts, first)
            out.write(csvfmt.format_rows(s.t, s.q, s.e, s.tool))
        else:
            out.write(format_count_lines(first, counts))
        total += len(counts)
    events_before(total)
    out.flush()
    return total
