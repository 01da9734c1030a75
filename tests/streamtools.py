"""Helpers for stream tests: where each record of a stream file starts."""

from __future__ import annotations

import struct

from deltaslice.emit import stream


def record_offsets(data: bytes) -> list[tuple[int, int, int]]:
    """[(offset, length, type)] of every record after the header."""
    hlen = struct.unpack_from("<H", data, 10)[0]
    out, pos = [], hlen
    while pos < len(data):
        kind = data[pos]
        length = stream.END_LEN if kind == stream.REC_END else struct.unpack_from("<H", data, pos + 1)[0]
        out.append((pos, length, kind))
        pos += length
    return out


def block_sample_counts(data: bytes) -> list[int]:
    return [struct.unpack_from("<H", data, off + 3)[0] for off, _l, k in record_offsets(data) if k == stream.REC_BLOCK]
