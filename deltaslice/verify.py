"""Verify: replay a written trajectory (setpoints CSV or binary stream) against the printer.

Checks, over every sample:

* the file was compiled for this printer (fingerprint),
* uniform time steps at the file's rate (a squeezed or stretched step is a violation),
* every joint's position limits (plus half a count of quantisation for streams),
* every joint's velocity and acceleration limits, and the tool's: extruder filament
  speed (``max_filament_speed`` while extruding; retracts may reach the retract
  speed) and acceleration, laser power within 0..1,
* given the part or G-code that was compiled, the Cartesian deviation of the
  replayed path (forward kinematics of the samples) from the toolpath polyline,
  for the working samples (tool on), against blend tolerance + quantisation. A
  stream has no extruder on/off state: its working samples are those where the
  filament count rises, with gaps of up to 50 ms inside a run filled.

Velocities and accelerations are finite differences over a window of ``w``
samples: ``v = (q[i+w] - q[i]) / (t[i+w] - t[i])``, accelerations from two
consecutive such velocities. Quantisation (half a count, ``d/2``) adds at most
``d / h`` to a velocity and ``2 d / h^2`` to an acceleration over a window of
``h = w / rate`` seconds; each channel's window is the shortest that keeps that
bound below ``NOISE_FRACTION`` (5 %) of its limit, and the bound is added to the
threshold. CSV files (10 decimals) get ``w = 1``. Limits are allowed
``MARGIN`` (2 %) above their value, since the planner keeps a 1 % margin and
enforces limits at its grid points only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import StreamError

MARGIN = 0.02
NOISE_FRACTION = 0.05
CSV_RESOLUTION = 1e-10  # the CSV's 10 decimals (rounding error 5e-11)
MAX_LISTED = 20
GAP_FILL = 0.05  # s: a stream's extruder count rises every few samples; gaps this short inside a run are working
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

    @property
    def ok(self) -> bool:
        return self.violation_count == 0

    def text(self) -> str:
        lines = [
            f"verify {self.output}: {self.format}, printer {self.printer}, {self.n_samples} samples, "
            f"{self.duration:.3f} s at {self.rate:g} Hz",
            f"limits allowed {100 * MARGIN:g} % above their value (the planner keeps 1 %); differences over windows "
            f"that keep quantisation noise under {100 * NOISE_FRACTION:g} % of each limit (bound added to the threshold)",
            f"{'channel':<10} {'unit':<5} {'range':>23}  {'peak vel':>10} {'% lim':>7} {'window':>7}  "
            f"{'peak acc':>10} {'% lim':>7} {'window':>7}",
        ]
        for c in self.channels:
            pv = 100 * c.peak_velocity / c.velocity_limit if c.velocity_limit else float("nan")
            pa = 100 * c.peak_acceleration / c.acceleration_limit if c.acceleration_limit else float("nan")
            ms = 1000.0 / self.rate
            lines.append(
                f"{c.name:<10} {c.unit:<5} {c.low:>11.4f}..{c.high:<10.4f}  {c.peak_velocity:>10.4g} {pv:>6.1f}% "
                f"{c.velocity_window * ms:>5.0f}ms  {c.peak_acceleration:>10.4g} {pa:>6.1f}% {c.acceleration_window * ms:>5.0f}ms"
            )
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

    def add_mask(self, kind, channel, mask, value, limit, unit, index_offset=0):
        """mask/value over difference positions; index_offset maps them to a sample index."""
        limit_arr = np.broadcast_to(np.asarray(limit, dtype=float), mask.shape)
        runs = _runs(mask, np.abs(value) - limit_arr)
        self.count += len(runs)
        for a, b, worst in runs[: 4 * MAX_LISTED]:
            i = min(worst + index_offset, len(self.t) - 1)
            self.items.append(Violation(kind, channel, i, float(self.t[i]), float(value[worst]), float(limit_arr[worst]), unit, b - a))

    def add(self, v: Violation):
        self.count += 1
        self.items.append(v)


def _window_velocity(limit, resolution, rate):
    """Samples per window so that resolution / h <= NOISE_FRACTION * limit; noise bound."""
    w = max(1, math.ceil(rate * resolution / (NOISE_FRACTION * limit)))
    return w, resolution / (w / rate)


def _window_acceleration(limit, resolution, rate):
    w = max(1, math.ceil(rate * math.sqrt(2 * resolution / (NOISE_FRACTION * limit))))
    return w, 2 * resolution / (w / rate) ** 2


def _differences(x, t, wv, wa):
    """Velocity over wv samples (at i + wv/2) and acceleration over 2 wa samples (centred at i + wa)."""
    n = len(x)
    if n > wv:
        v = (x[wv:] - x[:-wv]) / (t[wv:] - t[:-wv])
    else:
        v = np.zeros(0)
    if n > 2 * wa:
        va = (x[wa:] - x[:-wa]) / (t[wa:] - t[:-wa])  # velocity at the middle of [i, i + wa]
        a = (va[wa:] - va[:-wa]) / (0.5 * (t[2 * wa :] - t[: -2 * wa]))
    else:
        a = np.zeros(0)
    return v, a


# --------------------------------------------------------------------------- main entry


def verify_samples(samples, printer, *, rate: float, fmt: str, meta: dict | None = None, toolpath=None,
                   output: str = "<samples>") -> VerifyReport:
    """Check Samples against the printer (see the module docstring). ``fmt`` "csv" or "stream"
    sets the quantisation assumed."""
    meta = meta or {}
    n = len(samples)
    if samples.n_joints != printer.n_joints:
        raise StreamError(f"{output}: {samples.n_joints} joint columns, printer {printer.name} has {printer.n_joints} joints")
    t = samples.t
    col = _Collector(t)
    notes = []

    fp = meta.get("fingerprint")
    if fp is not None:
        try:
            fp_val = int(fp, 16)
        except ValueError:
            fp_val = None
        if fp_val != printer.fingerprint():
            col.add(Violation("fingerprint", "printer", 0, 0.0, float(fp_val or 0), float(printer.fingerprint()),
                              f"(file made for {meta.get('printer', '?')!r}, fingerprint {fp}, not 0x{printer.fingerprint():08x})"))
    if abs(rate - printer.planning.output_rate) > 1e-9 * rate:
        notes.append(f"file rate {rate:g} Hz differs from the printer's output_rate {printer.planning.output_rate:g} Hz")

    # time steps
    if n > 1:
        period = 1.0 / rate
        dt = np.diff(t)
        tol = max(1e-3 * period, 2e-9)
        col.add_mask("time_step", "t", np.abs(dt - period) > tol, dt, period, "s", index_offset=1)

    cpu = printer.joint_array("counts_per_unit")
    quantised = fmt == "stream"
    stats = []

    def channel(name, unit, x, lo, hi, vmax, amax, resolution, vkind="velocity", akind="acceleration", vmask=None,
                vlimit_arr=None):
        wv, nv = _window_velocity(vmax, resolution, rate)
        wa, na = _window_acceleration(amax, resolution, rate)
        half = 0.5 * resolution if quantised else CSV_RESOLUTION
        if lo is not None:
            col.add_mask("position", name, x < lo - half, x, lo, unit)
            col.add_mask("position", name, x > hi + half, x, hi, unit)
        v, a = _differences(x, t, wv, wa)
        vlim = (vmax if vlimit_arr is None else vlimit_arr[: len(v)]) * (1 + MARGIN) + nv
        if len(v):
            col.add_mask(vkind, name, np.abs(v) > vlim, v, vlim, f"{unit}/s", index_offset=wv // 2)
        alim = amax * (1 + MARGIN) + na
        if len(a):
            col.add_mask(akind, name, np.abs(a) > alim, a, alim, f"{unit}/s^2", index_offset=wa)
        stats.append(ChannelStat(
            name, unit, float(x.min()) if n else 0.0, float(x.max()) if n else 0.0,
            float(np.abs(v).max()) if len(v) else 0.0, float(vmax), wv,
            float(np.abs(a).max()) if len(a) else 0.0, float(amax), wa,
        ))

    for j, joint in enumerate(printer.joints):
        res = 1.0 / cpu[j] if quantised else CSV_RESOLUTION
        channel(f"q{j + 1}" if joint.name == f"q{j + 1}" else f"q{j + 1}/{joint.name}", joint.unit, samples.q[:, j],
                joint.position_min, joint.position_max, joint.velocity_max, joint.acceleration_max, res)

    tool = printer.tool
    if printer.is_laser:
        res = 1.0 / tool.power_counts if quantised else CSV_RESOLUTION
        p = samples.tool
        half = 0.5 * res if quantised else CSV_RESOLUTION
        col.add_mask("laser_power", "tool", (p < -half) | (p > 1 + half), p, np.where(p < 0, 0.0, 1.0), "")
    else:
        res = 1.0 / tool.counts_per_mm if quantised else CSV_RESOLUTION
        fast = max(tool.max_filament_speed, tool.retract_speed)
        vlimit_arr = None
        if quantised:
            vmax = fast
            notes.append(
                f"the stream carries no extruder on/off state: filament speed checked against "
                f"max(max_filament_speed, retract_speed) = {fast:g} mm/s"
            )
        else:
            # while extruding the melt rate bounds the feed; retracts (tool off) may reach the retract speed:
            # a difference window is held to max_filament_speed when the tool is on throughout it
            vmax = tool.max_filament_speed
            wv, _ = _window_velocity(vmax, res, rate)
            if n > wv:
                c = np.concatenate([[0], np.cumsum(samples.tool > 0)])
                on_throughout = (c[wv + 1 :] - c[: -wv - 1]) == wv + 1
                vlimit_arr = np.where(on_throughout, tool.max_filament_speed, fast)
        channel("e", "mm", samples.e, None, None, vmax, tool.max_filament_acceleration, res,
                "filament_speed", "filament_acceleration", vlimit_arr=vlimit_arr)
        tl = samples.tool
        col.add_mask("tool", "tool", (tl < 0) | (tl > 1), tl, np.where(tl < 0, 0.0, 1.0), "")

    max_dev = tol_max = None
    n_dev = 0
    if toolpath is not None:
        max_dev, tol_max, n_dev = _check_deviation(samples, printer, toolpath, quantised, col)
    col.items.sort(key=lambda v: (v.index, v.kind))
    return VerifyReport(
        output=str(output), printer=printer.name, format=fmt, n_samples=n, rate=rate,
        duration=float(t[-1] - t[0]) if n > 1 else 0.0, channels=tuple(stats), violations=tuple(col.items),
        violation_count=col.count, max_deviation=max_dev, deviation_tolerance=tol_max, deviation_samples=n_dev,
        notes=tuple(notes),
    )


def _check_deviation(samples, printer, toolpath, quantised, col):
    """Distance of each working sample's tool tip from the working moves of the toolpath."""
    from scipy.spatial import cKDTree

    work = samples.tool > 0
    if quantised and not printer.is_laser:
        work = _close_gaps(work, max(1, int(round(GAP_FILL * len(samples) / max(samples.t[-1] - samples.t[0], 1e-9)))))
    idx = np.flatnonzero(work)
    starts, ends = toolpath.starts, toolpath.xyz
    seg_ok = (toolpath.tool > 0) & (toolpath.lengths > 1e-9)
    a, b = starts[seg_ok], ends[seg_ok]
    blend = printer.planning.blend_tolerance
    if len(idx) == 0 or len(a) == 0:
        return 0.0, blend, 0
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
        cpu = printer.joint_array("counts_per_unit")
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
    return float(dist.max()), float(tol.max()), int(len(idx))


def _close_gaps(mask, k):
    """Fill runs of False no longer than k samples that have True on both sides (vectorised)."""
    n = len(mask)
    pos = np.arange(n)
    prev = np.maximum.accumulate(np.where(mask, pos, -(10**12)))
    nxt = np.minimum.accumulate(np.where(mask, pos, 10**12)[::-1])[::-1]
    return mask | ((nxt - prev) <= k + 1)


def _fracs(k):
    """Concatenated linspace(0, 1, m + 1) for every m in k, vectorised."""
    total = int((k + 1).sum())
    starts = np.concatenate([[0], np.cumsum(k + 1)[:-1]])
    pos = np.arange(total) - np.repeat(starts, k + 1)
    return pos / np.repeat(k, k + 1)


def verify_file(output, printer_path, toolpath_path=None, engrave=None) -> VerifyReport:
    """Read a setpoints CSV or binary stream and check it against the printer file.

    toolpath_path: the part (mesh) or G-code that was compiled, to check path deviation."""
    from .emit import read_output
    from .printer import Printer, load_printer

    printer = printer_path if isinstance(printer_path, Printer) else load_printer(printer_path)
    meta, samples = read_output(output)
    fmt = meta.get("format", "csv")
    try:
        rate = float(meta.get("rate_hz", printer.planning.output_rate))
    except ValueError:
        raise StreamError(f"{output}: rate_hz {meta.get('rate_hz')!r} is not a number") from None
    toolpath = None
    if toolpath_path is not None:
        from .pipeline import load_toolpath

        toolpath = load_toolpath(toolpath_path, printer, engrave=engrave)
    return verify_samples(samples, printer, rate=rate, fmt=fmt, meta=meta, toolpath=toolpath, output=str(output))
