"""Emit: turn planned samples into bytes (setpoints CSV or the binary stream) and back.

Everything here reads and writes open binary file objects; ``pipeline`` opens the paths.

* :func:`write_samples` writes any iterable of :class:`~deltaslice.samples.Samples`
  blocks (consecutive, uniform at ``rate`` from t = 0), block by block,
* :func:`write_trajectory` samples a planned ``Trajectory`` at its printer's output rate,
* :func:`read_output` reads a CSV or stream back as ``(metadata, Samples)``.

Output formats by file extension are in :mod:`deltaslice.formats`.
"""

from __future__ import annotations

from ..errors import DeltasliceError
from . import csv as csvfmt
from . import stream

STREAM_MAGIC = stream.MAGIC


_WRITERS = {"csv": csvfmt.write_csv, "stream": stream.write_stream}


def write_samples(blocks, printer, f, *, fmt: str, rate: float, metadata: dict | None = None) -> int:
    """Write consecutive Samples blocks for ``printer`` to the binary file ``f`` as ``fmt``
    ("csv" or "stream"). Returns bytes written."""
    try:
        writer = _WRITERS[fmt]
    except KeyError:
        raise DeltasliceError(f"cannot write samples as {fmt!r}: expected 'csv' or 'stream'") from None
    return writer(blocks, printer, f, rate=rate, metadata=metadata)


def write_trajectory(trajectory, f, fmt: str, watch=None) -> int:
    """Sample a planned trajectory at its printer's output rate and write it to ``f``.

    watch: optional callable wrapping the block iterator (e.g. ``LimitMonitor.watch``), so
    the samples are examined as they are written instead of being computed twice."""
    printer = trajectory.printer
    rate = printer.planning.output_rate
    metadata = dict(trajectory.metadata())
    metadata.setdefault("duration_s", f"{trajectory.duration:.6f}")
    blocks = trajectory.iter_samples(rate)
    if watch is not None:
        blocks = watch(blocks)
    return write_samples(blocks, printer, f, fmt=fmt, rate=rate, metadata=metadata)


def read_output(data: bytes, name: str = "<output>"):
    """(metadata dict, Samples) of a setpoints CSV or a binary stream (told apart by content)."""
    import io

    reader = stream.read_stream if data[: len(STREAM_MAGIC)] == STREAM_MAGIC else csvfmt.read_csv
    return reader(io.BytesIO(data), name)
