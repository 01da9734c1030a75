"""Pictures for people: a toolpath's layer coloured by role with its travels, and a written
trajectory's joints against their limits over time.

Figures are built here (matplotlib, Agg) and saved to a binary file object by :func:`save`;
``pipeline.preview`` opens the file. Long trajectories are drawn as min/max envelopes per
pixel column, so a one-sample spike stays visible.
"""

from __future__ import annotations

import math

import numpy as np

from .machine.limits import windowed_differences
from .tolerances import SAME_LENGTH
from .toolpath import Role

ROLE_STYLE = {  # role: (colour, label)
    Role.EXTERNAL_PERIMETER: ("#d62728", "outer perimeter"),
    Role.PERIMETER: ("#ff7f0e", "perimeter"),
    Role.INFILL: ("#2ca02c", "infill"),
    Role.SOLID_INFILL: ("#1f77b4", "solid infill"),
    Role.TOP_SOLID_INFILL: ("#9467bd", "top solid infill"),
    Role.SKIRT: ("#8c564b", "skirt / brim"),
    Role.OVERHANG_PERIMETER: ("#e6550d", "overhang perimeter"),
    Role.BRIDGE_INFILL: ("#17becf", "bridge infill"),
    Role.GAP_FILL: ("#bcbd22", "gap fill"),
    Role.SUPPORT: ("#636363", "support"),
    Role.SUPPORT_INTERFACE: ("#c49c94", "support interface"),
    Role.LASER: ("#e377c2", "laser"),
    Role.OTHER: ("#7f7f7f", "other"),
}
TRAVEL_COLOUR = "#9aa5b1"
ENVELOPE_COLUMNS = 1500


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, f) -> None:
    """Write ``fig`` as PNG to the binary file object ``f`` and free it."""
    fig.savefig(f, format="png", dpi=110)
    _plt().close(fig)


def _bed_outline(ax, bed):
    if bed.shape == "circle":
        t = np.linspace(0, 2 * np.pi, 200)
        ax.plot(bed.radius * np.cos(t), bed.radius * np.sin(t), color="#444", lw=1, ls=":", label="bed edge")
    else:
        x, y = bed.size_x / 2, bed.size_y / 2
        ax.plot([-x, x, x, -x, -x], [-y, -y, y, y, -y], color="#444", lw=1, ls=":", label="bed edge")


def toolpath_figure(toolpath, printer, *, layer=None, title=""):
    """(figure, layer drawn): the layer's moves coloured by role with travels dashed, the
    part's outline on the bed, and a side view of every layer. layer: index (default middle)."""
    from matplotlib.collections import LineCollection

    plt = _plt()
    n_layers = max(toolpath.n_layers, 1)
    if layer is None:
        layer = n_layers // 2
    layer = int(np.clip(layer, 0, n_layers - 1))
    fig, (ax, side) = plt.subplots(1, 2, figsize=(13, 6.2), gridspec_kw={"width_ratios": [1.15, 1]})
    starts, ends = toolpath.starts, toolpath.xyz
    on_layer = toolpath.layer == layer
    working = toolpath.tool > 0
    _bed_outline(ax, printer.bed)
    travel = on_layer & ~working & (toolpath.lengths > SAME_LENGTH)
    if travel.any():
        segs = np.stack([starts[travel, :2], ends[travel, :2]], axis=1)
        ax.add_collection(LineCollection(segs, colors=TRAVEL_COLOUR, linewidths=0.7, linestyles=(0, (3, 2)), label="travel"))
    for role, (colour, label) in ROLE_STYLE.items():
        m = on_layer & working & (toolpath.role == role)
        if m.any():
            segs = np.stack([starts[m, :2], ends[m, :2]], axis=1)
            ax.add_collection(LineCollection(segs, colors=colour, linewidths=1.4, label=label))
    pts = np.concatenate([starts[on_layer, :2], ends[on_layer, :2]]) if on_layer.any() else np.zeros((1, 2))
    span = max(float(np.ptp(pts[:, 0])), float(np.ptp(pts[:, 1])), 10.0)
    cx, cy = pts.mean(axis=0)
    ax.set_xlim(cx - 0.65 * span, cx + 0.65 * span)
    ax.set_ylim(cy - 0.65 * span, cy + 0.65 * span)
    ax.set_aspect("equal")
    ax.grid(alpha=0.25)
    z = toolpath.layer_z[layer] if len(toolpath.layer_z) > layer else 0.0
    ax.set_title(f"layer {layer + 1} of {toolpath.n_layers} (z = {z:.2f} mm)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.legend(loc="upper right", fontsize=8, framealpha=0.9)

    # side view: every working move, x against z, the drawn layer highlighted
    _bed_outline_side(side, printer.bed)
    for role, (colour, _label) in ROLE_STYLE.items():
        m = working & (toolpath.role == role)
        if m.any():
            segs = np.stack([starts[m][:, [0, 2]], ends[m][:, [0, 2]]], axis=1)
            side.add_collection(LineCollection(segs, colors=colour, linewidths=0.6, alpha=0.5))
    side.axhline(z, color="k", lw=1, ls="--", label=f"layer {layer + 1}")
    side.set_xlim(-1.05 * printer.bed.radius, 1.05 * printer.bed.radius)
    top = float(ends[:, 2].max()) if len(ends) else 1.0
    side.set_ylim(-0.02 * printer.bed.max_height, max(top * 1.15, 5.0))
    side.set_xlabel("x (mm)")
    side.set_ylabel("z above bed (mm)")
    side.set_title("side view (all layers)")
    side.grid(alpha=0.25)
    side.legend(loc="upper right", fontsize=8)
    s = toolpath.summary()
    fig.suptitle(f"{title}\n{s['layers']} layers, {s['moves']} moves, {s['filament_mm']:.0f} mm filament", fontsize=11)
    fig.tight_layout()
    return fig, layer


def _bed_outline_side(ax, bed):
    ax.plot([-bed.radius, bed.radius], [0, 0], color="#444", lw=2, label="bed")
    ax.axhline(bed.max_height, color="#444", lw=0.8, ls=":", label="max height")


def _envelope(t, y, columns=ENVELOPE_COLUMNS):
    """(t, low, high) per column of a long series; short series are returned as they are."""
    n = len(y)
    if n <= 2 * columns:
        return t, y, y
    k = n // columns
    m = k * columns
    yy = y[:m].reshape(columns, k)
    return t[:m].reshape(columns, k)[:, k // 2], np.nanmin(yy, axis=1), np.nanmax(yy, axis=1)


def _series(ax, t, y, colour, limit=None, lower=None, label=None):
    tt, lo, hi = _envelope(t, y)
    ax.fill_between(tt, lo, hi, color=colour, lw=0.6, alpha=0.85, step="mid", label=label)
    if limit is not None and math.isfinite(limit):
        ax.axhline(limit, color="#c0392b", lw=1, ls="--")
        ax.axhline(-limit if lower is None else lower, color="#c0392b", lw=1, ls="--")


def trajectory_figure(samples, printer, *, title="", tool_state=True):
    """Joint position, speed and acceleration over time against the printer's limits (red
    dashed), then the tool channel's speed and the tool-tip speed. samples: :class:`Samples`.
    tool_state: whether the samples' tool column is the tool's on/off state (a CSV's); a stream's is
    derived, and its filament speed is held, as verify holds it, to the larger of the two limits."""
    plt = _plt()
    lim = printer.limits
    J = lim.n_joints
    t = samples.t
    rate = 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    rows = 5 if printer.dynamics is not None else 4  # a torque row where the printer has dynamics
    fig, axes = plt.subplots(rows, J, figsize=(4.6 * J, 2.6 * rows + 0.1), sharex=True, squeeze=False)
    colours = ["#1f77b4", "#2ca02c", "#9467bd", "#8c564b"]
    deg = 180.0 / math.pi
    for j, ch in enumerate(lim.joints):
        k = deg if ch.kind == "revolute" else 1.0
        unit = "deg" if ch.kind == "revolute" else "mm"
        x = samples.q[:, j]
        res = 1.0 / abs(ch.counts_per_unit)
        check = lim.sampled_check(j, res, rate)  # the windows verify uses
        wv, wa = check.velocity_window, check.acceleration_window
        v, a = windowed_differences(x, t, wv, wa)
        c = colours[j % len(colours)]
        _series(axes[0, j], t, x * k, c, ch.position_max * k, ch.position_min * k)
        _series(axes[1, j], t[wv // 2: wv // 2 + len(v)], v * k, c, ch.velocity_max * k)
        _series(axes[2, j], t[wa: wa + len(a)], a * k, c, ch.acceleration_max * k)
        name = ch.name
        axes[0, j].set_title(f"{name}: position ({unit})")
        axes[1, j].set_title(f"{name}: speed ({unit}/s), peak {100 * _peak(v, ch.velocity_max):.0f} % of limit")
        axes[2, j].set_title(f"{name}: acceleration ({unit}/s²), peak {100 * _peak(a, ch.acceleration_max):.0f} % of limit")
    values = printer.tool.channel_values(samples.e, samples.tool)
    ax = axes[3, 0]
    if printer.tool.channel_is_power:
        _series(ax, t, values, "#e377c2", 1.0, 0.0)
        ax.set_title("laser power (0..1)")
    else:
        v, _a = windowed_differences(values, t, max(1, int(rate / 100)), 1)
        w = max(1, int(rate / 100))
        working, idle = lim.tool_velocity_limits()
        either = max(working, idle)
        tv = t[w // 2: w // 2 + len(v)]
        _series(ax, tv, v, "#ff7f0e")
        # The limit each stretch is held to, as verify holds it: the melt-flow speed only where the
        # tool extrudes throughout the window, the retract speed (either way) elsewhere. One line at
        # the melt-flow speed looked violated by every retraction and unretraction.
        if tool_state and len(v):
            on = np.asarray(samples.tool) > 0
            c = np.concatenate([[0], np.cumsum(on)])
            throughout = (c[w + 1: w + 1 + len(v)] - c[: len(v)]) == w + 1
            limit = np.where(throughout, working, either)
            lt, _lo, hi = _envelope(tv, limit)
            ax.plot(lt, hi, color="#c0392b", lw=1, ls="--", drawstyle="steps-mid")
            ax.plot(lt, -hi, color="#c0392b", lw=1, ls="--", drawstyle="steps-mid")
            ax.set_title(f"filament speed (mm/s); limits: melt flow {working:.3g}\nwhile extruding, retract {idle:.3g}",
                         fontsize=9)
        else:
            ax.axhline(either, color="#c0392b", lw=1, ls="--")
            ax.axhline(-either, color="#c0392b", lw=1, ls="--")
            ax.set_title(f"filament speed (mm/s); limit {either:.3g}: a stream has no\ntool state, so melt flow "
                         f"{working:.3g} and retract {idle:.3g} are not told apart", fontsize=9)
    tip = printer.kinematics().forward(samples.q)
    if len(t) > 1:
        w = max(1, int(rate / 100))
        speed = np.linalg.norm(tip[w:] - tip[:-w], axis=1) / (t[w:] - t[:-w])
        _series(axes[3, 1 % J], t[w // 2: w // 2 + len(speed)], speed, "#17becf")
    axes[3, 1 % J].set_title("tool-tip speed (mm/s)")
    if J > 2:
        ax = axes[3, 2]
        xy = tip[:: max(1, len(tip) // 20000)]
        ax.remove()
        ax = fig.add_subplot(rows, J, 3 * J + 3)
        ax.plot(xy[:, 0], xy[:, 1], lw=0.4, color="#555")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title("tool tip, top view (mm)")
    if rows == 5:
        _torque_panels(axes[4], samples, printer, rate)
    for ax in axes[3, :2]:
        ax.set_xlabel("time (s)")
    for row in axes:
        for ax in row:
            ax.grid(alpha=0.25)
    duration = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    fig.suptitle(f"{title}\n{len(t)} samples, {duration:.1f} s at {rate:.0f} Hz; red dashed: the printer's limits",
                 fontsize=11)
    fig.tight_layout()
    return fig


def _peak(x, limit):
    return float(np.nanmax(np.abs(x))) / limit if len(x) and limit > 0 else 0.0


def torque_limit_lines(printer, qd):
    """The limits a torque panel draws, those the planner keeps to (``planning.torque``): stall (J,)
    N m or N, and the motor's safe line at the joint speeds qd (N, J) joint units/s, stall (1 - |qd|
    / w) with w the line speed (``ActuatorCurves.line_speed``), floored at 0: (N, J)."""
    act = printer.dynamics.actuators
    stall, w = np.array(act.stall, dtype=float), np.array(act.line_speed(), dtype=float)
    return stall, stall * np.clip(1.0 - np.abs(qd) / w, 0.0, 1.0)


def _torque_panels(axes, samples, printer, rate):
    """Each actuator's torque (force) over time, read back through the printer's inverse dynamics as
    verify reads it (``machine.dynamics.sampled_torques``), against its stall torque (red dashed) and
    the speed-torque line at the joint's speed (orange: the torque it gives while driving)."""
    from .machine.dynamics import sampled_torques

    if len(samples.t) < 3:
        return
    tau, qd = sampled_torques(printer, samples.q, rate)
    stall, line = torque_limit_lines(printer, qd)
    t = samples.t[: len(tau)]
    for j, ax in enumerate(axes):
        revolute = printer.limits.joints[j].kind == "revolute"
        unit = "N m" if revolute else "N"
        _series(ax, t, tau[:, j], "#7f7f7f", stall[j])
        lt, _lo, hi = _envelope(t, line[:, j])
        ax.plot(lt, hi, color="#e67e22", lw=1, drawstyle="steps-mid", label="speed-torque line")
        ax.plot(lt, -hi, color="#e67e22", lw=1, drawstyle="steps-mid")
        ax.set_title(f"{printer.limits.joints[j].name}: {'torque' if revolute else 'force'} ({unit}), "
                     f"peak {100 * _peak(tau[:, j], stall[j]):.0f} % of stall", fontsize=9)
        ax.set_xlabel("time (s)")
