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
    #: ((time_s, kind, value), ...): heater, fan and laser events (toolpath.EventKind), in order;
    #: a wait event holds the time base (the player resumes after the heater is ready).
    events: tuple = ()

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

    def summary_text(self, toolpath, printer, monitor: "LimitMonitor", extra=None) -> str:
        """End-of-run summary; ``monitor`` has watched the samples as they were written."""
        kinds = {}
        for p in self.pieces:
            kinds[p.kind] = kinds.get(p.kind, 0) + 1
        lines = [
            f"printer: {printer.name}",
            f"layers: {toolpath.n_layers}, moves: {len(toolpath)}, pieces: "
            + ", ".join(f"{v} {k}" for k, v in sorted(kinds.items())),
            f"planner: {self.planner}, speed limit: {self.speed_limit}",
            f"print time: {self.duration:.2f} s ({self.duration / 60:.1f} min)",
            "peak use of limits: " + ", ".join(f"{k} {v:.0f} %" for k, v in monitor.peak_percent().items()),
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


class LimitMonitor:
    """Watches Samples blocks as they stream past (to an emitter, or nowhere) and keeps, per
    joint, the peak ratio of velocity and acceleration to its limit (central differences at
    the output rate, across block edges too), the peak filament speed while extruding, and
    the samples beyond a joint limit. Memory: two samples, whatever the print's length."""

    def __init__(self, printer, rate: float):
        self.printer, self.rate = printer, float(rate)
        self.vmax = printer.joint_array("velocity_max")
        self.amax = printer.joint_array("acceleration_max")
        self.peak_v = np.zeros(printer.n_joints)
        self.peak_a = np.zeros(printer.n_joints)
        self.peak_filament = 0.0
        self.violating_samples = 0
        self.events = 0
        self._tail = None  # last two samples of the previous block: (q, e, tool)
        self._bad_before = False

    def watch(self, blocks):
        """Yield the blocks unchanged, observing each."""
        for block in blocks:
            self.observe(block)
            yield block

    def consume(self, blocks) -> "LimitMonitor":
        for block in blocks:
            self.observe(block)
        return self

    def observe(self, block: Samples) -> None:
        q, e, tool = block.q, block.e, block.tool
        if self._tail is not None:
            q = np.concatenate([self._tail[0], q])
            e = np.concatenate([self._tail[1], e])
            tool = np.concatenate([self._tail[2], tool])
        self._tail = (q[-2:], e[-2:], tool[-2:])
        if len(q) < 3:
            return
        # Interior samples only: each is judged once, with both neighbours known.
        rv = np.abs(q[2:] - q[:-2]) * (0.5 * self.rate) / self.vmax
        ra = np.abs(q[2:] - 2 * q[1:-1] + q[:-2]) * self.rate**2 / self.amax
        self.peak_v = np.maximum(self.peak_v, rv.max(axis=0))
        self.peak_a = np.maximum(self.peak_a, ra.max(axis=0))
        if not self.printer.is_laser:
            # The melt-flow limit applies while extruding; retracts move cold filament.
            ev = np.abs(e[2:] - e[:-2]) * (0.5 * self.rate) * (tool[1:-1] > 0)
            self.peak_filament = max(self.peak_filament, float(ev.max()) / self.printer.tool.max_filament_speed)
        bad = (rv.max(axis=1) > 1.0) | (ra.max(axis=1) > 1.0)
        self.violating_samples += int(bad.sum())
        starts = np.diff(np.concatenate([[self._bad_before], bad]).astype(np.int8)) == 1
        self.events += int(starts.sum())
        self._bad_before = bool(bad[-1])

    @property
    def worst(self) -> float:
        """Largest joint velocity or acceleration ratio seen."""
        return float(max(self.peak_v.max(initial=0), self.peak_a.max(initial=0)))

    def peak_percent(self) -> dict:
        peak = {}
        for j, joint in enumerate(self.printer.joints):
            peak[f"{joint.name} vel"] = 100 * float(self.peak_v[j])
            peak[f"{joint.name} acc"] = 100 * float(self.peak_a[j])
        if not self.printer.is_laser:
            peak["filament vel"] = 100 * self.peak_filament
        return peak
