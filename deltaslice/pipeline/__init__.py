"""The stages chained: what the CLI commands call, and what other programs can call too.

This package is the one layer that opens paths: it reads the printer file, the part and the
outputs, hands each stage the previous stage's object, and writes every output atomically
(:mod:`.outputs`): printer -> mesh or G-code -> Toolpath -> Trajectory -> samples -> bytes.
Functions return objects (:class:`~deltaslice.report.CompileResult`,
:class:`~deltaslice.verify.VerifyReport`); :mod:`deltaslice.report` turns them into text.
"""

from __future__ import annotations

import contextlib
import os
import time
import warnings
from pathlib import Path

import numpy as np

from .. import interrupt
from ..errors import DeltasliceError, MeshWarning, OutputError, PlanningError, StreamError, ToolpathWarning
from ..formats import format_for, holds_samples, is_stdout, part_kind
from ..machine import LimitMonitor, Printer, check_reach, load_printer
from ..machine.limits import TOLERANCE
from ..pool import check_workers, resolve_workers
from ..progress import stderr_progress
from ..report import CompileResult, slice_summary
from .outputs import _check_path, _printer_file, atomic_output, check_bounds, check_job, check_output


def _printer(printer, reach_checks: bool = True) -> Printer:
    """A Printer as given, or loaded from a path or a shipped printer's name; with its reach
    checks done (:func:`~deltaslice.machine.check_reach`) unless ``reach_checks`` is False."""
    if not isinstance(printer, Printer):
        printer = load_printer(printer, reach_checks=reach_checks)
    return check_reach(printer) if reach_checks else printer


# G-code files larger than this are read a stretch at a time and planned as they are read
# (gcode.open_gcode, planning.plan_stream): memory bounded by a stretch, not by the print.
STREAM_BYTES = 8 * 1024**2

# Bounds on a job before it is written (overridable: compile_part(max_duration_s=None, max_bytes=None),
# CLI --max-time/--max-size 0). A G-code with F0.0001 plans to days of samples; these stop it first.
MAX_DURATION_S = 48 * 3600.0
MAX_BYTES = 4 * 1024**3


def load_toolpath(part, printer, *, scale=1.0, rotate=0.0, keep_position=False, progress=None, echo=None, engrave=None,
                  center=False, workers=1, while_slicing=None):
    """A Toolpath from a mesh (sliced here), a G-code file (read) or, for a laser, an
    image or SVG (engraved: :mod:`deltaslice.engrave`), in the bed frame.

    part: path to a mesh, G-code, image or SVG file; printer: Printer or path.
    engrave: :class:`~deltaslice.engrave.EngraveOptions` or a dict of its fields (images only).
    progress: callable(done, total) or None; echo: callable(str) for notes (repairs, skipped commands).
    center: move a G-code part's footprint to the bed centre (meshes are centred unless keep_position).
    workers: processes slicing a mesh's layers (the toolpath is the same for any number).
    while_slicing: a callable run in this process while the workers slice a mesh's first layers
    (:func:`~deltaslice.slicing.slice_mesh`'s ``started``), or first thing for other parts. A mesh
    is checked to fit the printer's reach at the same point, so a Printer read with
    ``reach_checks=False`` is not checked here for it (the process loads numba only there; the
    caller checks it, as compile_part does in ``while_slicing``); a path is read with its checks.
    """
    kind = part_kind(part)
    printer = _printer(printer, reach_checks=kind != "mesh" or not isinstance(printer, Printer))
    if kind != "mesh" and while_slicing is not None:
        while_slicing()
    if kind == "gcode":
        from ..gcode import read_gcode

        return read_gcode(part, printer=printer, echo=echo, center=center, progress=progress)
    if kind == "image":
        from ..engrave import engrave as engrave_image

        return engrave_image(part, printer, engrave)
    from ..mesh import check_fits, load_mesh
    from ..slicing import slice_mesh

    mesh = load_mesh(part, scale=scale, rotate_z=rotate, keep_position=keep_position)
    if echo is not None:
        for note in mesh.repairs:
            echo(f"mesh: {note}")

    def started():
        if while_slicing is not None:
            while_slicing()
        check_fits(mesh, printer)  # a refusal names the placement itself (and stops the workers)
        if echo is not None and mesh.placement:  # where the part went, in its own units (inches, off-centre)
            echo(f"mesh: {mesh.placement}")

    with warnings.catch_warnings(record=True) as caught:  # the slicer's MeshWarnings become notes
        warnings.simplefilter("always", MeshWarning)
        toolpath = slice_mesh(mesh, printer.slicing, printer.tool, progress=progress, name=printer.name, workers=workers,
                              started=started)
    for w in caught:
        if not issubclass(w.category, MeshWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        elif echo is not None:
            echo(f"mesh: {w.message}")
    _check_on_bed(toolpath, printer, part)
    return toolpath


def _check_on_bed(toolpath, printer, part) -> None:
    """Every working move (skirt included) on the bed: a part kept near the edge
    (--keep-position) can fit while its skirt does not."""
    from ..errors import UnreachableError

    work = toolpath.tool > 0
    if not work.any():
        return
    pts = toolpath.xyz[work, :2]
    off = ~printer.bed.contains_xy(pts)
    if off.any():
        r = np.hypot(pts[off, 0], pts[off, 1])
        i = int(np.argmax(r))
        x, y = pts[off][i]
        raise UnreachableError(
            f"{part}: {int(off.sum())} printing moves leave the bed (the farthest at x = {x:.1f}, y = {y:.1f} mm, "
            f"{r[i]:.1f} mm from the centre; bed radius {printer.bed.radius:g} mm, skirt included): move the part "
            "inwards or drop --keep-position"
        )


def write_gcode(toolpath, output, printer=None, *, max_bytes=MAX_BYTES) -> int:
    """Write a Toolpath as G-code to ``output``, atomically. Returns bytes written."""
    from ..gcode import gcode_text

    _check_toolpath(toolpath)
    text = gcode_text(toolpath, printer)
    with atomic_output(output, "w", encoding="ascii", newline="\n", max_bytes=max_bytes) as f:
        f.write(text)
    return len(text)  # ASCII: a byte a character


def write_firmware_config(printer, output=None) -> str:
    """The firmware players' configuration header of ``printer`` (path, name or Printer); written
    atomically to ``output`` when given. Returns the header text."""
    from ..emit.firmware_config import firmware_config

    if output is not None:
        check_output(output, inputs=[_printer_file(printer)])
    printer = _printer(printer)
    text = firmware_config(printer)
    if output is not None:
        with atomic_output(output, "w", encoding="ascii", newline="\n") as f:
            f.write(text)
    return text


def slice_to_gcode(part, printer, output, *, progress=False, echo=None, workers=None, **mesh_options) -> str:
    """Slice a mesh and write G-code (workers: slicing processes, default all cores; the G-code is
    the same for any number). Returns a summary line."""
    _check_path(part, "part")
    check_output(output, inputs=[part, _printer_file(printer)])
    printer = _printer(printer)
    t0 = time.perf_counter()
    toolpath = load_toolpath(part, printer, progress=stderr_progress(progress, "slicing layers"), echo=echo,
                             workers=resolve_workers(workers, "slice_to_gcode"), **mesh_options)
    interrupt.check()
    write_gcode(toolpath, output, printer)
    return slice_summary(str(output), toolpath.summary(), time.perf_counter() - t0)




def _check_toolpath(toolpath):
    from ..toolpath import Toolpath

    if not isinstance(toolpath, Toolpath):
        raise DeltasliceError(f"toolpath: expected a Toolpath, got {type(toolpath).__name__}")


def _bytes_per_sample(fmt, n_channels):
    """A generous estimate of an output's bytes per sample, for the size bound."""
    return 12.0 * (n_channels + 1) if fmt == "csv" else 1.0 * n_channels


def write_output(trajectory, output, fmt: str | None = None, watch=None, *, max_duration_s=MAX_DURATION_S,
                 max_bytes=MAX_BYTES, check=None, workers: int = 1) -> int:
    """Write a planned trajectory to ``output`` (format from the extension unless given),
    atomically. Refuses a job beyond ``max_duration_s`` or ``max_bytes`` (None: no bound)
    before writing. check: called after the last byte and before the file replaces
    ``output``; an exception from it leaves any previous output untouched. workers: processes
    sampling ahead of the writer (the bytes are the same for any number). Returns bytes written."""
    from ..emit import write_trajectory

    if not all(hasattr(trajectory, a) for a in ("printer", "duration", "iter_samples", "metadata")) or not isinstance(
            getattr(trajectory, "printer", None), Printer):
        raise DeltasliceError(f"trajectory: expected a planned Trajectory, got {type(trajectory).__name__}")
    check_workers(workers, "write_output")
    fmt = fmt or format_for(output)
    if fmt not in ("csv", "stream"):
        raise DeltasliceError(f"{output}: a trajectory is written as csv or stream, not {fmt!r}")
    printer = trajectory.printer
    check_output(output)
    check_job(trajectory.duration, printer.planning.output_rate, _bytes_per_sample(fmt, printer.n_joints + 1),
              max_duration_s=max_duration_s, max_bytes=max_bytes, output=str(output))
    with atomic_output(output, "wb", max_bytes=max_bytes) as f:
        size = write_trajectory(trajectory, f, fmt, watch=watch, workers=workers)
        if check is not None:
            check()
        return size


def write_samples(blocks, printer, output, *, fmt: str, rate: float, metadata: dict | None = None,
                  max_bytes=MAX_BYTES, events=()) -> int:
    """Write Samples blocks (or a Trajectory planned for ``printer``) for ``printer`` to ``output``
    as ``fmt``, atomically. Returns bytes written. Blocks with another joint count, or a trajectory
    planned for another printer, are refused (see ``emit.write_samples``).
    events: ``(sample_index, kind, value)`` (see ``emit.write_samples``)."""
    from ..emit import write_samples as encode

    printer = _printer(printer)
    with atomic_output(output, "wb", max_bytes=max_bytes) as f:
        return encode(blocks, printer, f, fmt=fmt, rate=rate, metadata=metadata, events=events)


def read_counts(path):
    """(StreamHeader, counts (n, C) int64) of a stream file."""
    from ..emit.stream import read_counts as decode

    try:
        f = open(path, "rb")
    except OSError as exc:
        raise StreamError(f"{path}: cannot open stream: {exc}") from None
    with f:
        return decode(f, str(path))


def read_output(path):
    """(metadata, Samples) of a written setpoints CSV or binary stream."""
    from ..emit import read_output as decode

    _check_path(path, "read_output: path")
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise StreamError(f"{path}: cannot read: {exc}") from None
    return decode(data, str(path))


def default_output(part) -> Path:
    """``PART.dsl`` beside the part: the compact binary stream (a CSV is ~80 bytes a sample)."""
    return Path(part).with_suffix(".dsl")


def compile_part(
    part,
    printer,
    *,
    output=None,
    fmt=None,
    speed_limit="feed",
    planner="toppra",
    solver="fast",
    workers=None,
    progress=False,
    echo=None,
    max_duration_s=MAX_DURATION_S,
    max_bytes=MAX_BYTES,
    **mesh_options,
) -> CompileResult:
    """Slice (or read), plan and emit. Returns what was done (see :mod:`deltaslice.report`).

    output: path (default ``PART.dsl`` beside the part); checked before any work (not the
    input, directory exists and is writable). max_duration_s, max_bytes: bounds on the
    planned print time and the output size checked before writing (None: no bound)."""
    _check_path(part, "part")
    check_bounds(max_duration_s, max_bytes)
    if output is None:
        output = default_output(part)
    fmt = fmt or format_for(output)  # a wrong extension fails before any slicing
    check_output(output, inputs=[part, _printer_file(printer)])
    workers = resolve_workers(workers, "compile_part")
    kind = part_kind(part)
    # A mesh's printer is checked (check_reach: numba's first load) while the slicing workers start
    printer = _printer(printer, reach_checks=kind != "mesh")
    checked = [printer]

    def while_slicing():
        checked[0] = check_reach(printer)
        # the planner's modules load here, while the workers slice, not before they fork
        from .. import planning as _planner  # noqa: F401

    t0 = time.perf_counter()
    stage = ("reading G-code", "lines") if kind == "gcode" else ("slicing layers", "it")
    reading = stderr_progress(progress, stage[0], unit=stage[1])
    planning = stderr_progress(progress, "planning", unit="moves")
    stream = _gcode_stream(part, printer, fmt, planner, mesh_options, reading, echo)
    if stream is not None and stream.streamed:
        from ..planning import plan_stream

        t_slice = time.perf_counter() - t0
        s = {"layers": stream.layers, "moves": stream.moves}
        with stream:
            trajectory = plan_stream(stream.chunks(), printer, moves=stream.moves, speed_limit=speed_limit,
                                     workers=workers, progress=planning, solver=solver)
    else:
        if stream is not None:
            with stream:
                toolpath = stream.whole()
        else:
            toolpath = load_toolpath(part, printer, progress=reading, echo=echo, workers=workers,
                                     while_slicing=while_slicing, **mesh_options)
            printer = checked[0]
        interrupt.check()
        t_slice = time.perf_counter() - t0
        s = toolpath.summary()
        if fmt == "gcode":  # G-code is a toolpath output: nothing to plan
            size = write_gcode(toolpath, output, printer, max_bytes=max_bytes)  # a pipe (-o -) has no size to stat
            return CompileResult(printer.name, str(output), fmt, size, s["layers"], s["moves"], {},
                                 "", speed_limit, None, times={"slice": t_slice, "total": time.perf_counter() - t0})
        from ..planning import plan

        with warnings.catch_warnings(record=True) as caught:  # the unit notes, said as notes
            warnings.simplefilter("always", ToolpathWarning)
            trajectory = plan(toolpath, printer, speed_limit=speed_limit, planner=planner, solver=solver, workers=workers,
                              progress=planning)
        for w in caught:
            if not issubclass(w.category, ToolpathWarning):
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            elif echo is not None:
                echo(f"note: {w.message}")
        del toolpath
    interrupt.check()
    t_plan = time.perf_counter() - t0 - t_slice
    monitor = LimitMonitor(printer.limits, printer.tool, printer.planning.output_rate)

    def within_limits():
        beyond = monitor.beyond()
        if beyond:
            raise PlanningError(
                f"{output}: not written: the planned motion goes beyond the limits of {printer.name} "
                f"({', '.join(beyond)}; {100 * TOLERANCE:g} % allowed for sampling); this is a planner defect, "
                "please report it with the part and printer file"
            )

    watch = _watch_progress(monitor.watch, progress, trajectory.duration)
    size = write_output(trajectory, output, fmt=fmt, watch=watch, max_duration_s=max_duration_s, max_bytes=max_bytes,
                        check=within_limits, workers=workers)
    return CompileResult(
        printer=printer.name, output=str(output), fmt=fmt, size_bytes=size, layers=s["layers"], moves=s["moves"],
        pieces=trajectory.piece_counts(), planner=trajectory.planner, speed_limit=speed_limit,
        duration_s=trajectory.duration, peak_percent=monitor.peak_percent(), active_fraction=trajectory.active_fraction,
        times={"slice": t_slice, "plan": t_plan, "total": time.perf_counter() - t0},
    )


def _gcode_stream(part, printer, fmt, planner, options, progress, echo):
    """A G-code of more than STREAM_BYTES read to be planned as it is read (gcode.open_gcode), or
    None: a mesh, an image, a smaller file, a G-code output, or the trapezoid planner (which takes
    the whole toolpath). A centred file (the footprint of every move) is then taken whole from the
    stream (see gcode.GcodeStream)."""
    if part_kind(part) != "gcode" or fmt == "gcode" or planner != "toppra":
        return None
    from .. import gcode  # here: a mesh's compile imports no G-code reader before its slicing forks

    try:
        if os.path.getsize(part) <= STREAM_BYTES:
            return None
    except OSError:
        return None  # the reader names the problem
    return gcode.open_gcode(part, printer=printer, echo=echo, center=bool(options.get("center", False)),
                            progress=progress)


def _watch_progress(watch, progress, duration):
    """Compose the limit monitor with a 'writing' progress bar over the trajectory's time."""
    bar = stderr_progress(progress, "writing output", unit="s")
    if bar is None:
        return watch

    def watched(blocks):
        for block in watch(blocks):
            interrupt.check()
            if len(block):
                bar(min(float(block.t[-1]), duration), duration)
            yield block
        bar(duration, duration)

    return watched


def verify_output(output, printer, toolpath=None, *, assume_printer=False, **mesh_options):
    """Read a setpoints CSV or binary stream and check it against the printer (path, name or Printer).

    toolpath: the part (mesh) or G-code that was compiled, to check path deviation; give the
    placement options (scale, rotate, keep_position) the compile had. assume_printer: check a file
    that does not say which printer it was made for (a CSV without its ``#`` header) as made for
    ``printer`` (refused otherwise); the report says the printer was assumed.
    Returns a :class:`~deltaslice.verify.VerifyReport`."""
    from ..verify import verify_samples

    _check_path(output, "output")
    printer = _printer(printer)
    _check_verify_memory(output, printer)
    meta, samples = read_output(output)
    fmt = meta.get("format", "csv")
    raw = meta.get("rate_hz", printer.planning.output_rate)
    try:
        rate = float(raw)
    except (TypeError, ValueError):
        raise StreamError(f"{output}: rate_hz {raw!r} is not a number") from None
    tp = None if toolpath is None else load_toolpath(toolpath, printer, **mesh_options)
    return verify_samples(samples, printer, rate=rate, fmt=fmt, meta=meta, toolpath=tp, output=str(output),
                          assume_printer=assume_printer)


# verify holds every sample at once: about this many bytes per sample and channel (+3 for time,
# tool and filament), measured at its peak (928 MB for a 6.67-million-sample delta_etitc stream)
VERIFY_BYTES_PER_VALUE = 20


def _check_verify_memory(output, printer) -> None:
    """Refuse, before reading it, an output whose samples would not fit the memory this process
    may use: a 1 MB stream of resting blocks holds 33 million samples (4.6 GB to verify)."""
    from ..emit import stream as dsl

    channels = printer.n_joints + 1
    try:
        size = os.path.getsize(output)
        with open(output, "rb") as f:
            head = f.read(len(dsl.MAGIC))
            if head == dsl.MAGIC:
                # at most MAX_BLOCK_SAMPLES per block of at least 5 + 2C + 4 bytes; the end record says how many
                samples = size * dsl.MAX_BLOCK_SAMPLES // (5 + 2 * channels + 4)
                f.seek(max(0, size - dsl.END_LEN))
                tail = f.read(dsl.END_LEN)
                if len(tail) == dsl.END_LEN and tail[0] == dsl.REC_END:
                    samples = min(samples, int.from_bytes(tail[3:7], "little"))
            else:  # a CSV: one sample a line, counted a megabyte at a time
                f.seek(0)
                samples = sum(chunk.count(b"\n") for chunk in iter(lambda: f.read(1 << 20), b""))
    except OSError:
        return  # the reader names the problem
    need = samples * VERIFY_BYTES_PER_VALUE * (channels + 3)
    budget = _memory_budget()
    if budget is not None and need > budget:
        rate = printer.planning.output_rate
        raise StreamError(
            f"{output}: its {samples / 1e6:.3g} million samples ({samples / rate / 3600:.3g} h at {rate:g} Hz) need about "
            f"{need / 1e9:.3g} GB to verify at once, more than the {budget / 1e9:.3g} GB this process can use"
        )


def _memory_budget() -> int | None:
    """Bytes this process can still take: the memory the system has available, within the
    process's own address-space and data limits; None where that cannot be told."""
    budget = None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    budget = int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource

        with open("/proc/self/statm") as f:
            used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
        for limit in (resource.RLIMIT_AS, resource.RLIMIT_DATA):
            soft = resource.getrlimit(limit)[0]
            if soft != resource.RLIM_INFINITY:
                budget = min(budget if budget is not None else soft, max(0, soft - used))
    except (ImportError, OSError, ValueError, IndexError):
        pass
    return budget


def decode_stream(path, out, *, units=False, printer=None) -> int:
    """Print a stream file's samples to the text file ``out`` (see ``emit.stream.decode_to_text``);
    printer: a path, name or Printer the stream must match, or None."""
    from ..emit.stream import decode_to_text

    _check_path(path, "stream")
    if not callable(getattr(out, "write", None)):
        raise DeltasliceError(f"decode_stream: out = {out!r:.60}: expected a text file object (with write)")
    if not isinstance(units, bool):
        raise DeltasliceError(f"decode_stream: units = {units!r}: expected True or False")
    loaded = None if printer is None else _printer(printer)
    try:
        f = open(path, "rb")
    except OSError as exc:
        raise StreamError(f"{path}: cannot open stream: {exc.strerror or exc}") from None
    with f:
        return decode_to_text(f, out, units=units, printer=loaded, name=str(path))


def send_file(stream_path, port_name, *, baud=115200, timeout=10.0, progress=False, printer=None, wait_limit=None,
              commands=None):
    """Check a stream file whole, then send it to the board on ``port_name`` (see :mod:`deltaslice.send`).
    printer: a path, name or Printer whose fingerprint the stream must carry, or None.
    wait_limit: the longest heating wait the sender sits through, s (None: the printer's
    ``[safety] wait_timeout`` plus a minute, or :data:`~deltaslice.send.WAIT_LIMIT`).
    commands: pause/resume/abort as :func:`~deltaslice.send.send_stream` takes them.
    Returns a :class:`~deltaslice.send.SendResult`."""
    import io

    from ..emit.stream import decode_to_text
    from ..errors import SendError
    from ..send import WAIT_LIMIT, send_stream

    _check_path(stream_path, "stream")
    try:
        data = open(stream_path, "rb").read()
    except OSError as exc:
        raise StreamError(f"{stream_path}: cannot open stream: {exc.strerror or exc}") from None
    # a damaged file is refused before the port is opened: the board would stop mid-print
    printer = None if printer is None else _printer(printer)
    decode_to_text(io.BytesIO(data), io.StringIO(), printer=printer, name=str(stream_path))
    # the board's own wait limit is the printer file's: the sender waits a minute longer
    if wait_limit is None:
        wait_limit = WAIT_LIMIT if printer is None else printer.safety.wait_timeout + 60.0
    try:
        import serial
    except ImportError:
        raise SendError("deltaslice send needs pyserial (pip install pyserial)") from None
    try:
        # a device, or a URL pyserial opens (socket://host:port: a board behind a TCP bridge, or QEMU's UART)
        port = serial.serial_for_url(str(port_name), baudrate=int(baud), timeout=0.2)
    except (serial.SerialException, ValueError, OSError) as exc:
        raise SendError(f"{port_name}: cannot open the serial port: {exc}") from None
    with port:
        try:
            return send_stream(data, port, timeout=timeout, name=str(stream_path), wait_limit=wait_limit,
                               commands=commands, progress=stderr_progress(progress, "sending", unit="B"))
        except (serial.SerialException, OSError) as exc:  # unplugged, or the far end closed
            raise SendError(f"{port_name}: the link to the board failed: {exc}") from None


def play_file(stream_path, bus_port, *, baud=1_000_000, ids=None, protocol=1, laser_port=None, release=False,
              min_interval=0.0, printer=None, keyboard=False, progress=False):
    """Check a stream file whole, then play it in real time on the Dynamixel bus at ``bus_port``
    and the laser board at ``laser_port`` (see :mod:`deltaslice.play`). ids: the servos' bus IDs
    in joint order (default 1, 2, 3, ...). printer: a path, name or Printer the stream must match,
    or None. keyboard: pause/resume/abort from the terminal's keys. Returns a
    :class:`~deltaslice.play.PlayResult`."""
    from ..emit.stream import StreamReader
    from ..errors import PlayError
    from ..machine.tool import tool_class
    from ..play import Keys, open_bus, open_laser, play

    _check_path(stream_path, "stream")
    try:
        f = open(stream_path, "rb")
    except OSError as exc:
        raise StreamError(f"{stream_path}: cannot open stream: {exc.strerror or exc}") from None
    with f:
        # a damaged file is refused before a port is opened: the machine would stop mid-job
        reader = StreamReader(f, str(stream_path))
        parts = [c for _i, _s, c in reader.blocks()]
    h = reader.header
    if printer is not None:
        loaded = _printer(printer)
        if loaded.fingerprint() != h.fingerprint:
            raise StreamError(f"{stream_path}: stream compiled for printer {h.printer_name!r}, not {loaded.name!r}")
    if laser_port is not None and not tool_class(h.tool_kind).takes_laser_power:
        raise PlayError(f"{stream_path}: --laser given, but the stream's tool is {h.tool_kind!r}, not a laser")
    counts = np.concatenate(parts) if parts else np.zeros((0, h.n_channels), dtype=np.int64)
    ids = list(range(1, h.n_joints + 1)) if ids is None else list(ids)
    bus = open_bus(bus_port, baud)
    laser = None
    try:
        laser = open_laser(laser_port) if laser_port is not None else None
        with Keys() if keyboard else contextlib.nullcontext() as keys:
            return play(counts, reader.events, rate=h.rate, n_joints=h.n_joints, bus_port=bus, baud=baud, ids=ids,
                        protocol=protocol, laser_port=laser, laser_name=str(laser_port), release=release,
                        min_interval=min_interval, keys=keys, name=str(stream_path),
                        progress=stderr_progress(progress, "playing", unit="samples"))
    finally:
        bus.closePort()
        if laser is not None:
            laser.close()


def shipped_printers() -> list[dict]:
    """The printers packaged with deltaslice: [{name, family, tool, description, path}]."""
    from ..printers import shipped_names, shipped_path

    rows = []
    for name in shipped_names():
        p = load_printer(shipped_path(name))
        rows.append({"name": name, "family": p.family, "tool": p.tool.channel_kind, "description": p.description,
                     "path": str(p.path)})
    return rows


def _check_png(path, inputs=()) -> None:
    _check_path(path, "plot")
    if Path(path).suffix.lower() != ".png" and not is_stdout(path):
        raise OutputError(f"{path}: expected a .png file name (or - for standard output)")
    check_output(path, inputs)


def preview(part, printer, output, *, layer=None, **mesh_options) -> str:
    """Draw ``part`` to the PNG ``output``: a mesh or G-code as one layer coloured by role with
    its travels, plus a side view; a compiled .csv/.dsl as joint position, speed and
    acceleration against the printer's limits over time, and the tool speed. Returns a line."""
    from .. import preview as draw

    _check_path(part, "part")
    _check_png(output, inputs=[part, _printer_file(printer)])
    if layer is not None and (isinstance(layer, bool) or not isinstance(layer, (int, np.integer))):
        raise DeltasliceError(f"preview: layer = {layer!r}: expected a layer index (an integer) or None")
    if not Path(part).exists():
        raise DeltasliceError(f"{part}: no such file")
    printer = _printer(printer)
    if holds_samples(part):
        meta, samples = read_output(part)
        fig = draw.trajectory_figure(samples, printer, title=f"{Path(part).name} on {printer.name}",
                                     tool_state=meta.get("format", "csv") != "stream")
        what = f"{len(samples)} samples"
    else:
        toolpath = load_toolpath(part, printer, **mesh_options)
        fig, shown = draw.toolpath_figure(toolpath, printer, layer=layer, title=f"{Path(part).name} on {printer.name}")
        what = f"layer {shown} of {toolpath.n_layers}"
    interrupt.check()
    with atomic_output(output, "wb") as f:
        draw.save(fig, f)
    return f"{output}: {what}"


def workspace_analysis(printer, plot_path=None, *, draw=True):
    """Workspace figures of a printer (:class:`~deltaslice.report.WorkspaceResult`); writes a PNG
    plot to plot_path (default ``<printer name>_workspace.png``), none with ``draw=False`` and no
    plot_path (the result's ``plot`` is then None)."""
    import numpy as np

    from ..kinematics.workspace import analyse, plot
    from ..report import WorkspaceResult

    printer = _printer(printer)
    draw = draw or plot_path is not None
    plot_path = (plot_path or f"{printer.name}_workspace.png") if draw else None
    if draw:
        _check_png(plot_path, inputs=[printer.path])
    kin = printer.kinematics()
    cpu = np.abs(printer.limits.counts_per_unit[: printer.n_joints])
    z_range = (-0.25 * printer.bed.max_height - 10.0, 2.0 * printer.bed.max_height + 20.0)
    radius_max = max(1.6 * printer.bed.radius, 50.0)
    rep = analyse(kin, cpu, z_range, radius_max)
    interrupt.check()
    if draw:
        with atomic_output(plot_path, "wb") as f:
            plot(kin, rep, cpu, f, title=f"{printer.name}: workspace")

    xy = np.linspace(-1, 1, 41)
    X, Y = np.meshgrid(xy, xy)
    if printer.bed.shape == "circle":
        pts = np.stack([X.ravel(), Y.ravel()], 1) * printer.bed.radius
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= printer.bed.radius]
    else:
        pts = np.stack([X.ravel() * printer.bed.size_x / 2, Y.ravel() * printer.bed.size_y / 2], 1)
    bed_cover = {}
    for z in (0.0, printer.bed.max_height):
        ok = kin.reachable(np.column_stack([pts, np.full(len(pts), z)]))
        bed_cover[f"{z:g}"] = float(100 * ok.mean())
    return WorkspaceResult(
        printer=printer.name, family=printer.family, path=str(printer.path),
        z_range=(float(z_range[0]), float(z_range[1])), radius_max=float(radius_max), z_step=float(rep.z[1] - rep.z[0]),
        reachable_litres=float(rep.reachable_volume / 1e6), cylinder=rep.cylinder.describe(),
        cylinder_on_bed=rep.cylinder_on_bed.describe(), cube=rep.cube.describe(), cube_on_bed=rep.cube_on_bed.describe(),
        bed_reachable_percent=bed_cover, condition_median=float(rep.condition_median),
        condition_max=float(rep.condition_max), singularity_limit=float(printer.planning.singularity_limit),
        resolution_mm=(float(rep.resolution_min), float(rep.resolution_median), float(rep.resolution_max)),
        plot=None if plot_path is None else str(plot_path),
    )


def workspace_report(printer, plot_path=None) -> str:
    """Workspace figures of a printer as text; writes a PNG plot."""
    from ..report import workspace_summary

    return workspace_summary(workspace_analysis(printer, plot_path))
