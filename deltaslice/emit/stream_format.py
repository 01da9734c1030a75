"""The binary stream's format (``docs/stream-format.md``): record types and sizes, channel kinds,
the header (:class:`StreamHeader`, :func:`parse_header`), the varints and zig-zag of the block
codec, event values. The encoder is :mod:`.stream`, the decoder :mod:`.stream_read`."""

from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from ..errors import StreamError
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


def event_value(kind: int, stored: int) -> float:
    """The natural value (degrees C, fan 0..255, laser mode) of a stored event value."""
    return stored / 10.0 if kind in _TENTHS else float(stored)
