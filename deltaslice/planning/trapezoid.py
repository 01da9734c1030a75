"""The conventional planner, as Marlin and Klipper do it: the baseline.

Every move is a constant-acceleration trapezoid in Cartesian space with one
uniform max velocity V (capped by the move's feed) and acceleration A; corners
are taken at the junction-deviation speed ``v^2 = A * jd * sin(t/2) / (1 - sin(t/2))``
(t: angle between the directions as Marlin defines it), an instantaneous change
of velocity direction. Lookahead (backward then forward pass) makes every move
reachable from its neighbours. Both passes are the min-plus recurrence
``w_k = min(J_k, w_{k+1} + 2 A L_k)`` on squared speeds, solved for all moves at
once as a reversed cumulative minimum.

Two settings:

* :func:`plan_firmware`: typical delta settings, corners as firmware runs them
  (the joint-limit violations users get today),
* :func:`plan_safe`: the largest uniform limits (one scale k on A and jd, sqrt(k)
  on V, keeping the braking distance V^2/A) whose samples keep every joint within
  its velocity and acceleration limits at the output rate, found by bisection.
"""

from __future__ import annotations

import numpy as np

from ..machine.limits import LimitMonitor
from .context import PlanContext
from .pieces import TrapezoidPiece
from .tolerances import DIVISION_FLOOR, NO_MOTION, SMALLEST_SCALE, STRAIGHT
from .trajectory import Trajectory

FIRMWARE_ACCEL = 3000.0  # mm/s^2, Marlin's delta default
FIRMWARE_SCV = 5.0  # mm/s, Klipper's default square corner velocity
FIRMWARE_VMAX = 300.0  # mm/s
SAFE_TOLERANCE = 1.0  # samples may reach 100 % of a limit, no more


def _moves(toolpath):
    """The moves the trapezoid planner plans: (starts, deltas, lengths, filament-only, kept mask)."""
    starts = toolpath.starts
    delta = toolpath.xyz - starts
    length = np.linalg.norm(delta, axis=1)
    filament_only = (length <= NO_MOTION) & (toolpath.e != 0)
    keep = (length > NO_MOTION) | filament_only
    return starts[keep], delta[keep], length[keep], filament_only[keep], keep


def build(toolpath, ctx: PlanContext, *, accel, jd, vmax) -> TrapezoidPiece:
    """Plan all moves with uniform Cartesian limits (A = accel, junction deviation jd, V = vmax), under
    the context's speed limit; the tool channel keeps to its planned limits."""
    speed_limit = ctx.speed_limit
    p0, delta, length, fil, keep = _moves(toolpath)
    feed = toolpath.feed[keep]
    e = toolpath.e[keep]
    tool = toolpath.tool[keep]
    n = len(length)
    d = np.where(length[:, None] > 0, delta / np.where(length > 0, length, 1)[:, None], 0.0)
    top = np.minimum(feed, vmax) if speed_limit == "feed" else np.full(n, vmax)
    a = np.full(n, float(accel))
    # Firmware caps every move so the extruder stays within its max feed rate (Marlin's
    # max_feedrate E); here that is the hot end's volumetric limit (a laser's e is zero).
    # the tool channel keeps the margin the planner keeps on every channel
    tool_v, tool_a = ctx.planned_limits.velocity[-1], ctx.retract_acceleration
    with np.errstate(divide="ignore"):
        ratio = np.where(length > 0, np.abs(e) / np.where(length > 0, length, 1), 0.0)
        top = np.minimum(top, np.where(ratio > 0, tool_v / ratio, np.inf))
    if fil.any():  # retracts at rest: only extruders have them
        top = np.where(fil, ctx.retract_speed, top)
        a = np.where(fil, tool_a, a)
    L = np.where(fil, np.abs(e), length)

    # Junction speed limits at the start of each move (squared).
    cos_t = -np.einsum("ij,ij->i", d[:-1], d[1:])  # Marlin: -dot(prev, next)
    sin_half = np.sqrt(np.clip(0.5 * (1 - cos_t), 0, 1))
    with np.errstate(divide="ignore", invalid="ignore"):
        vj2 = np.where(sin_half < 1 - STRAIGHT, accel * jd * sin_half / (1 - sin_half), np.inf)
    both_move = ~fil[:-1] & ~fil[1:]
    vj2 = np.where(both_move, vj2, 0.0)
    vj2 = np.minimum(vj2, np.minimum(top[:-1], top[1:]) ** 2)
    J = np.concatenate([[0.0], vj2, [0.0]])  # junction k is the start of move k; rest at both ends

    # Backward pass: w_k <= w_{k+1} + 2 a_k L_k  (reachable deceleration).
    two_al = 2 * a * L
    C = np.concatenate([[0.0], np.cumsum(two_al)])
    back = np.minimum.accumulate((J + C)[::-1])[::-1] - C
    # Forward pass: w_{k+1} <= w_k + 2 a_k L_k.
    fwd = np.minimum.accumulate(back - C) + C
    w = np.maximum(np.minimum(back, fwd), 0.0)
    v_in, v_out = np.sqrt(w[:-1]), np.sqrt(w[1:])
    # Peak speed of each trapezoid: the cruise speed or where acceleration meets deceleration.
    v_peak = np.sqrt(np.maximum((2 * a * L + v_in**2 + v_out**2) / 2, 0))
    v_top = np.maximum(np.minimum(top, v_peak), np.maximum(v_in, v_out))
    la = (v_top**2 - v_in**2) / (2 * a)
    ld = (v_top**2 - v_out**2) / (2 * a)
    tc = np.maximum(L - la - ld, 0) / np.maximum(v_top, DIVISION_FLOOR)
    t = (v_top - v_in) / a + (v_top - v_out) / a + tc
    t0 = np.concatenate([[0.0], np.cumsum(t)])
    e0 = np.concatenate([[0.0], np.cumsum(e)])[:-1]
    q_ends = ctx.kin.inverse(np.array([p0[0], p0[-1] + d[-1] * length[-1]]))
    return TrapezoidPiece(p0, d, L, v_in, v_top, v_out, a, t0, e0, e, tool, fil, q_ends[0], q_ends[1])


def plan_firmware(toolpath, printer, *, speed_limit="feed", accel=FIRMWARE_ACCEL, scv=FIRMWARE_SCV, vmax=FIRMWARE_VMAX):
    """The conventional planner with typical delta firmware settings (Klipper-style
    square corner velocity converted to junction deviation)."""
    jd = scv**2 * (np.sqrt(2) - 1) / accel
    piece = build(toolpath, PlanContext.of(printer, speed_limit), accel=accel, jd=jd, vmax=vmax)
    info = {"accel": accel, "junction_deviation": jd, "vmax": vmax, "setting": "firmware"}
    return Trajectory(printer, [piece], planner="trapezoid-firmware", speed_limit=speed_limit, info=info)


def _monitor(traj: Trajectory, rate: float, workers: int = 1) -> LimitMonitor:
    """The monitor of ``traj`` sampled at ``rate`` by ``workers`` processes (the same samples, and
    the same peaks, for any number: the monitor copies what it keeps of a block)."""
    ctx = PlanContext.of(traj.printer)
    blocks = traj.iter_samples(rate, workers=workers, transient=True) if workers > 1 else traj.iter_samples(rate)
    return LimitMonitor(ctx.machine_limits, ctx.tool, rate).consume(blocks)


def peak_ratio(traj: Trajectory, rate: float, workers: int = 1) -> float:
    """Largest sampled |joint velocity| / limit or |joint acceleration| / limit (sampled by
    ``workers`` processes)."""
    return _monitor(traj, rate, workers).worst


def plan_safe(toolpath, printer, *, speed_limit="feed", progress=None, iterations=14, head=(), tail=(), workers=1):
    """The conventional planner with the largest uniform limits that keep every joint
    within its limits at the output rate (bisection on one scale k). head, tail: pieces
    before and after the toolpath (the moves from and to rest); they are part of what is
    sampled, so the samples checked are the samples written. workers: processes sampling each
    candidate for its peak check (the same plan for any number)."""
    ctx = PlanContext.of(printer, speed_limit)
    rate = ctx.output_rate
    lo, hi = 0.0, 1.0
    jd0 = FIRMWARE_SCV**2 * (np.sqrt(2) - 1) / FIRMWARE_ACCEL

    def make(k):
        piece = build(toolpath, ctx, accel=FIRMWARE_ACCEL * k, jd=jd0 * k, vmax=FIRMWARE_VMAX * np.sqrt(k))
        info = {"accel": FIRMWARE_ACCEL * k, "junction_deviation": jd0 * k, "vmax": FIRMWARE_VMAX * np.sqrt(k), "scale": k}
        return Trajectory(printer, [*head, piece, *tail], planner="trapezoid-safe", speed_limit=speed_limit, info=info)

    if peak_ratio(make(1.0), rate, workers) <= SAFE_TOLERANCE:
        return make(1.0)
    for it in range(iterations):
        mid = 0.5 * (lo + hi) if lo > 0 else hi / 4
        if peak_ratio(make(mid), rate, workers) <= SAFE_TOLERANCE:
            lo = mid
        else:
            hi = mid
        if progress:
            progress(it + 1, iterations)
    if lo == 0.0:
        lo = hi / 4
        while peak_ratio(make(lo), rate, workers) > SAFE_TOLERANCE and lo > SMALLEST_SCALE:
            lo /= 4
    return make(lo)


def corner_violations(traj: Trajectory, rate: float | None = None) -> dict:
    """Joint-limit violations of a trajectory sampled at the output rate: how many
    samples and distinct events (consecutive violating samples count once) exceed a
    velocity or acceleration limit, and the worst ratios."""
    rate = rate or traj.printer.planning.output_rate
    m = _monitor(traj, rate)
    return {
        "violating_samples": m.violating_samples,
        "events": m.events,
        "worst_velocity_ratio": float(m.peak_v.max(initial=0)),
        "worst_acceleration_ratio": float(m.peak_a.max(initial=0)),
    }
