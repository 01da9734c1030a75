"""Emit: turn planned samples into bytes (setpoints CSV or the binary stream) and back.

Everything here reads and writes open binary file objects; ``pipeline`` opens the paths.

* :func:`write_samples` writes any iterable of :class:`~deltaslice.samples.Samples`
  blocks (consecutive, uniform at ``rate`` from t = 0), block by block,
* :func:`write_trajectory` samples a planned ``Trajectory`` at its printer's output rate,
* :func:`read_output` reads a CSV or stream back as ``(metadata, Samples)``.

Output formats by file extension are in :mod:`deltaslice.formats`.
"""

from __future__ import annotations

import math
import numbers

from ..errors import DeltasliceError
from ..tolerances import COUNT_ROUNDOFF
from . import csv as csvfmt
from . import stream

STREAM_MAGIC = stream.MAGIC


_WRITERS = {"csv": csvfmt.write_csv, "stream": stream.write_stream}


def _is_trajectory(x) -> bool:
    return all(hasattr(x, a) for a in ("printer", "duration", "iter_samples", "metadata"))


def _checked_blocks(blocks, printer):
    """The blocks, each checked to be Samples with the printer's joint count (a file is labelled
    with the printer's name and fingerprint: samples for another machine must not carry them)."""
    from ..samples import Samples

    for i, samples in enumerate(blocks):
        if not isinstance(samples, Samples):
            raise DeltasliceError(f"write_samples: blocks: block {i} is a {type(samples).__name__}, expected Samples")
        if samples.n_joints != printer.n_joints:
            raise DeltasliceError(
                f"write_samples: blocks: block {i} has {samples.n_joints} joints, printer {printer.name} has "
                f"{printer.n_joints}: these samples were planned for another machine")
        yield samples


def _check_file(f, what):
    import io

    if not callable(getattr(f, "write", None)) or isinstance(f, io.TextIOBase):
        raise DeltasliceError(f"{what}: f: expected a file object open for writing in binary mode, "
                              f"got {type(f).__name__}")


def write_samples(blocks, printer, f, *, fmt: str, rate: float, metadata: dict | None = None, events=()) -> int:
    """Write consecutive Samples blocks for ``printer`` to the binary file ``f`` as ``fmt``
    ("csv" or "stream"). Returns bytes written.

    blocks: an iterable of Samples with ``printer``'s joint count, or a planned Trajectory, which
    must have been planned for ``printer`` (same fingerprint) and is sampled at ``rate``.
    events: ``(sample_index, kind, value)`` in order (kind a :class:`~deltaslice.toolpath.EventKind`;
    value in degrees C, fan 0..255 or laser mode): each takes effect before sample ``sample_index``."""
    from ..machine import Printer

    try:
        writer = _WRITERS[fmt]
    except (KeyError, TypeError):
        raise DeltasliceError(f"cannot write samples as {fmt!r}: expected 'csv' or 'stream'") from None
    if not isinstance(printer, Printer):
        raise DeltasliceError(f"write_samples: printer: expected a loaded Printer, got {type(printer).__name__}")
    _check_file(f, "write_samples")
    if isinstance(rate, bool) or not isinstance(rate, numbers.Real) or not math.isfinite(rate) or rate <= 0:
        raise DeltasliceError(f"write_samples: rate = {rate!r}: expected a sample rate > 0, Hz")
    if _is_trajectory(blocks):
        planned = blocks.printer
        if planned.fingerprint() != printer.fingerprint():
            raise DeltasliceError(
                f"write_samples: the trajectory was planned for {planned.name} (fingerprint 0x{planned.fingerprint():08x}), "
                f"not printer {printer.name} (0x{printer.fingerprint():08x})")
        blocks = blocks.iter_samples(rate)
    elif blocks is None or isinstance(blocks, (str, bytes)) or not hasattr(blocks, "__iter__"):
        raise DeltasliceError(f"write_samples: blocks: expected an iterable of Samples, got {type(blocks).__name__}")
    return writer(_checked_blocks(blocks, printer), printer, f, rate=rate, metadata=metadata, events=events)


def write_trajectory(trajectory, f, fmt: str, watch=None, workers: int = 1) -> int:
    """Sample a planned trajectory at its printer's output rate and write it to ``f``, a binary
    file object.

    watch: optional callable wrapping the block iterator (e.g. ``LimitMonitor.watch``), so
    the samples are examined as they are written instead of being computed twice; with workers,
    a block's arrays are written again once the next block is taken (``iter_samples``'
    ``transient``), so ``watch`` must copy what it keeps of a block.
    workers: processes sampling ahead of the writer (``Trajectory.iter_samples(rate, workers=)``;
    1: ``iter_samples(rate)``, in this process); the bytes are the same for any number."""
    if not _is_trajectory(trajectory):
        raise DeltasliceError(f"write_trajectory: trajectory: expected a planned Trajectory, got {type(trajectory).__name__}")
    _check_file(f, "write_trajectory")
    printer = trajectory.printer
    rate = printer.planning.output_rate
    metadata = dict(trajectory.metadata())
    metadata.setdefault("duration_s", f"{trajectory.duration:.6f}")
    # transient blocks: the writer and ``watch`` are done with each before they take the next (a
    # trajectory of another planner need only take the rate when sampled in this process)
    if workers > 1:
        blocks = trajectory.iter_samples(rate, workers=workers, transient=True)
    else:
        blocks = trajectory.iter_samples(rate)
    if watch is not None:
        blocks = watch(blocks)
    return write_samples(blocks, printer, f, fmt=fmt, rate=rate, metadata=metadata,
                         events=event_samples(getattr(trajectory, "events", ()), trajectory.duration, rate))


def event_samples(events, duration: float, rate: float) -> list[tuple[int, int, float]]:
    """Trajectory events ``(time_s, kind, value)`` -> ``(sample_index, kind, value)``: the first
    sample at or after the event's time (``iter_samples`` gives ``ceil(duration * rate) + 1`` samples)."""
    n_total = int(math.ceil(duration * rate - COUNT_ROUNDOFF)) + 1
    return [(min(max(int(math.ceil(t * rate - 1e-6)), 0), n_total), int(k), float(v)) for t, k, v in events]


def read_output(data: bytes, name: str = "<output>"):
    """(metadata dict, Samples) of a setpoints CSV or a binary stream (told apart by content).

    The metadata's ``"events"`` entry (absent when there are none) is a tuple of
    ``(sample_index, kind, value)``: heater, fan and laser events, value in degrees C,
    fan 0..255 or laser mode 0/3/4."""
    import io

    # a .dsl or a file with NUL bytes is a stream, whatever its first bytes: one with a damaged magic
    # number is reported as such, not as a CSV that is not UTF-8
    binary = data[: len(STREAM_MAGIC)] == STREAM_MAGIC or str(name).lower().endswith(".dsl") or b"\0" in data[:64]
    reader = stream.read_stream if binary else csvfmt.read_csv
    return reader(io.BytesIO(data), name)
