"""Emit: write a planned trajectory as setpoints CSV or a binary stream, and read either back.

* :func:`format_for` picks the format from the output file's extension,
* :func:`write_trajectory` takes the planner's ``Trajectory`` (``iter_samples(rate)``,
  ``metadata()``) and calls :func:`write_samples`,
* :func:`write_samples` writes any iterable of :class:`~deltaslice.samples.Samples`
  blocks (consecutive, uniform at ``rate`` from t = 0), block by block, atomically,
* :func:`read_output` reads a CSV or stream back as ``(metadata, Samples)``.
"""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import DeltasliceError, StreamError

FORMATS = ("csv", "stream", "gcode")
SUFFIXES = {
    ".csv": "csv",
    ".dsl": "stream",
    ".stream": "stream",
    ".gcode": "gcode",
    ".gco": "gcode",
    ".g": "gcode",
    ".nc": "gcode",
}
STREAM_MAGIC = b"\x89DSL\r\n\x1a\n"


def format_for(path) -> str:
    """"csv" | "stream" | "gcode" from the output file's extension."""
    suffix = Path(str(path)).suffix.lower()
    try:
        return SUFFIXES[suffix]
    except KeyError:
        raise DeltasliceError(
            f"{path}: cannot tell the output format from {suffix or '(no extension)'!r}: use .csv (setpoints), "
            ".dsl or .stream (binary stream), .gcode, or --format csv|stream|gcode"
        ) from None


def write_samples(blocks, printer, output, *, fmt: str, rate: float, metadata: dict | None = None, events=()) -> int:
    """Write consecutive Samples blocks to ``output`` as ``fmt`` ("csv" or "stream").

    events: ``(sample_index, kind, value)`` in order (kind a :class:`~deltaslice.toolpath.EventKind`;
    value in degrees C, fan 0..255 or laser mode): each takes effect before sample ``sample_index``.
    The file appears only when complete (temp file + rename). Returns bytes written."""
    if fmt == "csv":
        from .csv import write_csv

        return write_csv(blocks, printer, output, rate=rate, metadata=metadata, events=events)
    if fmt == "stream":
        from .stream import write_stream

        return write_stream(blocks, printer, output, rate=rate, metadata=metadata, events=events)
    raise DeltasliceError(f"cannot write samples as {fmt!r}: expected 'csv' or 'stream'")


def write_trajectory(trajectory, printer, output, fmt: str | None = None, watch=None) -> int:
    """Sample a planned trajectory at the printer's output rate and write it.

    watch: optional callable wrapping the block iterator (e.g. ``LimitMonitor.watch``), so
    the samples are examined as they are written instead of being computed twice."""
    fmt = fmt or format_for(output)
    rate = printer.planning.output_rate
    metadata = dict(trajectory.metadata()) if hasattr(trajectory, "metadata") else {}
    metadata.setdefault("duration_s", f"{trajectory.duration:.6f}")
    blocks = trajectory.iter_samples(rate)
    if watch is not None:
        blocks = watch(blocks)
    return write_samples(blocks, printer, output, fmt=fmt, rate=rate, metadata=metadata,
                         events=event_samples(getattr(trajectory, "events", ()), trajectory.duration, rate))


def event_samples(events, duration: float, rate: float) -> list[tuple[int, int, float]]:
    """Trajectory events ``(time_s, kind, value)`` -> ``(sample_index, kind, value)``: the first
    sample at or after the event's time (``iter_samples`` gives ``ceil(duration * rate) + 1`` samples)."""
    n_total = int(math.ceil(duration * rate - 1e-9)) + 1
    return [(min(max(int(math.ceil(t * rate - 1e-6)), 0), n_total), int(k), float(v)) for t, k, v in events]


def read_output(path):
    """(metadata dict, Samples) of a setpoints CSV or a binary stream (sniffed by content).

    The metadata's ``"events"`` entry (absent when there are none) is a tuple of
    ``(sample_index, kind, value)``: heater, fan and laser events, value in degrees C,
    fan 0..255 or laser mode 0/3/4."""
    try:
        with open(path, "rb") as f:
            head = f.read(len(STREAM_MAGIC))
    except OSError as exc:
        raise StreamError(f"{path}: cannot read: {exc}") from None
    if head == STREAM_MAGIC:
        from .stream import read_stream

        return read_stream(path)
    from .csv import read_csv

    return read_csv(path)
