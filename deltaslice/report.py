"""Summaries for people: text built from the objects the stages return, in one place."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class CompileResult:
    """What a compile did: the toolpath's and the trajectory's figures, the limit use the
    monitor measured on the written samples, the output and the wall times (s)."""

    printer: str
    output: str
    fmt: str
    size_bytes: int
    layers: int
    moves: int
    pieces: dict
    planner: str
    speed_limit: str
    duration_s: float | None
    peak_percent: dict = field(default_factory=dict)
    active_fraction: float | None = None
    times: dict = field(default_factory=dict)




def compile_summary(r: CompileResult) -> str:
    """The end-of-run summary the CLI prints."""
    if r.fmt == "gcode":
        return f"{r.output}: G-code, {r.layers} layers, {r.moves} moves (no trajectory planned for G-code output)"
    lines = [
        f"printer: {r.printer}",
        f"layers: {r.layers}, moves: {r.moves}, pieces: " + ", ".join(f"{v} {k}" for k, v in sorted(r.pieces.items())),
        f"planner: {r.planner}, speed limit: {r.speed_limit}",
        f"print time: {r.duration_s:.2f} s ({r.duration_s / 60:.1f} min)",
        "peak use of limits: " + ", ".join(f"{k} {v:.0f} %" for k, v in r.peak_percent.items()),
        f"time with a limit active (joint, filament or feed cap): {100 * r.active_fraction:.1f} %",
        f"output: {r.output} ({r.fmt}, {r.size_bytes / 1024:.1f} KiB)",
        "wall time: " + ", ".join(f"{k} {v:.2f} s" for k, v in r.times.items()),
    ]
    return "\n".join(lines)


def slice_summary(output: str, summary: dict, seconds: float) -> str:
    """One line after ``deltaslice slice``; summary: ``Toolpath.summary()``."""
    return (
        f"{output}: {summary['layers']} layers, {summary['moves']} moves, {summary['filament_mm']:.1f} mm filament, "
        f"wall time {seconds:.2f} s"
    )


@dataclass(frozen=True)
class WorkspaceResult:
    """A printer's workspace figures (mm, litres); ``bed_reachable_percent`` by height (mm)."""

    printer: str
    family: str
    path: str
    z_range: tuple
    radius_max: float
    z_step: float
    reachable_litres: float
    cylinder: str
    cylinder_on_bed: str
    cube: str
    cube_on_bed: str
    bed_reachable_percent: dict
    condition_median: float
    condition_max: float
    singularity_limit: float
    resolution_mm: tuple
    plot: str | None  # the PNG written, None when none was asked for


def workspace_summary(r: WorkspaceResult) -> str:
    """What ``deltaslice workspace`` prints."""
    best, median, worst = r.resolution_mm
    cover = ", ".join(f"{v:.1f} % at z = {k} mm" for k, v in r.bed_reachable_percent.items())
    lines = [
        f"printer: {r.printer} ({r.family}, {r.path})",
        f"searched: z {r.z_range[0]:.0f}..{r.z_range[1]:.0f} mm, radius <= {r.radius_max:.0f} mm "
        f"(grid step {r.z_step:.2f} mm in z)",
        f"reachable volume: {r.reachable_litres:.2f} litres (within joint limits, tilt and singularity limit)",
        f"largest cylinder: {r.cylinder}",
        f"largest cylinder standing on the bed: {r.cylinder_on_bed}",
        f"largest cube: {r.cube}",
        f"largest cube standing on the bed: {r.cube_on_bed}",
        f"bed area reachable: {cover}",
        f"singularity margin (Jacobian condition number in the bed cylinder): median {r.condition_median:.2f}, "
        f"worst {r.condition_max:.2f} (limit {r.singularity_limit:g})",
        f"resolution (tool motion per actuator count, worst joint): best {best:.4f} mm, "
        f"median {median:.4f} mm, worst {worst:.4f} mm",
        f"plot: {r.plot or 'none'}",
    ]
    return "\n".join(lines)
