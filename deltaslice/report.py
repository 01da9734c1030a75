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


def piece_counts(pieces) -> dict:
    """{kind: count} of a trajectory's pieces."""
    kinds: dict = {}
    for p in pieces:
        kinds[p.kind] = kinds.get(p.kind, 0) + 1
    return kinds


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
        f"{seconds:.2f} s"
    )
