"""Verify: replay a written trajectory (setpoints CSV or binary stream) against the printer.

Checks, over every sample:

* the file was compiled for this printer (fingerprint); a file that does not say which printer
  it was made for (a CSV without its ``#`` header) is refused unless the caller assumes the
  printer (``assume_printer``), and the report then says the printer was assumed,
* uniform time steps at the file's rate (a squeezed or stretched step is a violation),
* every joint's position limits (plus half a count of quantisation for streams),
* every joint's velocity and acceleration limits, and the tool channel's: an extruder's
  filament speed (its melt-flow limit while extruding; retracts may reach the retract
  speed) and acceleration, a laser's power within 0..1,
* where the printer file has a ``[dynamics]`` table, each actuator's torque (or force) read back
  through the family's inverse dynamics (accelerations averaged over 5 ms) against its stall
  torque, and the share of samples past the speed-torque curve: reported, not enforced (the
  planner does not plan to torque yet, issue 56),
* given the part or G-code that was compiled, the Cartesian deviation of the
  replayed path (forward kinematics of the samples) from the toolpath polyline,
  for the working samples (tool on), against blend tolerance + quantisation. A
  stream has no extruder on/off state: its working samples are those where the
  filament count rises, with gaps of up to 50 ms inside a run filled where they are no
  more than three times the gaps beside them (a short travel between two runs is not).

Velocities and accelerations are finite differences over a window of ``w``
samples: ``v = (q[i+w] - q[i]) / (t[i+w] - t[i])``, accelerations from two
consecutive such velocities. Quantisation (half a count, ``d/2``) adds at most
``d / h`` to a velocity and ``2 d / h^2`` to an acceleration over a window of
``h = w / rate`` seconds; each channel's window is the shortest that keeps that
bound below ``NOISE_FRACTION`` (5 %) of its limit, and the bound is added to the
threshold. CSV files (10 decimals) get ``w = 1``. Limits are allowed
``MARGIN`` (2 %) above their value. The limits, the windows and the thresholds
(``Limits.sampled_check``, ``Limits.sampled_tool_velocity``) and the difference arithmetic are
:mod:`deltaslice.machine.limits`', shared with the planner and the compile's monitor.

Verify takes samples and a loaded printer (its limits and kinematics) and an optional
toolpath; ``pipeline.verify_output`` reads the files.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import StreamError
from .machine.limits import JERK_SPACING, NOISE_FRACTION, TOLERANCE, third_differences, windowed_differences
from .tolerances import RELATIVE_ROUNDOFF, SAME_LENGTH, SHORTEST_TIME

MARGIN = TOLERANCE  # shown in the report; the thresholds are Limits.sampled_check's
CSV_RESOLUTION = 1e-10  # the CSV's 10 decimals (rounding error 5e-11)
MAX_LISTED = 20
GAP_FILL = 0.05  # s: a stream's extruder count rises every few samples; gaps this short inside a run are working
GAP_RATIO = 3  # ... and no longer than this many times the gaps beside them (a short travel's pause is far longer)
PATH_SLACK = 1e-3  # mm: chords of the resampled toolpath, forward kinematics round-off


@dataclass(frozen=True)
class Violation:
    kind: str  # fingerprint, time_step, position, velocity, acceleration, filament_speed, filament_acceleration, laser_power, tool, deviation
    channel: str
    index: int  # sample index of the worst sample of the run
    time: float  # s
    value: float
    limit: float
    unit: str = ""
    samples: int = 1  # consecutive samples in violation

    def text(self) -> str:
        run = f" ({self.samples} samples)" if self.samples > 1 else ""
        return (
            f"{self.kind} {self.channel}: {self.value:.6g} {self.unit} beyond limit {self.limit:.6g} {self.unit} "
            f"at t = {self.time:.4f} s, sample {self.index}{run}"
        )


@dataclass(frozen=True)
class ChannelStat:
    """One channel's figures. ``velocity_limit`` is the limit that applies where the velocity
    uses the largest share of its limit (an extruder: the melt-flow limit while printing, the
    retract speed while idle), ``peak_velocity`` the velocity there."""

    name: str
    unit: str
    low: float
    high: float
    peak_velocity: float
    velocity_limit: float
    velocity_window: int
    peak_acceleration: float
    acceleration_limit: float
    acceleration_window: int
    velocity_index: int = 0
    acceleration_index: int = 0
    position_min: float = -math.inf
    position_max: float = math.inf


@dataclass(frozen=True)
class CheckRow:
    """One row of the verify table: a check on one channel, its worst sample and PASS/FAIL.
    percent: the peak's share of the limit (None where a share means nothing: time steps,
    non-finite values); place: the tool tip (mm, bed frame) at the worst sample, when known."""

    check: str
    channel: str
    unit: str
    peak: float
    limit: float
    percent: float | None
    time: float
    index: int
    place: tuple | None
    ok: bool
    informational: bool = False  # reported, not checked: the table says INFO, never FAIL


@dataclass(frozen=True)
class VerifyReport:
    output: str
    printer: str
    format: str
    n_samples: int
    rate: float
    duration: float
    channels: tuple[ChannelStat, ...]
    violations: tuple[Violation, ...]
    violation_count: int
    max_deviation: float | None = None
    deviation_tolerance: float | None = None
    deviation_samples: int = 0
    notes: tuple[str, ...] = field(default_factory=tuple)
    planner_margin: float = 0.0
    rows: tuple[CheckRow, ...] = field(default_factory=tuple)
    #: the file does not say which printer it was made for: checked as ``printer``'s because the caller said so
    printer_assumed: bool = False

    @property
    def ok(self) -> bool:
        return self.violation_count == 0

    def table(self) -> list[str]:
        """The check table: one row per check and channel, PASS or FAIL (revolute joints in degrees)."""
        head = f"{'check':<22} {'channel':<14} {'peak':>11} {'limit':>11} {'unit':<8} {'use':>7}  {'worst at':<36} result"
        lines = [head, "-" * len(head)]
        for r in self.rows:
            k, unit = (180.0 / math.pi, "deg" + r.unit[3:]) if r.unit.startswith("rad") else (1.0, r.unit)
            use = "" if r.percent is None else f"{r.percent:6.1f}%"
            where = "" if r.index < 0 else f"t = {r.time:.3f} s"
            if r.place is not None and all(math.isfinite(v) for v in r.place):
                where += " at ({:.1f}, {:.1f}, {:.1f})".format(*r.place)
            lines.append(
                f"{r.check:<22} {r.channel:<14} {r.peak * k:>11.5g} {r.limit * k:>11.5g} {unit:<8} {use:>7}  {where:<36} "
                f"{'INFO' if r.informational else 'PASS' if r.ok else 'FAIL'}"
            )
        return lines

    def text(self) -> str:
        lines = [
            f"verify {self.output}: {self.format}, printer {self.printer}"
            + (" (assumed: the file does not say which printer it was made for)" if self.printer_assumed else "")
            + f", {self.n_samples} samples, "
            f"{self.duration:.3f} s at {self.rate:g} Hz",
            f"limits allowed {100 * MARGIN:g} % above their value (the planner keeps {100 * self.planner_margin:g} %); "
            "differences over windows "
            f"that keep quantisation noise under {100 * NOISE_FRACTION:g} % of each limit (bound added to the threshold); "
            "'use' is the peak's share of its limit, 'worst at' the time and tool position (mm) of the peak",
            *self.table(),
        ]
        if self.max_deviation is not None:
            lines.append(
                f"path deviation: max {self.max_deviation:.4f} mm over {self.deviation_samples} working samples "
                f"(tolerance up to {self.deviation_tolerance:.4f} mm: blend tolerance + quantisation)"
            )
        lines += [f"note: {n}" for n in self.notes]
        if self.ok:
            lines.append("violations: none")
            lines.append("OK")
        else:
            shown = self.violations[:MAX_LISTED]
            lines.append(f"violations: {self.violation_count} run(s)" + (f", first {len(shown)}:" if self.violation_count > len(shown) else ":"))
            lines += ["  " + v.text() for v in shown]
            lines.append("FAIL")
        return "\n".join(lines)


# --------------------------------------------------------------------------- helpers


def _runs(mask: np.ndarray, excess: np.ndarray):
    """(start, end, worst) of each run of True in mask (excess: how bad each sample is)."""
    if not mask.any():
        return []
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(m))
    out = []
    for a, b in zip(edges[0::2], edges[1::2]):
        out.append((int(a), int(b), int(a + np.argmax(excess[a:b]))))
    return out


class _Collector:
    def __init__(self, t):
        self.t = t
        self.items: list[Violation] = []
        self.count = 0
        self.by_key: dict = {}

    def failed(self, kind, channel) -> bool:
        return self.by_key.get((kind, channel), 0) > 0

    def add_mask(self, kind, channel, mask, value, limit, unit, index_offset=0):
        """mask/value over difference positions; index_offset maps them to a sample index."""
        limit_arr = np.broadcast_to(np.asarray(limit, dtype=float), mask.shape)
        runs = _runs(mask, np.nan_to_num(np.abs(value) - limit_arr, nan=np.inf))
        self.count += len(runs)
        self.by_key[(kind, channel)] = self.by_key.get((kind, channel), 0) + len(runs)
        for a, b, worst in runs[: 4 * MAX_LISTED]:
            i = min(worst + index_offset, len(self.t) - 1)
            self.items.append(Violation(kind, channel, i, float(self.t[i]), float(value[worst]), float(limit_arr[worst]), unit, b - a))

    def add(self, v: Violation):
        self.count += 1
        self.by_key[(v.kind, v.channel)] = self.by_key.get((v.kind, v.channel), 0) + 1
        self.items.append(v)


# --------------------------------------------------------------------------- main entry


MIN_RATE = 50.0  # Hz: below this the motion between samples is not constrained by anything checked here
#: Relative difference below which a file's rate is the printer's output rate (a note otherwise).
RATE_MATCH = RELATIVE_ROUNDOFF


def _nan_argmax(x) -> int:
    return int(np.nanargmax(x)) if len(x) and np.isfinite(x).any() else -1


def verify_samples(samples, printer, *, rate: float, fmt: str, meta: dict | None = None, toolpath=None,
                   output: str = "<samples>", assume_printer: bool = False) -> VerifyReport:
    """Check Samples against the printer (see the module docstring). ``fmt`` "csv" or "stream"
    sets the quantisation assumed. rate: the file's sample rate, Hz (finite, > 0).

    meta: the file's metadata (``read_output``), whose fingerprint must confirm the printer; a
    file's metadata without one is refused (StreamError) unless ``assume_printer``: the caller
    names ``printer`` as the one the file was made for, and the report says so. None: samples
    that come from no file (nothing to confirm).

    Fails (violations, not exceptions) on: no samples, any non-finite value, a rate below
    MIN_RATE, non-uniform time steps, and every limit. Raises StreamError on arguments that
    cannot describe a file (rate not a positive number, wrong joint count)."""
    rate, assumed = _checked_arguments(samples, printer, rate, fmt, meta, output, assume_printer)
    check = _Checks(samples, printer, rate, fmt)
    check.basics()
    check.fingerprint(meta or {}, assumed)
    check.time_steps()
    check.joints()
    check.tool_channel()
    n, t = check.n, check.t
    if n > 2 and printer.dynamics is not None and np.isfinite(samples.q).all():
        _torque_rows(samples.q, t, rate, printer, check.rows, check.notes)
    max_dev = tol_max = None
    n_dev = 0
    if toolpath is not None and n:
        max_dev, tol_max, n_dev, i_dev = _check_deviation(samples, printer, toolpath, check.quantised, check.col)
        check.rows.append(CheckRow(
            check="path deviation", channel="tool tip", unit="mm", peak=max_dev, limit=tol_max,
            percent=100.0 * max_dev / tol_max if tol_max else None, time=float(t[i_dev]) if i_dev >= 0 else 0.0,
            index=i_dev, place=None, ok=not check.col.failed("deviation", "path")))
    rows = _with_places(check.rows, samples, printer)
    col = check.col
    col.items.sort(key=lambda v: (v.index, v.kind))
    return VerifyReport(
        output=str(output), printer=printer.name, format=fmt, n_samples=n, rate=rate,
        duration=float(t[-1] - t[0]) if n > 1 else 0.0, channels=tuple(check.stats), violations=tuple(col.items),
        violation_count=col.count, max_deviation=max_dev, deviation_tolerance=tol_max, deviation_samples=n_dev,
        notes=tuple(check.notes), planner_margin=printer.planning.limit_margin, rows=tuple(rows),
        printer_assumed=assumed,
    )


def _checked_arguments(samples, printer, rate, fmt, meta, output, assume_printer) -> tuple[float, bool]:
    """(rate as a float, whether the printer is assumed) of verify_samples' arguments, or StreamError."""
    from .machine import Printer
    from .samples import Samples

    if not isinstance(samples, Samples):
        raise StreamError(f"{output}: samples: expected Samples, got {type(samples).__name__}")
    if not isinstance(printer, Printer):
        raise StreamError(f"{output}: printer: expected a loaded Printer, got {type(printer).__name__}")
    try:
        rate = float(rate)
    except (TypeError, ValueError):
        raise StreamError(f"{output}: rate {rate!r}: expected a number of samples per second") from None
    if not math.isfinite(rate) or rate <= 0:
        raise StreamError(f"{output}: rate_hz = {rate:g}: expected a finite rate > 0 Hz")
    if fmt not in ("csv", "stream"):
        raise StreamError(f"{output}: format {fmt!r}: expected 'csv' or 'stream'")
    assumed = meta is not None and meta.get("fingerprint") is None
    if assumed and not assume_printer:
        raise StreamError(
            f"{output}: the file does not say which printer it was made for (no fingerprint: a CSV's '#' header "
            f"lines are missing), so it cannot be confirmed as made for {printer.name}; if it was, say so with "
            "--assume-printer (assume_printer=True)")
    if samples.n_joints != printer.n_joints:
        raise StreamError(f"{output}: {samples.n_joints} joint columns, printer {printer.name} has {printer.n_joints} joints")
    return rate, assumed


class _Checks:
    """The checks of one verify_samples call and what they found: violations (``col``), the table's
    rows, notes and per-channel figures, in the order the report shows them."""

    def __init__(self, samples, printer, rate: float, fmt: str):
        self.samples, self.printer, self.rate = samples, printer, rate
        self.quantised = fmt == "stream"
        self.n, self.t = len(samples), samples.t
        self.lim = printer.limits
        self.col = _Collector(self.t if self.n else np.zeros(1))
        self.notes: list[str] = []
        self.rows: list[CheckRow] = []
        self.stats: list[ChannelStat] = []

    def _row(self, check, channel, unit, peak, limit, *, percent=None, time=0.0, index=-1, ok=True) -> None:
        self.rows.append(CheckRow(check=check, channel=channel, unit=unit, peak=peak, limit=limit, percent=percent,
                                  time=time, index=index, place=None, ok=ok))

    def basics(self) -> None:
        """Samples at all, a rate the motion can be checked at, finite values only."""
        col, n, t, rate = self.col, self.n, self.t, self.rate
        if n == 0:
            col.add(Violation("samples", "file", 0, 0.0, 0.0, 1.0, "(the file holds no samples)"))
            self._row("samples", "file", "", 0.0, 1.0, ok=False)
        if rate < MIN_RATE:
            col.add(Violation("rate", "t", 0, 0.0, rate, MIN_RATE, "Hz (too slow to check the motion between samples)"))
        # the one row whose limit is a minimum: named so ("rate t 1000, limit 50 Hz" read as a maximum)
        self._row("sample rate, at least", "samples", "Hz", rate, MIN_RATE, ok=not col.failed("rate", "t"))
        # any non-finite value fails; the checks below see the finite values only
        s = self.samples
        arrays = [("t", t)] + [(f"q{j + 1}", s.q[:, j]) for j in range(s.n_joints)] + [("e", s.e), ("tool", s.tool)]
        bad_total, first_bad = 0, -1
        for name, x in arrays:
            bad = ~np.isfinite(x)
            if bad.any():
                col.add_mask("non_finite", name, bad, np.where(bad, np.inf, 0.0), np.zeros(n), "")
                bad_total += int(bad.sum())
                i = int(np.argmax(bad))
                first_bad = i if first_bad < 0 else min(first_bad, i)
        self._row("non-finite values", "all", "", float(bad_total), 0.0,
                  time=float(np.nan_to_num(t[first_bad])) if first_bad >= 0 else 0.0, index=first_bad,
                  ok=bad_total == 0)

    def fingerprint(self, meta: dict, assumed: bool) -> None:
        """The file made for this printer (its fingerprint), or the printer assumed; the rate's note."""
        printer = self.printer
        fp = meta.get("fingerprint")
        if fp is not None:
            try:
                fp_val = int(fp, 16)
            except (TypeError, ValueError):
                fp_val = None
            if fp_val != printer.fingerprint():
                self.col.add(Violation("fingerprint", "printer", 0, 0.0, float(fp_val or 0), float(printer.fingerprint()),
                                       f"(file made for {meta.get('printer', '?')!r}, fingerprint {fp}, "
                                       f"not 0x{printer.fingerprint():08x})"))
            self._row("printer fingerprint", str(meta.get("printer", "?")), "", float(fp_val or 0),
                      float(printer.fingerprint()), ok=not self.col.failed("fingerprint", "printer"))
        elif assumed:
            self.notes.append(f"the printer was assumed: the file does not say which printer it was made for; checked "
                              f"as made for {printer.name} (--assume-printer)")
        if abs(self.rate - printer.planning.output_rate) > RATE_MATCH * self.rate:
            self.notes.append(f"file rate {self.rate:g} Hz differs from the printer's output_rate "
                              f"{printer.planning.output_rate:g} Hz")

    def time_steps(self) -> None:
        """Every step 1 / rate (within a thousandth of it)."""
        if self.n <= 1:
            return
        t, period = self.t, 1.0 / self.rate
        dt = np.diff(t)
        tol = max(1e-3 * period, 2e-9)
        self.col.add_mask("time_step", "t", np.abs(dt - period) > tol, dt, period, "s", index_offset=1)
        err = np.abs(dt - period)
        k = _nan_argmax(err)
        self._row("time step error", "t", "s", float(err[k]) if k >= 0 else 0.0, tol,
                  time=float(t[k + 1]) if k >= 0 else 0.0, index=k + 1 if k >= 0 else -1,
                  ok=not self.col.failed("time_step", "t"))

    def joints(self) -> None:
        """Every joint's position, velocity and acceleration."""
        if not self.n:
            return
        for j, joint in enumerate(self.lim.joints):
            res = 1.0 / abs(joint.counts_per_unit) if self.quantised else CSV_RESOLUTION
            self.channel(f"q{j + 1}" if joint.name == f"q{j + 1}" else f"q{j + 1}/{joint.name}", joint.unit,
                         self.samples.q[:, j], joint.position_min, joint.position_max, j, res)

    def tool_channel(self) -> None:
        """The tool channel, from its limits: a laser has a power range (0..1) and no rate limit; an
        extruder has no range, a melt-flow speed limit while extruding and its retract speed when idle."""
        lim, n, t, col, samples = self.lim, self.n, self.t, self.col, self.samples
        T = lim.n_joints
        ch = lim.channel(T)
        x = self.printer.tool.channel_values(samples.e, samples.tool)
        res = 1.0 / abs(ch.counts_per_unit) if self.quantised else CSV_RESOLUTION
        if n and (math.isfinite(ch.position_min) or math.isfinite(ch.position_max)):
            half = 0.5 * res if self.quantised else CSV_RESOLUTION
            bad = (x < ch.position_min - half) | (x > ch.position_max + half)
            col.add_mask(f"{ch.name}_power", "tool", bad, x, np.where(x < ch.position_min, ch.position_min,
                                                                      ch.position_max), "")
            i = _nan_argmax(x)
            self._row(f"{ch.name} power", "tool", ch.unit, float(x[i]) if i >= 0 else 0.0, ch.position_max,
                      percent=100.0 * float(x[i]) / ch.position_max if i >= 0 and ch.position_max > 0 else None,
                      time=float(t[i]) if i >= 0 else 0.0, index=i, ok=not col.failed(f"{ch.name}_power", "tool"))
            self._full_power_note(float(x[i]) if i >= 0 else 0.0)
        if n and math.isfinite(ch.velocity_max):
            # a stream carries no tool state: the larger of the working and idle limits; a CSV's
            # windows are held to the working limit where the tool is on throughout
            vmax, vlimit_arr = lim.sampled_tool_velocity(None if self.quantised else samples.tool, res, self.rate,
                                                         NOISE_FRACTION)
            if self.quantised:
                self.notes.append(
                    f"the stream carries no tool on/off state: {ch.name} speed checked against the larger of its "
                    f"working and idle limits, {vmax:g} {ch.unit}/s"
                )
            self.channel("e", ch.unit, x, None, None, T, res, f"{ch.name}_speed", f"{ch.name}_acceleration", vmax=vmax,
                         vlimit_arr=vlimit_arr)
            tl = samples.tool
            col.add_mask("tool", "tool", (tl < 0) | (tl > 1), tl, np.where(tl < 0, 0.0, 1.0), "")
            self._row("tool state 0..1", "tool", "", float(np.nanmax(np.abs(tl))) if np.isfinite(tl).any() else 0.0,
                      1.0, ok=not col.failed("tool", "tool"))

    def _full_power_note(self, peak: float) -> None:
        """What the peak power burns, in watts, for a tool that says what its full power is."""
        watts = self.printer.tool.full_power_w
        if watts is not None and math.isfinite(peak):
            self.notes.append(f"peak power {peak:.3g} of full power: {peak * watts:.3g} W of the tool's "
                              f"max_power {watts:g} W")

    def channel(self, name, unit, x, lo, hi, i, resolution, vkind="velocity", akind="acceleration", vmax=None,
                vlimit_arr=None) -> None:
        """One channel's position range (when lo is given), velocity and acceleration: violations,
        its ChannelStat and its rows."""
        col, t, n = self.col, self.t, self.n
        check = self.lim.sampled_check(i, resolution, self.rate, NOISE_FRACTION, velocity=vmax)
        vmax, amax = check.velocity_limit, check.acceleration_limit
        wv, wa = check.velocity_window, check.acceleration_window
        half = 0.5 * resolution if self.quantised else CSV_RESOLUTION
        if lo is not None:
            col.add_mask("position", name, x < lo - half, x, lo, unit)
            col.add_mask("position", name, x > hi + half, x, hi, unit)
        v, a = windowed_differences(x, t, wv, wa)
        vbase = np.full(len(v), float(vmax)) if vlimit_arr is None else vlimit_arr[: len(v)]
        vlim = check.velocity_threshold(vbase)
        if len(v):
            col.add_mask(vkind, name, np.abs(v) > vlim, v, vlim, f"{unit}/s", index_offset=wv // 2)
        alim = check.acceleration_threshold()
        if len(a):
            col.add_mask(akind, name, np.abs(a) > alim, a, alim, f"{unit}/s^2", index_offset=wa)
        iv = _nan_argmax(np.abs(v) / vbase) if len(v) else -1
        ia = _nan_argmax(np.abs(a)) if len(a) else -1
        finite = x[np.isfinite(x)]
        stat = ChannelStat(
            name=name, unit=unit, low=float(finite.min()) if len(finite) else 0.0,
            high=float(finite.max()) if len(finite) else 0.0, peak_velocity=float(abs(v[iv])) if iv >= 0 else 0.0,
            velocity_limit=float(vbase[iv]) if iv >= 0 else float(vmax), velocity_window=wv,
            peak_acceleration=float(abs(a[ia])) if ia >= 0 else 0.0, acceleration_limit=float(amax),
            acceleration_window=wa, velocity_index=min(iv + wv // 2, n - 1) if iv >= 0 else -1,
            acceleration_index=min(ia + wa, n - 1) if ia >= 0 else -1,
            position_min=-math.inf if lo is None else float(lo), position_max=math.inf if hi is None else float(hi),
        )
        self.stats.append(stat)
        if lo is not None and len(finite):
            near_hi = (stat.high - hi) >= (lo - stat.low)
            k = _nan_argmax(x if near_hi else -x)
            self._row("position", name, unit, stat.high if near_hi else stat.low, hi if near_hi else lo,
                      time=float(t[k]), index=k, ok=not col.failed("position", name))
        self._row(vkind.replace("_", " "), name, f"{unit}/s", stat.peak_velocity, stat.velocity_limit,
                  percent=_share(stat.peak_velocity, stat.velocity_limit),
                  time=float(t[stat.velocity_index]) if iv >= 0 else 0.0, index=stat.velocity_index,
                  ok=not col.failed(vkind, name))
        self._row(akind.replace("_", " "), name, f"{unit}/s^2", stat.peak_acceleration, stat.acceleration_limit,
                  percent=_share(stat.peak_acceleration, stat.acceleration_limit),
                  time=float(t[stat.acceleration_index]) if ia >= 0 else 0.0, index=stat.acceleration_index,
                  ok=not col.failed(akind, name))
        self._jerk_row(name, unit, x, i)

    def _jerk_row(self, name, unit, x, i) -> None:
        """Channel i's jerk use: its largest third difference over ``JERK_SPACING`` against its
        jerk_max. Reported, never failed: jerk_max is the planner's target (``planning.jerk_limit``),
        not a limit the machine breaks at."""
        jmax, n, t = float(self.lim.jerk[i]), self.n, self.t
        if not (math.isfinite(jmax) and n):
            return
        jk = np.abs(third_differences(x, self.rate))
        k = _nan_argmax(jk) if len(jk) else -1
        w = max(1, int(round(JERK_SPACING * self.rate)))
        peak = float(jk[k]) if k >= 0 else 0.0
        self._row("jerk (5 ms third difference)", name, f"{unit}/s^3", peak, jmax, percent=_share(peak, jmax),
                  time=float(t[min(k + 3 * w // 2, n - 1)]) if k >= 0 else 0.0, index=k, ok=True)


def _share(peak: float, limit: float) -> float | None:
    """The peak's share of its limit, percent (None for a limit of 0)."""
    return 100.0 * peak / limit if limit > 0 else None


def _torque_rows(q, t, rate, printer, rows, notes):
    """An INFO row per actuator, its peak torque (N m) or force (N) read back through the printer's
    inverse dynamics against its stall torque, and a note on the samples past the curves."""
    from .machine.dynamics import ACCELERATION_WINDOW, torque_blocks

    act = printer.dynamics.actuators
    J = printer.n_joints
    peak, where = np.zeros(J), np.full(J, -1)
    over_stall = over_line = 0
    for start, tau, qd in torque_blocks(printer, q, rate):
        mag = np.where(np.isfinite(tau), np.abs(tau), np.inf)  # a pose the model cannot close is its worst
        k = np.argmax(mag, axis=0)
        better = mag[k, np.arange(J)] > peak
        peak[better], where[better] = mag[k, np.arange(J)][better], start + k[better]
        over_stall += int(np.any(mag > np.array(act.stall), axis=1).sum())
        over_line += int(np.any(act.over_line(qd, tau), axis=1).sum())
    for j, joint in enumerate(printer.limits.joints):
        k = int(where[j])
        unit = "N m" if joint.kind == "revolute" else "N"
        name = f"q{j + 1}" if joint.name == f"q{j + 1}" else f"q{j + 1}/{joint.name}"
        rows.append(CheckRow(check="torque (model)", channel=name, unit=unit, peak=float(peak[j]), limit=act.stall[j],
                             percent=100.0 * peak[j] / act.stall[j], time=float(t[k]) if k >= 0 else 0.0, index=k,
                             place=None, ok=True, informational=True))
    notes.append(f"torque (model): [dynamics] read back with accelerations averaged over {1e3 * ACCELERATION_WINDOW:g} ms; "
                 f"an actuator over its stall torque on {100 * over_stall / len(q):.1f} % of the samples, past its "
                 f"speed-torque curve on {100 * over_line / len(q):.1f} %; reported, not failed (the planner keeps to "
                 "them where [planning] torque_limit is on, the default)")


def _with_places(rows, samples, printer):
    """Rows with the tool tip (forward kinematics) at their worst sample."""
    import dataclasses

    idx = [r.index for r in rows if 0 <= r.index < len(samples)]
    if not idx:
        return rows
    q = samples.q[np.asarray(idx)]
    pts = printer.kinematics().forward(np.where(np.isfinite(q), q, np.nan))
    where = dict(zip(idx, map(tuple, pts.tolist())))
    return [dataclasses.replace(r, place=where.get(r.index)) for r in rows]


def _check_deviation(samples, printer, toolpath, quantised, col):
    """Distance of each working sample's tool tip from the working moves of the toolpath."""
    from scipy.spatial import cKDTree

    work = samples.tool > 0
    if quantised and printer.tool.takes_filament:  # a stream's extruder state is derived from rising counts
        work = _close_gaps(work, max(1, int(round(GAP_FILL * len(samples) / max(samples.t[-1] - samples.t[0], SHORTEST_TIME)))))
    idx = np.flatnonzero(work)
    starts, ends = toolpath.starts, toolpath.xyz
    seg_ok = (toolpath.tool > 0) & (toolpath.lengths > SAME_LENGTH)
    a, b = starts[seg_ok], ends[seg_ok]
    blend = printer.planning.blend_tolerance
    if len(idx) == 0 or len(a) == 0:
        return 0.0, blend, 0, -1
    kin = printer.kinematics()
    q = samples.q[idx]
    p = kin.forward(q)
    # densely resampled working moves, each point tagged with its segment
    lengths = np.linalg.norm(b - a, axis=1)
    ds = max(0.05, lengths.sum() / 2e6)
    k = np.maximum(1, np.ceil(lengths / ds).astype(int))
    seg = np.repeat(np.arange(len(a)), k + 1)
    frac = _fracs(k)
    pts = a[seg] + frac[:, None] * (b - a)[seg]
    tree = cKDTree(pts)
    kq = min(4, len(pts))
    _d, nn = tree.query(np.nan_to_num(p, nan=1e9), k=kq, workers=-1)
    nn = nn.reshape(len(p), kq)
    cand = seg[nn]  # (N, kq) candidate segments
    ca, cb = a[cand], b[cand]
    ab = cb - ca
    u = np.clip(np.einsum("nkd,nkd->nk", p[:, None] - ca, ab) / np.maximum(np.einsum("nkd,nkd->nk", ab, ab), 1e-300), 0, 1)
    dist = np.linalg.norm(p[:, None] - (ca + u[..., None] * ab), axis=2).min(axis=1)
    dist = np.where(np.isfinite(p).all(axis=1), dist, np.inf)
    # quantisation: half a count on each joint, through the Jacobian
    if quantised:
        cpu = np.abs(printer.limits.counts_per_unit[: printer.n_joints])
        jac = kin.jacobian(q)  # (N, 3, J)
        qres = np.linalg.norm(0.5 * np.abs(jac) / cpu[None, None, :], axis=1).sum(axis=1)
        qres = np.nan_to_num(qres, nan=0.0)
    else:
        qres = np.zeros(len(p))
    tol = blend + qres + PATH_SLACK
    bad = dist > tol
    mask = np.zeros(len(samples), bool)
    mask[idx[bad]] = True
    value = np.zeros(len(samples))
    value[idx] = dist
    limit = np.zeros(len(samples))
    limit[idx] = tol
    col.add_mask("deviation", "path", mask, value, limit, "mm")
    worst = int(np.argmax(np.where(np.isfinite(dist), dist, np.inf)))
    return float(dist[worst]), float(tol.max()), int(len(idx)), int(idx[worst])


def _close_gaps(mask, k):
    """Fill the runs of False between two True samples that are no longer than k samples and no
    more than GAP_RATIO times the longer of the gaps beside them (at least one sample): the
    pauses of a count that rises every few samples, not a travel between two runs (its count
    stands still many times longer than it paused while extruding). mask: (n,) bool."""
    rise = np.flatnonzero(mask)
    if len(rise) < 2:
        return mask
    gap = np.diff(rise) - 1  # False samples between consecutive True ones
    beside = np.maximum(np.concatenate([[0], gap[:-1]]), np.concatenate([gap[1:], [0]]))
    fill = (gap > 0) & (gap <= k) & (gap <= GAP_RATIO * np.maximum(beside, 1))
    out = mask.copy()
    starts, lengths = rise[:-1][fill] + 1, gap[fill]
    # every filled sample: its gap's first sample plus its offset in the gap
    offsets = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    out[np.repeat(starts, lengths) + offsets] = True
    return out


def _fracs(k):
    """Concatenated linspace(0, 1, m + 1) for every m in k, vectorised."""
    total = int((k + 1).sum())
    starts = np.concatenate([[0], np.cumsum(k + 1)[:-1]])
    pos = np.arange(total) - np.repeat(starts, k + 1)
    return pos / np.repeat(k, k + 1)
