"""The Trajectory: planned pieces end to end, sampled on demand.

Pieces (runs, travels, retracts) each start and end at rest and know their
duration and how to give joint positions, filament and tool state at any time
inside them. The trajectory stores only the pieces (grids and profiles, small),
and samples them block by block at the output rate, so a long print streams to
disk without holding its samples in memory.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..samples import Samples

BLOCK = 8192  # samples per block handed to emitters


@dataclass
class Trajectory:
    printer: object
    pieces: list
    planner: str = "toppra"
    speed_limit: str = "feed"
    e_start: float = 0.0
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        self.kin = self.printer.kinematics()
        self.durations = np.array([p.duration for p in self.pieces], dtype=float)
        self.starts = np.concatenate([[0.0], np.cumsum(self.durations)])
        self.e_offsets = self.e_start + np.concatenate([[0.0], np.cumsum([p.filament_total for p in self.pieces])])

    @property
    def duration(self) -> float:
        return float(self.starts[-1])

    def metadata(self) -> dict:
        return {"planner": self.planner, "speed_limit": self.speed_limit, "duration_s": f"{self.duration:.6f}"}

    def sample_at(self, t: np.ndarray) -> Samples:
        """Samples at absolute times t (s, sorted). Times past the end hold the last pose."""
        t = np.asarray(t, dtype=float)
        n = len(t)
        q = np.empty((n, self.kin.n_joints))
        e = np.empty(n)
        tool = np.zeros(n)
        k = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, len(self.pieces) - 1)
        bounds = np.flatnonzero(np.diff(k)) + 1
        for lo, hi in zip(np.concatenate([[0], bounds]), np.concatenate([bounds, [n]])):
            i = int(k[lo])
            piece = self.pieces[i]
            qq, de, tl = piece.sample(self.kin, t[lo:hi] - self.starts[i])
            q[lo:hi], e[lo:hi], tool[lo:hi] = qq, self.e_offsets[i] + de, tl
        return Samples(t, q, e, tool)

    def iter_samples(self, rate: float | None = None, block: int = BLOCK):
        """Blocks of Samples at ``rate`` Hz (default: the printer's output rate), from t = 0
        through the end (the last sample is at or after the end, holding the final pose)."""
        rate = rate or self.printer.planning.output_rate
        n_total = int(np.ceil(self.duration * rate - 1e-9)) + 1
        for i0 in range(0, n_total, block):
            idx = np.arange(i0, min(i0 + block, n_total))
            yield self.sample_at(idx / rate)

    def samples(self, rate: float | None = None) -> Samples:
        """All samples at once (tests and small parts; long prints should use iter_samples)."""
        return Samples.concatenate(list(self.iter_samples(rate)))

    @property
    def active_fraction(self) -> float:
        """Fraction of the duration with at least one limit active, from the planner's own
        solution (toppra stages at a velocity or acceleration bound; ruckig and retract
        profiles are bang-bang and always at a bound)."""
        return float(sum(p.active_time for p in self.pieces) / self.duration) if self.duration > 0 else 0.0

    def summary_text(self, toolpath, printer, extra=None) -> str:
        rate = printer.planning.output_rate
        util = utilisation_of(printer, self.samples(rate), rate)
        kinds = {}
        for p in self.pieces:
            kinds[p.kind] = kinds.get(p.kind, 0) + 1
        lines = [
            f"printer: {printer.name}",
            f"layers: {toolpath.n_layers}, moves: {len(toolpath)}, pieces: "
            + ", ".join(f"{v} {k}" for k, v in sorted(kinds.items())),
            f"planner: {self.planner}, speed limit: {self.speed_limit}",
            f"print time: {self.duration:.2f} s ({self.duration / 60:.1f} min)",
            "peak use of limits: " + ", ".join(f"{k} {v:.0f} %" for k, v in util["peak_percent"].items()),
            f"time with a limit active (joint, filament or feed cap): {100 * self.active_fraction:.1f} %",
        ]
        for k, v in (extra or {}).items():
            lines.append(f"{k}: {v}")
        return "\n".join(lines)


def finite_differences(samples: Samples, rate: float):
    """Joint velocity and acceleration by central differences at the output rate: (n,J) each."""
    q = samples.q
    v = np.gradient(q, 1.0 / rate, axis=0)
    a = np.zeros_like(q)
    if len(q) > 2:
        a[1:-1] = (q[2:] - 2 * q[1:-1] + q[:-2]) * rate * rate
    return v, a


def utilisation_of(printer, samples: Samples, rate: float, feed_cap=None, active_threshold=0.95) -> dict:
    """Peak percentage of each joint velocity/acceleration limit and the active fraction."""
    v, a = finite_differences(samples, rate)
    vmax = printer.joint_array("velocity_max")
    amax = printer.joint_array("acceleration_max")
    rv = np.abs(v) / vmax[None]
    ra = np.abs(a) / amax[None]
    peak = {}
    for j, joint in enumerate(printer.joints):
        peak[f"{joint.name} vel"] = 100 * float(rv[:, j].max(initial=0))
        peak[f"{joint.name} acc"] = 100 * float(ra[:, j].max(initial=0))
    ratios = [rv.max(axis=1), ra.max(axis=1)]
    if not printer.is_laser and len(samples) > 2:
        # The melt-flow limit applies while extruding; retracts move cold filament at retract speed.
        ev = np.abs(np.gradient(samples.e, 1.0 / rate)) * (samples.tool > 0)
        ratios.append(ev / printer.tool.max_filament_speed)
        peak["filament vel"] = 100 * float(ratios[-1].max(initial=0))
    if feed_cap is not None:
        p = printer.kinematics().forward(samples.q)
        speed = np.linalg.norm(np.gradient(p, 1.0 / rate, axis=0), axis=1)
        ratios.append(speed / feed_cap)
    active = np.max(np.stack(ratios), axis=0) >= active_threshold
    return {"peak_percent": peak, "active_fraction": float(active.mean()) if len(active) else 0.0}
