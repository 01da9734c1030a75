"""Realistic synthetic trajectories for the emit and verify tests (no planner needed).

A small print is laid out in the bed frame (per layer: circular perimeters, then a
zig-zag infill with sharp turns, joined by travels), densely resampled, given a
speed profile that respects a Cartesian acceleration bound (full stop at sharp
corners, ``v <= sqrt(a / curvature)`` on arcs, forward/backward acceleration
passes, all vectorised), sampled at the printer's rate and mapped to joints
through the printer's inverse kinematics. The filament position rises in
proportion to the extruded arc length. The result stays well inside the joint
limits of the shipped printers (checked by ``tests/test_verify.py``).
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from deltaslice.machine import load_printer
from deltaslice.samples import Samples
from deltaslice.toolpath import Role, ToolpathBuilder

ROOT = Path(__file__).resolve().parents[1]
PRINTERS = ROOT / "printers"


# Cartesian acceleration bound (mm/s^2) that keeps each machine's joints inside their limits
ACCEL: dict[str, float] = {}  # default 1500; all shipped printers stay within limits at 3000
SIZE = {"delta_ucb": 20.0}


@lru_cache(maxsize=None)
def printer(name: str = "delta_etitc"):
    return load_printer(PRINTERS / f"{name}.toml")


def _circle(cx, cy, r, z, step=0.5):
    n = max(16, int(math.ceil(2 * math.pi * r / step)))
    a = np.linspace(0.0, 2 * math.pi, n + 1)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a), np.full(n + 1, z)])


def _zigzag(half, spacing, z, angle):
    ys = np.arange(-half, half + 1e-9, spacing)
    pts = []
    for i, y in enumerate(ys):
        xs = (-half, half) if i % 2 == 0 else (half, -half)
        pts += [(xs[0], y), (xs[1], y)]
    p = np.array(pts, float)
    c, s = math.cos(angle), math.sin(angle)
    p = p @ np.array([[c, s], [-s, c]])
    return np.column_stack([p, np.full(len(p), z)])


def layout(layers: int = 2, size: float = 30.0, feeds=(30.0, 60.0, 130.0)):
    """A list of (polyline (m,3) mm, feed mm/s, extruding bool) in print order."""
    perim_feed, infill_feed, travel_feed = feeds
    moves = []
    pos = np.array([0.0, 0.0, 0.5])
    for k in range(layers):
        z = 0.5 + 0.4 * k
        for i in range(3):
            r = size / 2 - 0.5 * i
            c = _circle(0.0, 0.0, r, z)
            moves.append((np.vstack([pos, c[0]]), travel_feed, False))
            moves.append((c, perim_feed, True))
            pos = c[-1]
        zz = _zigzag(size / 2 / math.sqrt(2) - 1.5, 1.3, z, math.radians(45 + 90 * k))
        moves.append((np.vstack([pos, zz[0]]), travel_feed, False))
        moves.append((zz, infill_feed, True))
        pos = zz[-1]
    return moves


def _densify(poly, ds):
    seg = np.diff(poly, axis=0)
    length = np.linalg.norm(seg, axis=1)
    keep = length > 1e-12
    poly = np.vstack([poly[:1], poly[1:][keep]])
    seg, length = seg[keep], length[keep]
    s_knots = np.concatenate([[0.0], np.cumsum(length)])
    n = max(2, int(math.ceil(s_knots[-1] / ds)) + 1)
    s = np.linspace(0.0, s_knots[-1], n)
    s = np.union1d(s, s_knots)  # keep every corner
    pts = np.column_stack([np.interp(s, s_knots, poly[:, d]) for d in range(3)])
    return s, pts


def _speed_profile(s, pts, feed, accel):
    """v(s): feed cap, curvature cap, zero at both ends, |dv/dt| <= accel (trapezoids)."""
    n = len(s)
    cap = np.full(n, float(feed))
    if n > 2:
        a, b, c = pts[:-2], pts[1:-1], pts[2:]
        ab, bc, ca = (np.linalg.norm(x, axis=1) for x in (b - a, c - b, a - c))
        cross = np.linalg.norm(np.cross(b - a, c - b), axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            kappa = np.where(ab * bc * ca > 0, 2 * cross / (ab * bc * ca), 0.0)
        cos_turn = np.einsum("ij,ij->i", b - a, c - b) / np.maximum(ab * bc, 1e-300)
        with np.errstate(divide="ignore"):
            vk = np.where(kappa > 1e-9, np.sqrt(accel / np.maximum(kappa, 1e-12)), np.inf)
        vk = np.where(cos_turn < math.cos(math.radians(20)), 0.0, vk)  # sharp corner: stop
        cap[1:-1] = np.minimum(cap[1:-1], vk)
    cap[0] = cap[-1] = 0.0
    u = cap**2
    two_a = 2 * accel * np.diff(s)
    # forward pass u_i = min(cap_i^2, u_{i-1} + 2 a ds), vectorised with a running minimum
    acc = np.concatenate([[0.0], np.cumsum(two_a)])
    u = np.minimum(u, acc + np.minimum.accumulate(u - acc))
    acc_b = np.concatenate([[0.0], np.cumsum(two_a[::-1])])
    ur = u[::-1]
    ur = np.minimum(ur, acc_b + np.minimum.accumulate(ur - acc_b))
    return np.sqrt(np.maximum(ur[::-1], 0.0))


def realistic(printer_name: str = "delta_etitc", layers: int = 2, accel: float | None = None, size: float | None = None,
              rate: float | None = None, feeds=(30.0, 60.0, 130.0)):
    """(Samples, Toolpath) of a small print on that printer, sampled at its output rate.

    Consecutive moves start and end at rest, so joint motion is continuous."""
    p = printer(printer_name)
    rate = rate or p.planning.output_rate
    accel = accel or ACCEL.get(printer_name, 1500.0)
    size = size or SIZE.get(printer_name, 30.0)
    tool_cfg = p.tool
    layer_h, width = 0.4, 0.5
    # filament per mm of path: a 0.4 x 0.5 mm bead, reduced if the fastest working feed would
    # then exceed 80 % of the hot end's melt rate
    e_per_mm = 0.0 if p.is_laser else min(layer_h * width / tool_cfg.filament_area,
                                          0.8 * tool_cfg.max_filament_speed / max(feeds[:2]))
    builder = ToolpathBuilder(start=(0.0, 0.0, 0.5))
    builder.new_layer(0.5)
    t_all, x_all, e_all, tool_all = [], [], [], []
    t0, e0 = 0.0, 0.0
    for poly, feed, extruding in layout(layers, size, feeds):
        s, pts = _densify(poly, 0.05)
        v = _speed_profile(s, pts, feed, accel)
        dt = 2 * np.diff(s) / np.maximum(v[1:] + v[:-1], 1e-12)
        t = np.concatenate([[0.0], np.cumsum(dt)])
        k0 = int(math.ceil(t0 * rate - 1e-9))
        ts = np.arange(k0, int(math.floor((t0 + t[-1]) * rate)) + 1) / rate
        # exact constant-acceleration motion inside each interval (no kinks from linear interpolation)
        tau_all = np.clip(ts - t0, 0.0, t[-1])
        k = np.clip(np.searchsorted(t, tau_all, side="right") - 1, 0, len(s) - 2)
        acc_k = (v[1:] ** 2 - v[:-1] ** 2) / (2 * np.maximum(np.diff(s), 1e-300))
        tau = tau_all - t[k]
        ss = np.minimum(s[k] + v[k] * tau + 0.5 * acc_k[k] * tau**2, s[k + 1])
        xyz = np.column_stack([np.interp(ss, s, pts[:, d]) for d in range(3)])
        tool_on = 1.0 if extruding else 0.0
        t_all.append(ts)
        x_all.append(xyz)
        e_all.append(e0 + (ss * e_per_mm if extruding else 0.0 * ss))
        tool_all.append(np.full(len(ts), tool_on))
        t0 += t[-1]
        if extruding:
            e0 += s[-1] * e_per_mm
        # toolpath: the polyline's vertices (a chord every 0.5 mm on arcs)
        fil = np.linalg.norm(np.diff(poly, axis=0), axis=1) * e_per_mm if extruding else np.zeros(len(poly) - 1)
        builder.add(poly[1:], feed, fil, tool_on, Role.PERIMETER if extruding else Role.TRAVEL)
    t = np.concatenate(t_all)
    # consecutive moves meet at rest at the same point: drop duplicate time stamps
    t, idx = np.unique(np.round(t * rate).astype(np.int64), return_index=True)
    xyz = np.concatenate(x_all)[idx]
    q = p.kinematics().inverse(xyz)
    if not np.all(np.isfinite(q)):
        raise ValueError("synthetic path leaves the workspace")
    samples = Samples(t / rate, q, np.concatenate(e_all)[idx], np.concatenate(tool_all)[idx])
    return samples, builder.build()


def blocks(samples: Samples, size: int = 4096):
    """Split Samples into consecutive blocks, as Trajectory.iter_samples does."""
    for i in range(0, len(samples), size):
        sl = slice(i, i + size)
        yield Samples(samples.t[sl], samples.q[sl], samples.e[sl], samples.tool[sl])


def long_print(samples: Samples, n_total: int):
    """Tile a trajectory (it starts and ends at rest at the same pose? no: joined by its
    own start) to n_total samples as blocks, for timing; e grows continuously."""
    n = len(samples)
    rate = 1.0 / (samples.t[1] - samples.t[0])
    # a palindrome tiles smoothly: forward then backward, e keeps rising
    q2 = np.concatenate([samples.q, samples.q[::-1]])
    de = np.abs(np.diff(np.concatenate([samples.e, samples.e[::-1]]), prepend=samples.e[0]))
    tool2 = np.concatenate([samples.tool, samples.tool[::-1]])
    period = 2 * n
    done, e_off = 0, 0.0
    while done < n_total:
        k = min(period, n_total - done)
        e = e_off + np.cumsum(de[:k])
        yield Samples(np.arange(done, done + k) / rate, q2[:k], e, tool2[:k])
        e_off = e[-1]
        done += k


def finite_differences(samples, rate):
    """Brute force, independent of the package: joint velocity (np.gradient) and acceleration
    (second differences, zero at both ends) at the output rate, (n, J) each."""
    q = samples.q
    v = np.gradient(q, 1.0 / rate, axis=0)
    a = np.zeros_like(q)
    if len(q) > 2:
        a[1:-1] = (q[2:] - 2 * q[1:-1] + q[:-2]) * rate * rate
    return v, a
