"""The deltaslice binary setpoint stream (``.dsl``): the encoder and writer; the format's names
(:mod:`.stream_format`) and the decoder's (:mod:`.stream_read`) are read through here too.

The format is specified in ``docs/stream-format.md``; this module is its
reference implementation and ``examples/firmware/dsl_player.h`` the C one.
In short: a header (magic, version, printer fingerprint, rate, channels with
kind and scale, printer name, metadata, CRC-32), then self-contained blocks of
integer actuator counts (per block and channel: first value, optional first
difference, then bit-packed zig-zag residuals of first or second differences at
one bit width, CRC-32 per block, at most 512 bytes per block record), event
records (heaters, fan, laser mode; version 2) between blocks, then an end record
with the sample count and a CRC-32 of everything before it.

Encoding and decoding are vectorised per block with numpy.
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

from ..errors import StreamError
from ..jit import njit
from ..samples import Samples, to_counts
from . import csv as csvfmt
from .stream_format import (BLOCK_SAMPLES, COUNT_LIMIT, END_LEN, EVENT_LEN, KIND_CODES, KIND_EXTRUDER, KIND_LASER,
                            KIND_NAMES, KIND_PRISMATIC, KIND_REVOLUTE, KIND_UNITS, MAGIC, MAX_BLOCK_SAMPLES,
                            MAX_CHANNELS, MAX_RECORD, REC_BLOCK, REC_END, REC_EVENT, VERSION, VERSION_EVENTS, _EVENT,
                            _TENTHS, Channel, StreamHeader, _zz1, event_value, parse_header, unzigzag, zigzag)
from .stream_read import (StreamReader, UnitConverter, decode_block, decode_to_text, format_count_lines, read_counts,
                          read_stream, stream_metadata)

# the format's and the decoder's names, read through this module as before the split
__all__ = ["BLOCK_SAMPLES", "COUNT_LIMIT", "END_LEN", "EVENT_LEN", "KIND_CODES", "KIND_EXTRUDER", "KIND_LASER",
           "KIND_NAMES", "KIND_PRISMATIC", "KIND_REVOLUTE", "KIND_UNITS", "MAGIC", "MAX_BLOCK_SAMPLES", "MAX_CHANNELS",
           "MAX_RECORD", "REC_BLOCK", "REC_END", "REC_EVENT", "VERSION", "VERSION_EVENTS", "Channel", "StreamHeader",
           "StreamReader", "StreamWriter", "UnitConverter", "decode_block", "decode_to_text", "encode_block",
           "encode_blocks", "encode_event", "event_value", "format_count_lines", "parse_header", "read_counts",
           "read_stream", "stream_metadata", "unzigzag", "write_stream", "zigzag", "_zz1"]



@njit
def _zz(v):
    """Zig-zag of an int64 without a branch: 2v for v >= 0, -2v - 1 below."""
    return (v << 1) ^ (v >> 63)


@njit
def _bits(u):
    n = 0
    while u:
        u >>= 1
        n += 1
    return n


@njit
def _varint_len(u):
    n = 1
    while u >= 128:
        u >>= 7
        n += 1
    return n


@njit
def _put_varint(buf, pos, u):
    while u >= 128:
        buf[pos] = (u & 0x7F) | 0x80
        u >>= 7
        pos += 1
    buf[pos] = u
    return pos + 1


@njit
def _ors(x, a, b, ored):
    """ored[0, c]: the or of the zig-zags of channel c's first differences over rows a..b-1,
    ored[1, c] of its second differences (0 where there are none). The bits a width needs are
    those of the largest zig-zag, which are those of all of them or-ed together (a pass without a
    branch)."""
    for c in range(x.shape[1]):
        m1 = 0
        m2 = 0
        if b - a >= 2:
            d_prev = x[a + 1, c] - x[a, c]
            m1 = _zz(d_prev)
            for k in range(a + 2, b):
                d = x[k, c] - x[k - 1, c]
                m1 |= _zz(d)
                m2 |= _zz(d - d_prev)
                d_prev = d
        ored[0, c] = m1
        ored[1, c] = m2


@njit(inline="always")  # one caller: typed in it, no module of its own on a first run
def _halves_ors(x, a, m, b, left, right, whole):
    """:func:`_ors` of rows a..m-1 and m..b-1 (a + 2 <= m <= b - 2), and of a..b-1 from theirs:
    the whole's differences are the halves' and those that cross m (the first difference at row
    m, the second differences at rows m and m + 1). One pass over the rows for the three."""
    _ors(x, a, m, left)
    _ors(x, m, b, right)
    for c in range(x.shape[1]):
        d_before = x[m - 1, c] - x[m - 2, c]
        d_at = x[m, c] - x[m - 1, c]
        d_after = x[m + 1, c] - x[m, c]
        whole[0, c] = left[0, c] | right[0, c] | _zz(d_at)
        whole[1, c] = left[1, c] | right[1, c] | _zz(d_at - d_before) | _zz(d_after - d_at)


@njit(inline="always")  # one caller: typed in it, no module of its own on a first run
def _sized(x, a, b, use1, use2, order, width, v0, ored):
    """Per channel of rows a..b-1 (their ors: :func:`_ors`): first (order 1) or second (order 2)
    differences, whichever needs fewer bits of their zig-zag; v0 the first difference an order-2
    channel starts from. Returns the record's size in bytes."""
    n = b - a
    size = 1 + 2 + 2 + 4  # type, length, count, crc
    row_bits = 0
    for c in range(x.shape[1]):
        w1 = _bits(ored[0, c]) if (use1 or n < 3) else 99
        w2 = _bits(ored[1, c]) if (n >= 3 and use2) else 99
        if w2 < w1:
            order[c], width[c], v0[c] = 2, w2, x[a + 1, c] - x[a, c]
        else:
            order[c], width[c], v0[c] = 1, w1, 0
        size += 1 + _varint_len(_zz(x[a, c]))
        if order[c] == 2:
            size += _varint_len(_zz(v0[c]))
        row_bits += width[c]
    return size + ((n - 1) * row_bits + 7) // 8


@njit(inline="always")  # one caller: typed in it, no module of its own on a first run
def _write_record(x, a, b, order, width, v0, size, buf, pos):
    """The block record of rows a..b-1 at buf[pos:pos + size] (every byte written), its CRC
    left zero (the caller's)."""
    n = b - a
    nch = x.shape[1]
    buf[pos] = REC_BLOCK
    buf[pos + 1] = size & 0xFF
    buf[pos + 2] = size >> 8
    buf[pos + 3] = n & 0xFF
    buf[pos + 4] = n >> 8
    q = pos + 5
    for c in range(nch):
        buf[q] = (order[c] << 6) | width[c]
        q = _put_varint(buf, q + 1, _zz(x[a, c]))
        if order[c] == 2:
            q = _put_varint(buf, q, _zz(v0[c]))
    # sample-major LSB-first bit packing of the residual rows, four bytes written as soon as
    # they are full. A width is at most 32 bits (counts within +-(2^29 - 1), as _encoded checks:
    # second differences within +-(2^31 - 4)), and fewer than 32 are held when one is added, so
    # the accumulator never holds more than 63.
    acc = 0
    held = 0
    for k in range(a + 1, b):
        for c in range(nch):
            d = x[k, c] - x[k - 1, c]
            if order[c] == 2:
                d = d - (x[k - 1, c] - x[k - 2, c]) if k > a + 1 else 0
            acc |= _zz(d) << held
            held += width[c]
            if held >= 32:
                buf[q] = acc & 0xFF
                buf[q + 1] = (acc >> 8) & 0xFF
                buf[q + 2] = (acc >> 16) & 0xFF
                buf[q + 3] = (acc >> 24) & 0xFF
                acc >>= 32
                held -= 32
                q += 4
    while held > 0:
        buf[q] = acc & 0xFF
        acc >>= 8
        held -= 8
        q += 1
    for i in range(4):
        buf[pos + size - 4 + i] = 0


@njit(nogil=True)  # beside the limit monitor's thread (LimitMonitor.watch)
def _encode_kernel(x, block_samples, max_record, use1, use2, buf, rec_end):
    """Block records of counts x (n, C) into buf: nominal ``block_samples`` rows each,
    halved until a record fits ``max_record`` bytes. rec_end[i]: where record i ends in buf.
    Returns the number of records, or -1 when one sample does not fit.

    A nominal block's halves are measured in the pass that measures it (:func:`_halves_ors`):
    most of a print's blocks are halved once, and measuring each half again cost a third of
    the encoding. A half halved again is measured as it comes."""
    nch = x.shape[1]
    order = np.empty(nch, dtype=np.int64)
    width = np.empty(nch, dtype=np.int64)
    v0 = np.empty(nch, dtype=np.int64)
    ored = np.empty((2, nch), dtype=np.int64)  # of the range being sized
    halves = np.empty((2, 2, nch), dtype=np.int64)  # of a nominal block's two halves
    # a, b, and which ors are known: -1 none, 0 or 1 a half's (in halves), 2 the nominal block's (in ored)
    stack = np.empty((64, 3), dtype=np.int64)
    pos = np.int64(0)  # not a literal 0: numba would compile _write_record for that value too
    count = 0
    for first in range(0, x.shape[0], block_samples):
        a = first
        b = min(first + block_samples, x.shape[0])
        stack[0, 0], stack[0, 1], stack[0, 2] = a, b, -1
        if b - a >= 4:
            _halves_ors(x, a, (a + b) // 2, b, halves[0], halves[1], ored)
            stack[0, 2] = 2
        top = 1
        while top:
            top -= 1
            a = stack[top, 0]
            b = stack[top, 1]
            known = stack[top, 2]
            if known < 0:
                _ors(x, a, b, ored)
            size = _sized(x, a, b, use1, use2, order, width, v0, halves[known] if 0 <= known <= 1 else ored)
            if size > max_record:
                if b - a == 1:
                    return -1
                m = (a + b) // 2
                nominal = known == 2  # its halves' ors were taken with its own
                stack[top, 0], stack[top, 1], stack[top, 2] = m, b, 1 if nominal else -1
                stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = a, m, 0 if nominal else -1
                top += 2
                continue
            _write_record(x, a, b, order, width, v0, size, buf, pos)
            pos += size
            rec_end[count] = pos
            count += 1
    return count


@njit(nogil=True)
def _time_base_offset(t, n0, rate):
    """The largest |t[k] - (n0 + k) / rate| over t (n,), s (the division numpy's, of the index as a
    float); NaN if any t is NaN: the writer's time-base check in one pass instead of six."""
    worst = 0.0
    for k in range(t.shape[0]):
        off = abs(t[k] - (n0 + k) / rate)
        if not off <= worst:
            worst = off
            if off != off:
                return off
    return worst


def _beyond_limit(counts: np.ndarray) -> np.ndarray:
    """Where counts (int64) are not within +-(COUNT_LIMIT - 1): by comparison, since np.abs leaves
    -2^63 negative (what a value of 1e30 or more turns into when cast)."""
    return (counts >= COUNT_LIMIT) | (counts <= -COUNT_LIMIT)


def _records(counts: np.ndarray, block_samples: int, max_record: int, orders=(1, 2)) -> list[bytes]:
    data, rec_end = _encoded(counts, block_samples, max_record, orders)
    return [data[a:b] for a, b in zip([0, *rec_end[:-1]], rec_end)]


def _encoded(counts: np.ndarray, block_samples: int, max_record: int, orders=(1, 2), *,
             checked: bool = False) -> tuple[bytes, list[int]]:
    """The block records of ``counts`` end to end, CRCs in place, and where each ends: what a
    writer puts in one write instead of a write per record. checked: the counts are known to be
    within +-(COUNT_LIMIT - 1) (the writer checked them as it made them)."""
    counts = np.ascontiguousarray(counts, dtype=np.int64)
    n = len(counts)
    if n == 0:
        return b"", []
    if not checked:
        beyond = _beyond_limit(counts)
        if beyond.any():  # compared, not np.abs'd: |-2^63| is still negative in int64
            raise StreamError(f"an actuator count beyond +-2^29 ({int(counts[beyond][0])}) cannot be stored")
    # at most one record per sample; each at most max_record bytes and its rows' bits
    cap = min(n * max_record, n * (9 + counts.shape[1] * 20) + 64)
    buf = np.empty(cap, dtype=np.uint8)  # every byte up to the last record's end is written
    rec_end = np.empty(n, dtype=np.int64)
    count = _encode_kernel(counts, int(block_samples), int(max_record), 1 in orders, 2 in orders, buf, rec_end)
    if count < 0:
        raise StreamError(f"one sample of {counts.shape[1]} channels does not fit a {max_record}-byte block")
    ends = rec_end[:count].tolist()
    data = bytearray(buf[: ends[-1]].tobytes())
    view = memoryview(data)
    start = 0
    for end in ends:
        struct.pack_into("<I", data, end - 4, zlib.crc32(view[start : end - 4]))
        start = end
    view.release()
    return bytes(data), ends


def encode_block(x: np.ndarray) -> bytes:
    """One block record for counts x (n, C) int64, 1 <= n <= 65535, whatever its size up to the
    format's 65535 bytes (callers that must fit MAX_RECORD split: see :func:`encode_blocks`)."""
    x = np.asarray(x, dtype=np.int64)
    recs = _records(x, len(x), 0xFFFF)
    if len(recs) != 1:
        raise StreamError(f"block of {len(x)} samples needs more than 65535 bytes: too large")
    return recs[0]


def encode_blocks(counts: np.ndarray, block_samples: int = BLOCK_SAMPLES, max_record: int = MAX_RECORD,
                  orders=(1, 2)) -> list[bytes]:
    """Block records for counts (n, C): nominal ``block_samples`` per block, halved
    until each record fits ``max_record`` bytes (planned, sized and packed in one compiled pass;
    ``orders`` restricts the difference orders, for measurements)."""
    return _records(counts, block_samples, max_record, orders)


# --------------------------------------------------------------------------- events


def encode_event(index: int, kind: int, value: float) -> bytes:
    """One 16-byte event record: before sample ``index``; value in degrees C (stored in
    tenths), fan 0..255 or laser mode 0/3/4."""
    if kind not in (1, 2, 3, 4, 5, 6):
        raise StreamError(f"event kind {kind} is not one of 1..6")
    stored = int(round(value * 10 if kind in _TENTHS else value))
    if not 0 <= index <= 0xFFFFFFFF or not -(2**31) <= stored < 2**31:
        raise StreamError(f"event at sample {index} with value {value!r} cannot be stored")
    rec = _EVENT.pack(REC_EVENT, EVENT_LEN, index, kind, stored)
    return rec + struct.pack("<I", zlib.crc32(rec))




# --------------------------------------------------------------------------- writer


class StreamWriter:
    """Encodes Samples blocks to an open binary file; :meth:`close` writes the end record."""

    def __init__(self, f, printer, rate: float, metadata: dict | None = None, block_samples: int = BLOCK_SAMPLES,
                 events=()):
        self.f = f
        self.printer = printer
        # (sample index, kind, value) in order; a block ends at every event's index
        self.events = sorted(((int(i), int(k), float(v)) for i, k, v in events), key=lambda ev: ev[0])
        for ev in self.events:
            encode_event(*ev)  # refuse an unstorable event before anything is written
        self.header = StreamHeader.for_printer(printer, rate, metadata, VERSION_EVENTS if self.events else VERSION)
        self.rate = self.header.rate
        self.block_samples = block_samples
        self.crc = 0
        self.size = 0
        self.n_samples = 0  # samples received
        self.n_written = 0  # samples in written blocks
        self.pending = np.zeros((0, self.header.n_channels), dtype=np.int64)
        self._put(self.header.encode())

    def _put(self, data: bytes) -> None:
        self.f.write(data)
        self.crc = zlib.crc32(data, self.crc)
        self.size += len(data)

    def write(self, samples: Samples) -> None:
        if samples.n_joints != self.printer.n_joints:
            raise StreamError(f"samples have {samples.n_joints} joints, printer {self.printer.name} has {self.printer.n_joints}")
        if len(samples) == 0:
            return
        if not _time_base_offset(samples.t, self.n_samples, self.rate) <= 1e-3 / self.rate:  # NaN fails too
            csvfmt.check_finite(samples, self.n_samples)  # a non-finite value is named as such
            expect = (self.n_samples + np.arange(len(samples))) / self.rate
            i = int(np.argmax(np.abs(samples.t - expect) > 1e-3 / self.rate))
            raise StreamError(
                f"sample {self.n_samples + i}: t = {samples.t[i]:.9f} s, expected {expect[i]:.9f} s: a stream holds "
                f"samples uniformly spaced at {self.rate:g} Hz from t = 0"
            )
        # The counts' pass gives their largest magnitude: values all finite and every count within
        # +-(COUNT_LIMIT - 1) exactly when it is below COUNT_LIMIT - 1/2 (rint rounds half to even,
        # COUNT_LIMIT is even). Only otherwise are the arrays searched for the sample to name.
        counts, peak = to_counts(self.printer, samples, with_peak=True)
        if not (peak < COUNT_LIMIT - 0.5 and np.isfinite(samples.e).all() and np.isfinite(samples.tool).all()):
            csvfmt.check_finite(samples, self.n_samples)
            big = _beyond_limit(counts)
            if big.any():
                i = int(np.flatnonzero(big.any(axis=1))[0])
                raise StreamError(f"sample {self.n_samples + i}: actuator count {counts[i].tolist()} beyond +-2^29")
        self.n_samples += len(samples)
        # Rows held back are completed to a block with the rows they need, not joined to the whole
        # block of samples (a copy of every sample): the pending rows start at a record's start, so
        # taking the rows in two parts cuts the same records.
        while len(self.pending) and len(counts):
            k = self.block_samples - len(self.pending)
            self._take(np.concatenate([self.pending, counts[:k]]))
            counts = counts[k:]
        if len(counts):
            self._take(counts)

    def _take(self, pending):
        """Write the pending rows (from a record's start) up to each event they reach and in
        whole blocks; hold the rest back."""
        pending = self._emit_events(pending)
        full = len(pending) // self.block_samples * self.block_samples
        self._emit(pending[:full])
        self.pending = pending[full:]

    def _emit_events(self, pending):
        """Write the pending samples before each event whose index they reach, then the event;
        return the samples left after the last such event."""
        while self.events and self.events[0][0] <= self.n_written + len(pending):
            i = self.events[0][0]
            cut = i - self.n_written
            if cut > 0:
                self._emit(pending[:cut])
                pending = pending[cut:]
            while self.events and self.events[0][0] == i:
                self._put(encode_event(*self.events.pop(0)))
        return pending

    def _emit(self, counts):
        if len(counts):
            self._put(_encoded(counts, self.block_samples, MAX_RECORD, checked=True)[0])
            self.n_written += len(counts)

    def close(self) -> int:
        self._emit(self._emit_events(self.pending))
        self.pending = self.pending[:0]
        for ev in self.events:  # events at or past the last sample stand before the end record
            self._put(encode_event(self.n_written, ev[1], ev[2]))
        self.events = []
        body = bytes([REC_END]) + struct.pack("<HII", END_LEN, self.n_written, self.crc)
        self._put(body + struct.pack("<I", zlib.crc32(body)))
        return self.size


def write_stream(blocks, printer, f, *, rate: float, metadata: dict | None = None,
                 block_samples: int = BLOCK_SAMPLES, events=()) -> int:
    """Write Samples blocks as a binary stream to the binary file ``f``. Returns bytes written.

    events: ``(sample_index, kind, value)`` in order; the stream is version 2 when there are any."""
    w = StreamWriter(f, printer, rate, metadata, block_samples, events)
    for samples in blocks:
        w.write(samples)
    return w.close()
