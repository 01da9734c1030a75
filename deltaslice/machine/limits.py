"""Limits: the one owner of every channel's position, velocity, acceleration and jerk
limits and of its actuator counts, and the one place they are checked.

Channels are the machine's joints in order, then its tool channel (filament position
for an extruder, power fraction for a laser). Units are joint units (rad for revolute
joints, mm for prismatic ones, mm of filament, power fraction) per s, s^2, s^3.

The planner's constraints (``limits.scaled(1 - margin)``), the compile's
:class:`LimitMonitor` and ``verify`` all read these arrays and use the difference
functions below, so a limit means the same thing everywhere.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

from ..jit import njit

KINDS = ("revolute", "prismatic", "extruder", "laser")

#: How far above a limit a sampled output may go before the compile fails and verify says FAIL
#: (finite differences of samples see discretisation that the continuous motion does not have).
TOLERANCE = 0.02
#: The difference window of a sampled check is the shortest that keeps quantisation noise below
#: this share of the limit (:func:`velocity_window`, :func:`acceleration_window`).
NOISE_FRACTION = 0.05
JERK_SPACING = 5e-3  # s: jerk is read (verify) and held (the planner) over third differences this far apart
UNITS = {"revolute": "rad", "prismatic": "mm", "extruder": "mm", "laser": "0..1"}


@dataclass(frozen=True)
class ChannelLimits:
    """One channel's limits (a view of :class:`Limits`; joint units)."""

    name: str
    kind: str
    position_min: float
    position_max: float
    velocity_max: float
    acceleration_max: float
    jerk_max: float | None
    counts_per_unit: float
    zero_count: float

    @property
    def unit(self) -> str:
        return UNITS[self.kind]


@dataclass(frozen=True, eq=False)
class Limits:
    """Per-channel limits, (C,) float arrays, C = joints + 1 (the tool channel last).

    ``velocity`` is the limit while working (an extruder's melt-flow limit);
    ``idle_velocity`` applies while the tool is off (an extruder's retract speed).
    ``jerk`` is NaN where the file gives none. Counts: ``count = zero_count + counts_per_unit * value``."""

    names: tuple[str, ...]
    kinds: tuple[str, ...]
    position_min: np.ndarray
    position_max: np.ndarray
    velocity: np.ndarray
    idle_velocity: np.ndarray
    acceleration: np.ndarray
    jerk: np.ndarray
    counts_per_unit: np.ndarray
    zero_count: np.ndarray

    def __post_init__(self):
        n = len(self.names)
        for f in fields(self):
            if f.name in ("names", "kinds"):
                continue
            arr = np.array(getattr(self, f.name), dtype=float).reshape(-1)
            if len(arr) != n:
                raise ValueError(f"Limits.{f.name}: expected {n} values, got {len(arr)}")
            arr.setflags(write=False)
            object.__setattr__(self, f.name, arr)

    def __eq__(self, other):
        return isinstance(other, Limits) and self.names == other.names and self.kinds == other.kinds and all(
            np.array_equal(getattr(self, f.name), getattr(other, f.name), equal_nan=True)
            for f in fields(self) if f.name not in ("names", "kinds"))

    __hash__ = None

    @property
    def n_channels(self) -> int:
        return len(self.names)

    @property
    def n_joints(self) -> int:
        return len(self.names) - 1

    @property
    def tool_kind(self) -> str:
        return self.kinds[-1]

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(UNITS[k] for k in self.kinds)

    def scaled(self, factor: float) -> "Limits":
        """The same limits with every rate limit (velocity, acceleration, jerk) times ``factor``:
        ``limits.scaled(1 - margin)`` is what the planner plans to."""
        return replace(
            self,
            velocity=self.velocity * factor,
            idle_velocity=self.idle_velocity * factor,
            acceleration=self.acceleration * factor,
            jerk=self.jerk * factor,
        )

    def channel(self, i: int) -> ChannelLimits:
        jerk = float(self.jerk[i])
        return ChannelLimits(
            self.names[i], self.kinds[i], float(self.position_min[i]), float(self.position_max[i]),
            float(self.velocity[i]), float(self.acceleration[i]), None if math.isnan(jerk) else jerk,
            float(self.counts_per_unit[i]), float(self.zero_count[i]),
        )

    @property
    def joints(self) -> tuple[ChannelLimits, ...]:
        return tuple(self.channel(i) for i in range(self.n_joints))

    # -- checking sampled outputs (verify, previews) ---------------------------------------
    def tool_velocity_limits(self) -> tuple[float, float]:
        """(working, idle) velocity limit of the tool channel: an extruder's melt-flow speed
        while extruding, its retract speed while the tool is off (infinite for a laser)."""
        T = self.n_joints
        return float(self.velocity[T]), float(self.idle_velocity[T])

    def sampled_tool_velocity(self, tool_state, resolution: float, rate: float,
                              noise_fraction: float = NOISE_FRACTION) -> tuple[float, np.ndarray | None]:
        """The tool channel's velocity limit for differences of samples at ``rate`` Hz.

        Returns (the limit that sets the window, a per-window limit array or None). Without the
        tool state (``tool_state`` None: a stream carries none) every window is held to the larger
        of the working and idle limits. With it ((n,) values, on when > 0), a window of the working
        limit's size is held to the working limit when the tool is on throughout it, else to the
        larger of the two."""
        working, idle = self.tool_velocity_limits()
        either = max(working, idle)
        if tool_state is None:
            return either, None
        wv, _ = velocity_window(working, resolution, rate, noise_fraction)
        on = np.asarray(tool_state) > 0
        if len(on) <= wv:
            return working, None
        c = np.concatenate([[0], np.cumsum(on)])
        on_throughout = (c[wv + 1:] - c[: -wv - 1]) == wv + 1
        return working, np.where(on_throughout, working, either)

    def sampled_check(self, i: int, resolution: float, rate: float, noise_fraction: float = NOISE_FRACTION,
                      velocity: float | None = None, tolerance: float = TOLERANCE) -> "SampledCheck":
        """How channel ``i`` sampled at ``rate`` Hz with ``resolution`` (channel units) is held
        to its limits: difference windows, their quantisation noise, the thresholds with
        ``tolerance`` and the noise added. velocity: the velocity limit to use instead of the
        channel's (the tool channel's, from :meth:`sampled_tool_velocity`)."""
        vmax = float(self.velocity[i]) if velocity is None else float(velocity)
        amax = float(self.acceleration[i])
        wv, nv = velocity_window(vmax, resolution, rate, noise_fraction)
        wa, na = acceleration_window(amax, resolution, rate, noise_fraction)
        return SampledCheck(vmax, amax, wv, nv, wa, na, tolerance)

    def to_counts(self, values: np.ndarray) -> np.ndarray:
        """values: (n, C) float, channel units (or one row (C,)) -> (n, C) int64 actuator counts
        (rounded)."""
        values = np.atleast_2d(np.asarray(values, dtype=float))
        return self.joint_and_channel_counts(values[:, :-1], values[:, -1])

    def joint_and_channel_counts(self, q: np.ndarray, channel: np.ndarray, with_peak: bool = False):
        """:meth:`to_counts` of the joints q (n, J) and the tool channel (n,) given apart (a
        sample block's arrays, not copied into one): (n, J + 1) int64, zero + cpu * value rounded
        half to even, in one compiled pass (the stream writer's per-block call). with_peak: also
        the largest magnitude of zero + cpu * value before rounding (NaN if any is not finite),
        from the same pass: returns (counts, peak)."""
        q, channel = np.asarray(q, dtype=float), np.asarray(channel, dtype=float)
        C = len(self.counts_per_unit)
        if q.ndim != 2 or q.shape[1] != C - 1 or channel.shape != (len(q),):
            raise ValueError(f"Limits counts: joints {q.shape} and tool channel {channel.shape}: expected "
                             f"(n, {C - 1}) and (n,) for {C} channels")
        out = np.empty((len(q), C), dtype=np.int64)
        peak = _counts_kernel(q, channel, self.counts_per_unit, self.zero_count, out)
        return (out, float(peak)) if with_peak else out

    def from_counts(self, counts: np.ndarray) -> np.ndarray:
        """counts: (n, C) -> (n, C) float, channel units."""
        return (np.asarray(counts, dtype=float) - self.zero_count[None]) / self.counts_per_unit[None]

    def ratios(self, v: np.ndarray, a: np.ndarray, working: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and acceleration as fractions of their limits.

        v, a: (n, k) float for the first k channels; working: (n,) bool, the tool on (the
        working velocity limit applies) — default: working everywhere. Returns (n, k) each."""
        k = v.shape[1]
        vlim = np.broadcast_to(self.velocity[:k], v.shape)
        if working is not None:
            vlim = np.where(np.asarray(working, bool)[:, None], vlim, self.idle_velocity[None, :k])
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.abs(v) / vlim, np.abs(a) / self.acceleration[None, :k]


@dataclass(frozen=True)
class SampledCheck:
    """One channel's check on sampled values (from :meth:`Limits.sampled_check`): velocities over
    ``velocity_window`` samples, accelerations over twice ``acceleration_window``, each held to its
    limit plus ``tolerance`` plus the window's quantisation noise bound."""

    velocity_limit: float
    acceleration_limit: float
    velocity_window: int
    velocity_noise: float
    acceleration_window: int
    acceleration_noise: float
    tolerance: float = TOLERANCE

    def velocity_threshold(self, limit=None):
        """The velocity above which a window fails: the limit (or ``limit``, a per-window array)
        with the tolerance, plus the noise bound."""
        base = self.velocity_limit if limit is None else limit
        return base * (1 + self.tolerance) + self.velocity_noise

    def acceleration_threshold(self) -> float:
        return self.acceleration_limit * (1 + self.tolerance) + self.acceleration_noise


# --------------------------------------------------------------------------- differences


def third_differences(x: np.ndarray, rate: float, spacing: float = JERK_SPACING) -> np.ndarray:
    """Jerk by third differences of samples ``spacing`` s apart (the nearest whole number of
    samples, at least one): x (n,) or (n, k) at ``rate`` Hz -> (n - 3 w, ...), w the samples apart.
    Over 5 ms a motion whose acceleration changes no faster than J on average over every 5 ms
    reads at most J; an acceleration step of A reads 0.75 A / spacing."""
    w = max(1, int(round(spacing * rate)))
    x = np.asarray(x, dtype=float)
    if len(x) <= 3 * w:
        return x[:0]
    return (x[3 * w:] - 3 * x[2 * w:-w] + 3 * x[w:-2 * w] - x[:-3 * w]) * (rate / w) ** 3


def central_differences(x: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity and acceleration of the interior samples by central differences.

    x: (n, k) float sampled at ``rate`` Hz -> (v, a), each (n - 2, k), at samples 1..n-2."""
    v = (x[2:] - x[:-2]) * (0.5 * rate)
    a = (x[2:] - 2 * x[1:-1] + x[:-2]) * (rate * rate)
    return v, a


def velocity_window(limit: float, resolution: float, rate: float, noise_fraction: float) -> tuple[int, float]:
    """Samples per velocity window so that quantisation (``resolution / h``, h the window in s)
    stays below ``noise_fraction`` of ``limit``; returns (window, noise bound)."""
    if not math.isfinite(limit):
        return 1, 0.0
    w = max(1, math.ceil(rate * resolution / (noise_fraction * limit)))
    return w, resolution / (w / rate)


def acceleration_window(limit: float, resolution: float, rate: float, noise_fraction: float) -> tuple[int, float]:
    """As :func:`velocity_window` for accelerations (noise ``2 resolution / h^2``)."""
    if not math.isfinite(limit):
        return 1, 0.0
    w = max(1, math.ceil(rate * math.sqrt(2 * resolution / (noise_fraction * limit))))
    return w, 2 * resolution / (w / rate) ** 2


def windowed_differences(x: np.ndarray, t: np.ndarray, wv: int, wa: int) -> tuple[np.ndarray, np.ndarray]:
    """Velocity over ``wv`` samples (at i + wv/2) and acceleration over 2 ``wa`` samples (at i + wa).

    x, t: (n,) float -> (v (n - wv,), a (n - 2 wa,))."""
    n = len(x)
    v = (x[wv:] - x[:-wv]) / (t[wv:] - t[:-wv]) if n > wv else np.zeros(0)
    if n > 2 * wa:
        va = (x[wa:] - x[:-wa]) / (t[wa:] - t[:-wa])  # velocity at the middle of [i, i + wa]
        a = (va[wa:] - va[:-wa]) / (0.5 * (t[2 * wa:] - t[: -2 * wa]))
    else:
        a = np.zeros(0)
    return v, a


# --------------------------------------------------------------------------- the monitor


class LimitMonitor:
    """Watches Samples blocks as they stream past (to an emitter, or nowhere) and keeps, per
    channel, the peak ratio of velocity and acceleration to its limit (central differences
    at the output rate, across block edges too) and the samples beyond a joint limit. The
    tool channel's velocity counts only while the tool works (an extruder's melt-flow limit;
    retracts move cold filament). Memory: two samples, whatever the print's length."""

    def __init__(self, limits: Limits, tool, rate: float):
        self.limits, self.tool, self.rate = limits, tool, float(rate)
        J = limits.n_joints
        self.peak_v = np.zeros(J)
        self.peak_a = np.zeros(J)
        self.peak_tool_v = 0.0
        self.violating_samples = 0
        self.events = 0
        self._tail = None  # last two samples of the previous block: (q, channel, tool)
        self._bad_before = False

    def watch(self, blocks):
        """Yield the blocks unchanged, observing each in a second thread while the caller uses it
        (the compiled pass holds no GIL: beside a writer's compiled passes, which hold none either,
        the monitor costs the writing process no time; it was a quarter of it). Each block is
        observed before the next is taken (a writer's blocks may be views of buffers refilled
        then), in order, so the results are those of observing them here one by one."""
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(1, thread_name_prefix="deltaslice-monitor") as thread:
            for block in blocks:
                seen = thread.submit(self.observe, block)
                try:
                    yield block
                finally:
                    seen.result()

    def consume(self, blocks) -> "LimitMonitor":
        for block in blocks:
            self.observe(block)
        return self

    def observe(self, block) -> None:
        q, c, tool = block.q, self.tool.channel_values(block.e, block.tool), block.tool
        if self._tail is not None:
            if len(q) < 3:
                q, c, tool = (np.concatenate([a, b]) for a, b in zip(self._tail, (q, c, tool)))
            else:
                # the interior samples at the seam (the tail's last and the block's first), then
                # the block's own: the same samples in the same order as the two joined, without
                # copying the block
                seam = [np.concatenate([a, b[:2]]) for a, b in zip(self._tail, (q, c, tool))]
                if len(seam[0]) >= 3:
                    self._observe(*seam)
        self._tail = (q[-2:].copy(), c[-2:].copy(), tool[-2:].copy())
        if len(q) >= 3:
            self._observe(q, c, tool)

    def _observe(self, q, c, tool) -> None:
        """Judge the interior samples of q (n >= 3, J), c, tool (n,): each once, with both
        neighbours known."""
        J = self.limits.n_joints
        tool_v, bad, events, last_bad = _observe_kernel(
            np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(c, dtype=float),
            np.ascontiguousarray(tool, dtype=float), self.rate, np.ascontiguousarray(self.limits.velocity[:J]),
            np.ascontiguousarray(self.limits.acceleration[:J]), self.peak_v, self.peak_a, self._bad_before)
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = float(np.float64(tool_v) / self.limits.velocity[-1])
        if not math.isfinite(ratio):  # numpy's nan_to_num is slow on a scalar: only where needed
            ratio = float(np.nan_to_num(ratio))
        self.peak_tool_v = max(self.peak_tool_v, ratio)
        self.violating_samples += int(bad)
        self.events += int(events)
        self._bad_before = bool(last_bad)

    @property
    def worst(self) -> float:
        """Largest joint velocity or acceleration ratio seen."""
        return float(max(self.peak_v.max(initial=0), self.peak_a.max(initial=0)))

    def beyond(self, tolerance: float = TOLERANCE) -> list[str]:
        """The channels whose peak went beyond ``1 + tolerance`` times their limit, as
        ``"<name> acc 103.1 %"`` (empty when the output is within every limit)."""
        return [f"{k} {v:.1f} %" for k, v in self.peak_percent().items() if v > 100 * (1 + tolerance)]

    def peak_percent(self) -> dict:
        """{"<channel> vel": %, "<channel> acc": %} for every joint, and the tool channel's
        velocity where it has a limit."""
        peak = {}
        for j in range(self.limits.n_joints):
            peak[f"{self.limits.names[j]} vel"] = 100 * float(self.peak_v[j])
            peak[f"{self.limits.names[j]} acc"] = 100 * float(self.peak_a[j])
        if math.isfinite(self.limits.velocity[-1]):
            peak[f"{self.limits.names[-1]} vel"] = 100 * self.peak_tool_v
        return peak


@njit(nogil=True)  # the writer's: runs beside the monitor's thread (LimitMonitor.watch)
def _counts_kernel(q, channel, cpu, zero, out):
    """out[k, c] = rint(cpu[c] * value + zero[c]) for the joints' values q[k, c] and, in the last
    column, channel[k]: numpy's ``np.rint(cpu * values + zero)`` (half to even), to int64.
    Returns the largest |cpu[c] * value + zero[c]|, NaN if any is not finite (v - v is 0 for a
    finite v, NaN otherwise: summed, no branch in the loop)."""
    J = q.shape[1]
    peak = 0.0
    finite = 0.0
    for k in range(q.shape[0]):
        for c in range(J):
            v = cpu[c] * q[k, c] + zero[c]
            out[k, c] = np.int64(np.rint(v))
            finite += v - v
            peak = max(peak, abs(v))
        v = cpu[J] * channel[k] + zero[J]
        out[k, J] = np.int64(np.rint(v))
        finite += v - v
        peak = max(peak, abs(v))
    return peak + finite


@njit(inline="always")  # one caller: typed in it, no module of its own on a first run
def _row_ratios(q, i, half, rate2, vlim, alim):
    """The largest velocity and acceleration ratio to vlim, alim (J,) among the joints at interior
    sample i + 1 of q (n, J), by central differences (each NaN if any joint's is, as numpy's
    max)."""
    row_v = -np.inf
    row_a = -np.inf
    for j in range(q.shape[1]):
        rv = abs((q[i + 2, j] - q[i, j]) * half) / vlim[j]
        ra = abs(((q[i + 2, j] - 2 * q[i + 1, j]) + q[i, j]) * rate2) / alim[j]
        if rv > row_v or rv != rv:
            row_v = rv if row_v == row_v else row_v
        if ra > row_a or ra != ra:
            row_a = ra if row_a == row_a else row_a
    return row_v, row_a


@njit(nogil=True)  # in LimitMonitor.watch's thread, beside the writer's kernels
def _observe_kernel(q, c, tool, rate, vlim, alim, peak_v, peak_a, bad_before):
    """:meth:`LimitMonitor.observe` over one block in one pass (it was ten numpy passes over
    the block's arrays, the emit stage's second largest cost). q (n, J), c, tool (n,); peak_v,
    peak_a (J,) updated in place (NaN propagates, as numpy's max). Central differences at each
    interior sample, as :func:`central_differences`: the joints' ratios to vlim, alim (J,); the
    tool channel's speed where the tool works. A sample is bad when the largest ratio of its row
    (NaN if any is NaN, as numpy's) exceeds 1. Returns (largest tool channel speed, bad samples,
    bad stretches that start here, whether the last sample is bad).

    Without a division a sample: a peak is the largest difference scaled once at the end (the
    scaling, a product and a quotient by positive numbers, is monotonic in floating point too),
    and a row's ratios are computed (:func:`_row_ratios`) only where a product by the reciprocal
    limit, within a few ulps of the ratio, comes within 0.1 % of 1 (or is NaN)."""
    n, J = q.shape
    half = 0.5 * rate
    rate2 = rate * rate
    cv = np.empty(J)
    ca = np.empty(J)
    dv_max = np.zeros(J)
    da_max = np.zeros(J)
    for j in range(J):
        cv[j] = half / vlim[j]
        ca[j] = rate2 / alim[j]
    tool_v = -np.inf
    bad_count = 0
    events = 0
    prev = bad_before
    for i in range(n - 2):
        near = False
        for j in range(J):
            dv = abs(q[i + 2, j] - q[i, j])
            da = abs((q[i + 2, j] - 2 * q[i + 1, j]) + q[i, j])
            if dv > dv_max[j] or dv != dv:
                dv_max[j] = dv if dv_max[j] == dv_max[j] else dv_max[j]
            if da > da_max[j] or da != da:
                da_max[j] = da if da_max[j] == da_max[j] else da_max[j]
            near = near or not (dv * cv[j] <= 0.999 and da * ca[j] <= 0.999)
        tv = abs(c[i + 2] - c[i]) * half * (1.0 if tool[i + 1] > 0 else 0.0)
        if tv > tool_v or tv != tv:
            tool_v = tv if tool_v == tool_v else tool_v
        bad = False
        if near:
            row_v, row_a = _row_ratios(q, i, half, rate2, vlim, alim)
            bad = row_v > 1.0 or row_a > 1.0
        if bad:
            bad_count += 1
            if not prev:
                events += 1
        prev = bad
    if n > 2:
        for j in range(J):
            rv = (dv_max[j] * half) / vlim[j]
            ra = (da_max[j] * rate2) / alim[j]
            if rv > peak_v[j] or rv != rv:
                peak_v[j] = rv if peak_v[j] == peak_v[j] else peak_v[j]
            if ra > peak_a[j] or ra != ra:
                peak_a[j] = ra if peak_a[j] == peak_a[j] else peak_a[j]
    return tool_v, bad_count, events, prev
