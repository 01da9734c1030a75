"""The stages chained: what the CLI commands call, and what other programs can call too.

This is the one module that opens paths: it reads the printer file, the part and the
outputs, hands each stage the previous stage's object, and writes every output
atomically (printer -> mesh or G-code -> Toolpath -> Trajectory -> samples -> bytes).
Functions return objects (:class:`~deltaslice.report.CompileResult`,
:class:`~deltaslice.verify.VerifyReport`); :mod:`deltaslice.report` turns them into text.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
import warnings
from pathlib import Path

from .errors import GcodeError, MeshWarning, PlanningError, StreamError
from .formats import format_for, part_kind
from .machine import LimitMonitor, Printer, load_printer
from .machine.limits import TOLERANCE
from .progress import stderr_progress
from .report import CompileResult, piece_counts, slice_summary


def _printer(printer) -> Printer:
    return printer if isinstance(printer, Printer) else load_printer(printer)


@contextlib.contextmanager
def atomic_output(path, mode: str = "wb", **open_kwargs):
    """Open a temporary file next to ``path``; on success it replaces ``path``. A failure
    anywhere while writing removes it and leaves any previous file untouched."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, mode, **open_kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def load_toolpath(part, printer, *, scale=1.0, rotate=0.0, keep_position=False, progress=None, echo=None, engrave=None):
    """A Toolpath from a mesh (sliced here), a G-code file (read) or, for a laser, an
    image or SVG (engraved: :mod:`deltaslice.engrave`), in the bed frame.

    part: path to a mesh, G-code, image or SVG file; printer: Printer or path.
    engrave: :class:`~deltaslice.engrave.EngraveOptions` or a dict of its fields (images only).
    progress: callable(done, total) or None; echo: callable(str) for notes (repairs, skipped commands).
    """
    printer = _printer(printer)
    kind = part_kind(part)
    if kind == "gcode":
        from .gcode import read_gcode

        return read_gcode(part, printer=printer, echo=echo)
    if kind == "image":
        from .engrave import engrave as engrave_image

        return engrave_image(part, printer, engrave)
    from .mesh import check_fits, load_mesh
    from .slicing import slice_mesh

    mesh = load_mesh(part, scale=scale, rotate_z=rotate, keep_position=keep_position)
    if echo is not None:
        for note in mesh.repairs:
            echo(f"mesh: {note}")
    check_fits(mesh, printer)
    with warnings.catch_warnings(record=True) as caught:  # the slicer's MeshWarnings become notes
        warnings.simplefilter("always", MeshWarning)
        toolpath = slice_mesh(mesh, printer.slicing, printer.tool, progress=progress, name=printer.name)
    for w in caught:
        if not issubclass(w.category, MeshWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        elif echo is not None:
            echo(f"mesh: {w.message}")
    return toolpath


def write_gcode(toolpath, output, printer=None) -> None:
    """Write a Toolpath as G-code to ``output``, atomically."""
    from .gcode import gcode_text

    text = gcode_text(toolpath, printer)
    try:
        with atomic_output(output, "w", encoding="ascii", newline="\n") as f:
            f.write(text)
    except OSError as exc:
        raise GcodeError(f"{output}: cannot write G-code: {exc}") from None


def slice_to_gcode(part, printer, output, *, progress=False, echo=None, **mesh_options) -> str:
    """Slice a mesh and write G-code. Returns a summary line."""
    printer = _printer(printer)
    t0 = time.perf_counter()
    toolpath = load_toolpath(part, printer, progress=stderr_progress(progress, "slicing layers"), echo=echo, **mesh_options)
    write_gcode(toolpath, output, printer)
    return slice_summary(str(output), toolpath.summary(), time.perf_counter() - t0)


def write_output(trajectory, output, fmt: str | None = None, watch=None, check=None) -> int:
    """Write a planned trajectory to ``output`` (format from the extension unless given),
    atomically. Returns bytes written. check: called after the last byte and before the file
    replaces ``output``; an exception from it leaves any previous output untouched."""
    from .emit import write_trajectory

    fmt = fmt or format_for(output)
    with atomic_output(output, "wb") as f:
        size = write_trajectory(trajectory, f, fmt, watch=watch)
        if check is not None:
            check()
        return size


def write_samples(blocks, printer, output, *, fmt: str, rate: float, metadata: dict | None = None) -> int:
    """Write Samples blocks for ``printer`` to ``output`` as ``fmt``, atomically. Returns bytes written."""
    from .emit import write_samples as encode

    with atomic_output(output, "wb") as f:
        return encode(blocks, printer, f, fmt=fmt, rate=rate, metadata=metadata)


def read_counts(path):
    """(StreamHeader, counts (n, C) int64) of a stream file."""
    from .emit.stream import read_counts as decode

    try:
        f = open(path, "rb")
    except OSError as exc:
        raise StreamError(f"{path}: cannot open stream: {exc}") from None
    with f:
        return decode(f, str(path))


def read_output(path):
    """(metadata, Samples) of a written setpoints CSV or binary stream."""
    from .emit import read_output as decode

    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise StreamError(f"{path}: cannot read: {exc}") from None
    return decode(data, str(path))


def compile_part(
    part,
    printer,
    *,
    output=None,
    fmt=None,
    speed_limit="feed",
    planner="toppra",
    workers=None,
    progress=False,
    echo=None,
    **mesh_options,
) -> CompileResult:
    """Slice (or read), plan and emit. Returns what was done (see :mod:`deltaslice.report`)."""
    from .planning import plan

    printer = _printer(printer)
    if output is None:
        output = str(Path(part).with_suffix(".csv").name)
    fmt = fmt or format_for(output)  # a wrong extension fails before any slicing
    t0 = time.perf_counter()
    toolpath = load_toolpath(part, printer, progress=stderr_progress(progress, "slicing layers"), echo=echo, **mesh_options)
    t_slice = time.perf_counter() - t0
    s = toolpath.summary()
    if fmt == "gcode":  # G-code is a toolpath output: nothing to plan
        write_gcode(toolpath, output, printer)
        return CompileResult(printer.name, str(output), fmt, Path(output).stat().st_size, s["layers"], s["moves"], {},
                             "", speed_limit, None, times={"slice": t_slice, "total": time.perf_counter() - t0})
    trajectory = plan(
        toolpath,
        printer,
        speed_limit=speed_limit,
        planner=planner,
        workers=workers or os.cpu_count() or 1,
        progress=stderr_progress(progress, "planning runs"),
    )
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

    size = write_output(trajectory, output, fmt=fmt, watch=monitor.watch, check=within_limits)
    return CompileResult(
        printer=printer.name, output=str(output), fmt=fmt, size_bytes=size, layers=s["layers"], moves=s["moves"],
        pieces=piece_counts(trajectory.pieces), planner=trajectory.planner, speed_limit=speed_limit,
        duration_s=trajectory.duration, peak_percent=monitor.peak_percent(), active_fraction=trajectory.active_fraction,
        times={"slice": t_slice, "plan": t_plan, "total": time.perf_counter() - t0},
    )


def verify_output(output, printer, toolpath=None, **mesh_options):
    """Read a setpoints CSV or binary stream and check it against the printer (path or Printer).

    toolpath: the part (mesh) or G-code that was compiled, to check path deviation.
    Returns a :class:`~deltaslice.verify.VerifyReport`."""
    from .verify import verify_samples

    printer = _printer(printer)
    meta, samples = read_output(output)
    fmt = meta.get("format", "csv")
    try:
        rate = float(meta.get("rate_hz", printer.planning.output_rate))
    except ValueError:
        raise StreamError(f"{output}: rate_hz {meta.get('rate_hz')!r} is not a number") from None
    tp = None if toolpath is None else load_toolpath(toolpath, printer, **mesh_options)
    return verify_samples(samples, printer, rate=rate, fmt=fmt, meta=meta, toolpath=tp, output=str(output))


def decode_stream(path, out, *, units=False, printer=None) -> int:
    """Print a stream file's samples to the text file ``out`` (see ``emit.stream.decode_to_text``);
    printer: a path or Printer the stream must match, or None."""
    from .emit.stream import decode_to_text

    loaded = None if printer is None else _printer(printer)
    try:
        f = open(path, "rb")
    except OSError as exc:
        raise StreamError(f"{path}: cannot open stream: {exc}") from None
    with f:
        return decode_to_text(f, out, units=units, printer=loaded, name=str(path))


def workspace_report(printer, plot_path=None) -> str:
    """Workspace figures of a printer as text; writes a PNG plot."""
    import numpy as np

    from .kinematics.workspace import analyse, plot

    printer = _printer(printer)
    kin = printer.kinematics()
    cpu = np.abs(printer.limits.counts_per_unit[: printer.n_joints])
    z_range = (-0.25 * printer.bed.max_height - 10.0, 2.0 * printer.bed.max_height + 20.0)
    radius_max = max(1.6 * printer.bed.radius, 50.0)
    rep = analyse(kin, cpu, z_range, radius_max)
    plot_path = plot_path or f"{printer.name}_workspace.png"
    plot(kin, rep, cpu, plot_path, title=f"{printer.name}: workspace")

    xy = np.linspace(-1, 1, 41)
    X, Y = np.meshgrid(xy, xy)
    if printer.bed.shape == "circle":
        pts = np.stack([X.ravel(), Y.ravel()], 1) * printer.bed.radius
        pts = pts[np.hypot(pts[:, 0], pts[:, 1]) <= printer.bed.radius]
    else:
        pts = np.stack([X.ravel() * printer.bed.size_x / 2, Y.ravel() * printer.bed.size_y / 2], 1)
    bed_cover = []
    for z in (0.0, printer.bed.max_height):
        ok = kin.reachable(np.column_stack([pts, np.full(len(pts), z)]))
        bed_cover.append(f"{100 * ok.mean():.1f} % at z = {z:g} mm")

    lines = [
        f"printer: {printer.name} ({printer.family}, {printer.path})",
        f"searched: z {z_range[0]:.0f}..{z_range[1]:.0f} mm, radius <= {radius_max:.0f} mm "
        f"(grid step {rep.z[1] - rep.z[0]:.2f} mm in z)",
        f"reachable volume: {rep.reachable_volume / 1e6:.2f} litres (within joint limits, tilt and singularity limit)",
        f"largest cylinder: {rep.cylinder.describe()}",
        f"largest cylinder standing on the bed: {rep.cylinder_on_bed.describe()}",
        f"largest cube: {rep.cube.describe()}",
        f"largest cube standing on the bed: {rep.cube_on_bed.describe()}",
        f"bed area reachable: {', '.join(bed_cover)}",
        f"singularity margin (Jacobian condition number in the bed cylinder): median {rep.condition_median:.2f}, "
        f"worst {rep.condition_max:.2f} (limit {printer.planning.singularity_limit:g})",
        f"resolution (tool motion per actuator count, worst joint): best {rep.resolution_min:.4f} mm, "
        f"median {rep.resolution_median:.4f} mm, worst {rep.resolution_max:.4f} mm",
        f"plot: {plot_path}",
    ]
    return "\n".join(lines)
