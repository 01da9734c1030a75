"""The deltaslice binary setpoint stream (``.dsl``): encoder, decoder, text dump.

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

import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from ..errors import StreamError
from ..jit import njit
from ..samples import Samples, to_counts
from ..toolpath import EVENT_NAMES, EventKind
from . import csv as csvfmt

MAGIC = b"\x89DSL\r\n\x1a\n"
VERSION = 1  # a stream without events
VERSION_EVENTS = 2  # a stream with event records (a version-2 reader plays version 1 too)
MAX_RECORD = 512  # bytes: the player's block buffer (DSL_MAX_RECORD in dsl_player.h)
MAX_CHANNELS = 8
BLOCK_SAMPLES = 512  # nominal samples per block; halved until the record fits MAX_RECORD
# A reader refuses a block declaring more samples than a writer makes: a 17-byte block of width 0
# may declare 65,535 samples, so 17 KB of valid CRCs would otherwise decode to 65 million samples
# (gigabytes). With it a stream holds at most BLOCK_SAMPLES / (5 + 2C + 4) samples per byte.
MAX_BLOCK_SAMPLES = BLOCK_SAMPLES
COUNT_LIMIT = 1 << 29  # |counts| must stay below this (int32 arithmetic in the player)

REC_BLOCK = 0x42  # 'B'
REC_END = 0x45  # 'E'
END_LEN = 15
REC_EVENT = 0x56  # 'V'
EVENT_LEN = 16
_EVENT = struct.Struct("<BHIBi")  # type, length, sample index, kind, value; then CRC-32
_TENTHS = (1, 2, 3, 4)  # temperature kinds: value in tenths of a degree C

KIND_REVOLUTE, KIND_PRISMATIC, KIND_EXTRUDER, KIND_LASER = 1, 2, 3, 4
KIND_NAMES = {KIND_REVOLUTE: "revolute", KIND_PRISMATIC: "prismatic", KIND_EXTRUDER: "extruder", KIND_LASER: "laser"}
KIND_CODES = {name: code for code, name in KIND_NAMES.items()}
KIND_UNITS = {KIND_REVOLUTE: "rad", KIND_PRISMATIC: "mm", KIND_EXTRUDER: "mm", KIND_LASER: "0..1"}

_FIXED = struct.Struct("<8sHHIIBBH")  # magic, version, header_len, fingerprint, rate_mhz, channels, flags, max_record
_CHANNEL = struct.Struct("<Bdd")  # kind, counts_per_unit, zero_count


# --------------------------------------------------------------------------- header


@dataclass(frozen=True)
class Channel:
    kind: int
    counts_per_unit: float
    zero_count: float

    @property
    def kind_name(self) -> str:
        return KIND_NAMES[self.kind]


@dataclass(frozen=True)
class StreamHeader:
    fingerprint: int
    rate_mhz: int
    channels: tuple[Channel, ...]
    printer_name: str
    metadata: dict = field(default_factory=dict)
    max_record: int = MAX_RECORD
    flags: int = 0
    version: int = VERSION

    @property
    def rate(self) -> float:
        """Samples per second."""
        return self.rate_mhz / 1000.0

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    @property
    def n_joints(self) -> int:
        return len(self.channels) - 1

    @property
    def tool_kind(self) -> str:
        """The tool channel's kind name: "extruder" or "laser"."""
        return self.channels[-1].kind_name

    def encode(self) -> bytes:
        name = self.printer_name.encode("utf-8")[:255]
        meta = "".join(f"{k}={v}\n" for k, v in csvfmt.check_metadata(self.metadata).items()).encode("utf-8")
        if len(meta) > 0xFFFF:
            raise StreamError(f"stream metadata too long ({len(meta)} bytes, at most 65535)")
        body = b"".join(_CHANNEL.pack(c.kind, c.counts_per_unit, c.zero_count) for c in self.channels)
        body += bytes([len(name)]) + name + struct.pack("<H", len(meta)) + meta
        total = _FIXED.size + len(body) + 4
        if total > 0xFFFF:
            raise StreamError(f"stream header too long ({total} bytes)")
        fixed = _FIXED.pack(MAGIC, self.version, total, self.fingerprint & 0xFFFFFFFF, self.rate_mhz,
                            len(self.channels), self.flags, self.max_record)
        data = fixed + body
        return data + struct.pack("<I", zlib.crc32(data))

    @classmethod
    def for_printer(cls, printer, rate: float, metadata: dict | None = None, version: int = VERSION) -> "StreamHeader":
        rate_mhz = int(round(rate * 1000.0))
        if not 1 <= rate_mhz <= 0xFFFFFFFF:
            raise StreamError(f"sample rate {rate:g} Hz cannot be stored (0.001 Hz .. 4.29 MHz)")
        lim = printer.limits
        chans = [
            Channel(KIND_CODES[kind], float(cpu), float(zero))
            for kind, cpu, zero in zip(lim.kinds, lim.counts_per_unit, lim.zero_count)
        ]
        if len(chans) > MAX_CHANNELS:
            raise StreamError(f"{len(chans)} channels: the stream holds at most {MAX_CHANNELS}")
        return cls(printer.fingerprint(), rate_mhz, tuple(chans), printer.name, dict(metadata or {}), version=version)


def parse_header(data: bytes, where: str = "stream") -> StreamHeader:
    """Parse and check a complete header (``data`` holds at least header_len bytes).
    Raises StreamError on any inconsistency, including a length field shorter than the
    fields it must hold."""
    try:
        return _parse_header(data, where)
    except (struct.error, IndexError, ValueError) as exc:
        raise StreamError(f"{where}: header fields run past the header length: {exc}") from None


def _parse_header(data: bytes, where: str) -> StreamHeader:
    if len(data) < _FIXED.size:
        raise StreamError(f"{where}: truncated header: {len(data)} bytes, expected at least {_FIXED.size}")
    magic, version, hlen, fp, rate_mhz, nch, flags, max_record = _FIXED.unpack_from(data)
    if magic != MAGIC:
        raise StreamError(f"{where}: not a deltaslice stream (bad magic {magic!r} at byte offset 0)")
    if version not in (VERSION, VERSION_EVENTS):
        raise StreamError(f"{where}: stream format version {version} is not supported (this reader knows 1 and 2)")
    if len(data) < hlen:
        raise StreamError(f"{where}: truncated header: {len(data)} bytes, header length is {hlen}")
    need = _FIXED.size + nch * _CHANNEL.size + 1 + 2 + 4
    if hlen < need:
        raise StreamError(f"{where}: header length {hlen} is smaller than its {nch} channels and fields ({need} bytes at least)")
    stored = struct.unpack_from("<I", data, hlen - 4)[0]
    if zlib.crc32(data[: hlen - 4]) != stored:
        raise StreamError(f"{where}: header CRC mismatch (bytes 0..{hlen - 1}): the header is corrupt")
    if not 2 <= nch <= MAX_CHANNELS or rate_mhz == 0 or max_record > MAX_RECORD:
        raise StreamError(f"{where}: header holds invalid values (channels {nch}, rate {rate_mhz} mHz, max record {max_record})")
    pos = _FIXED.size
    chans = []
    for _ in range(nch):
        kind, cpu, zero = _CHANNEL.unpack_from(data, pos)
        if kind not in KIND_NAMES or not (math.isfinite(cpu) and cpu != 0):
            raise StreamError(f"{where}: header byte offset {pos}: invalid channel kind {kind} or scale {cpu}")
        chans.append(Channel(kind, cpu, zero))
        pos += _CHANNEL.size
    nlen = data[pos]
    name = data[pos + 1 : pos + 1 + nlen].decode("utf-8", "replace")
    pos += 1 + nlen
    if pos + 2 > hlen - 4:
        raise StreamError(f"{where}: header length {hlen}: the printer name runs past it")
    (mlen,) = struct.unpack_from("<H", data, pos)
    if pos + 2 + mlen > hlen - 4:
        raise StreamError(f"{where}: header length {hlen}: the metadata ({mlen} bytes) runs past it")
    meta_text = data[pos + 2 : pos + 2 + mlen].decode("utf-8", "replace")
    meta = dict(line.split("=", 1) for line in meta_text.splitlines() if "=" in line)
    return StreamHeader(fp, rate_mhz, tuple(chans), name, meta, max_record, flags, version)


# --------------------------------------------------------------------------- block codec


def zigzag(v: np.ndarray) -> np.ndarray:
    """int64 -> uint64: 0, -1, 1, -2, 2 ... -> 0, 1, 2, 3, 4 ..."""
    v = np.asarray(v, dtype=np.int64)
    return ((v << 1) ^ (v >> 63)).view(np.uint64)


def unzigzag(u: np.ndarray) -> np.ndarray:
    u = np.asarray(u, dtype=np.uint64)
    return ((u >> np.uint64(1)).view(np.int64)) ^ (-(u & np.uint64(1)).view(np.int64))


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        b = value & 0x7F
        value >>= 7
        if value:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _read_varint(buf: bytes, pos: int, end: int) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        if pos >= end or shift > 28:  # at most 5 bytes (32 bits)
            raise ValueError("bad varint")
        b = buf[pos]
        pos += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if not b & 0x80:
            return value, pos


def _zz1(v: int) -> int:
    return 2 * v if v >= 0 else -2 * v - 1


def _unzz1(u: int) -> int:
    return (u >> 1) ^ -(u & 1)


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


@njit
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


@njit
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


@njit
def _plan(x, a, b, use1, use2, order, width, v0, ored):
    """:func:`_sized` of rows a..b-1, their ors taken into ``ored`` ((2, C) int64)."""
    _ors(x, a, b, ored)
    return _sized(x, a, b, use1, use2, order, width, v0, ored)


@njit
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
    pos = 0
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
            if known == 2:
                size = _sized(x, a, b, use1, use2, order, width, v0, ored)
            elif known >= 0:
                size = _sized(x, a, b, use1, use2, order, width, v0, halves[known])
            else:
                size = _plan(x, a, b, use1, use2, order, width, v0, ored)
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


def event_value(kind: int, stored: int) -> float:
    """The natural value (degrees C, fan 0..255, laser mode) of a stored event value."""
    return stored / 10.0 if kind in _TENTHS else float(stored)


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
        self.last_e = None

    def __call__(self, counts: np.ndarray, first: int) -> Samples:
        h = self.h
        n = len(counts)
        t = (first + np.arange(n)) * 1000.0 / h.rate_mhz
        q = (counts[:, :-1] - self.zero) / self.cpu
        tool_ch = h.channels[-1]
        if h.tool_kind == "laser":  # the power fraction; an extruder's state is its rising count
            tool = counts[:, -1] / tool_ch.counts_per_unit
            e = np.zeros(n)
        else:
            e = counts[:, -1] / tool_ch.counts_per_unit
            prev = np.concatenate([[e[0] if self.last_e is None else self.last_e], e[:-1]])
            tool = (e > prev).astype(float)
            if n:
                self.last_e = e[-1]
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
