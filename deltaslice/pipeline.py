"""The stages chained: what the CLI commands call, and what other programs can call too.

Each function takes paths and options, runs the stages in order
(printer -> mesh or G-code -> Toolpath -> Trajectory -> file) and returns a short
text summary. The stages themselves live in their own modules.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from .errors import DeltasliceError
from .printer import Printer, load_printer
from .progress import stderr_progress

MESH_SUFFIXES = (".stl", ".obj", ".3mf", ".ply", ".off")
GCODE_SUFFIXES = (".gcode", ".gco", ".g", ".nc")


def _printer(printer) -> Printer:
    return printer if isinstance(printer, Printer) else load_printer(printer)


def load_toolpath(part, printer, *, scale=1.0, rotate=0.0, keep_position=False, progress=None, echo=None):
    """A Toolpath from a mesh (sliced here) or a G-code file (read), in the bed frame.

    part: path to .stl/.obj/.3mf or .gcode; printer: Printer or path.
    progress: callable(done, total) or None; echo: callable(str) for notes (repairs, skipped commands).
    """
    printer = _printer(printer)
    suffix = Path(part).suffix.lower()
    if suffix in GCODE_SUFFIXES:
        from .gcode import read_gcode

        toolpath = read_gcode(part, printer=printer, echo=echo)
    elif suffix in MESH_SUFFIXES:
        from .mesh import check_fits, load_mesh
        from .slicing import slice_mesh

        mesh = load_mesh(part, scale=scale, rotate_z=rotate, keep_position=keep_position)
        if echo is not None:
            for note in mesh.repairs:
                echo(f"mesh: {note}")
        check_fits(mesh, printer)
        toolpath = slice_mesh(mesh, printer, progress=progress)
    else:
        raise DeltasliceError(
            f"{part}: unknown part type {suffix or '(no extension)'!r}: expected a mesh "
            f"({', '.join(MESH_SUFFIXES)}) or G-code ({', '.join(GCODE_SUFFIXES)})"
        )
    return toolpath


def slice_to_gcode(part, printer, output, *, progress=False, echo=None, **mesh_options) -> str:
    """Slice a mesh and write G-code. Returns a summary line."""
    from .gcode import write_gcode

    printer = _printer(printer)
    t0 = time.perf_counter()
    toolpath = load_toolpath(part, printer, progress=stderr_progress(progress, "slicing layers"), echo=echo, **mesh_options)
    write_gcode(toolpath, output, printer)
    s = toolpath.summary()
    return (
        f"{output}: {s['layers']} layers, {s['moves']} moves, {s['filament_mm']:.1f} mm filament, "
        f"{time.perf_counter() - t0:.2f} s"
    )


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
    **mesh_options,
) -> str:
    """Slice (or read), plan and emit. Returns the end-of-run summary text."""
    from .emit import format_for, write_trajectory
    from .planning import plan
    from .planning.trajectory import LimitMonitor

    printer = _printer(printer)
    if output is None:
        output = str(Path(part).with_suffix(".csv").name)
    fmt = fmt or format_for(output)  # a wrong extension fails before any slicing
    t0 = time.perf_counter()
    toolpath = load_toolpath(part, printer, progress=stderr_progress(progress, "slicing layers"), echo=echo, **mesh_options)
    t_slice = time.perf_counter() - t0
    if fmt == "gcode":
        from .gcode import write_gcode

        write_gcode(toolpath, output, printer)
        s = toolpath.summary()
        return f"{output}: G-code, {s['layers']} layers, {s['moves']} moves (no trajectory planned for G-code output)"
    trajectory = plan(
        toolpath,
        printer,
        speed_limit=speed_limit,
        planner=planner,
        solver=solver,
        workers=workers or os.cpu_count() or 1,
        progress=stderr_progress(progress, "planning runs"),
    )
    t_plan = time.perf_counter() - t0 - t_slice
    monitor = LimitMonitor(printer, printer.planning.output_rate)
    size = write_trajectory(trajectory, printer, output, fmt=fmt, watch=monitor.watch)
    t_all = time.perf_counter() - t0
    return trajectory.summary_text(
        toolpath,
        printer,
        monitor,
        extra={
            "output": f"{output} ({fmt}, {size / 1024:.1f} KiB)",
            "wall time": f"slice {t_slice:.2f} s, plan {t_plan:.2f} s, total {t_all:.2f} s",
        },
    )


def workspace_report(printer, plot_path=None) -> str:
    """Workspace figures of a printer as text; writes a PNG plot."""
    import numpy as np

    from .kinematics.workspace import analyse, plot

    printer = _printer(printer)
    kin = printer.kinematics()
    cpu = printer.joint_array("counts_per_unit")
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
