"""An optimistic estimate of the jerk-limited print time on the star part (not a test, not shipped
planning): bench_jerk.py's star with every RunPiece from rest to rest re-timed by a relaxation of
``planning/jerk.py``'s linear programs, every conservatism removed:

* the full jerk_max (not the planned jerk, no window factor, no step caps);
* no split between steps and changes inside a stage: only the acceleration's net change from the
  start of a stage to the start of the next (and from end to end) within J times the mean of the
  two stages' durations (the distance between their middles: two averages of a function whose
  slope is at most J over neighbouring stages differ by at most that), and from rest within J
  times half the first (last) stage's;
* a grid of STAGE on the TOPP-RA profile; passes of the convex-concave procedure (budgets over the
  durations' tangent at the last solution, which starts from the planner's, slowed uniformly until
  it keeps these rows), a trust region of GROW both ways, shrunk when a pass is slower, until one
  gains less than CONVERGED;
* no check and no slow-down afterwards.

The programs keep x <= the TOPP-RA x and the acceleration rows, as the planner does. The figure is
an estimate from below, not a proof: the rows are necessary conditions of a motion whose joint
jerk is within J if a stage's acceleration stands for its average (so the relaxed problem's
optimum is at most the true one, up to the grid's discretisation: 1 ms and 0.5 ms agree within
0.6 %), but the passes find a local optimum of a non-convex problem, and the bar's 5 ms third
differences (within 1.05 J) allow a shorter jerk above J than a bound on the jerk itself.

    python benchmarks/jerk_bound.py [--stage MS] [--scale F] [PRINTER ...]
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from deltaslice import load_printer  # noqa: E402
from deltaslice.planning import jerk as jm  # noqa: E402
from deltaslice.planning import plan  # noqa: E402
from deltaslice.planning.runpath import RunPath  # noqa: E402
from test_planning_limits import star_part  # noqa: E402

PRINTERS = ("delta_etitc", "linear_kossel", "fivebar_atlas", "delta_uady")
STAGE = 0.5e-3  # s
PASSES = 40
GROW = 2.0
CONVERGED = 1e-4
SCALE = 1.0  # of jerk_max (--scale: the bound at the planner's rate, 1 / 1.2 of 0.99)
STATS = {"violation": 0.0}


def bound_rows(first, end, k, c, g):
    """One channel's relaxed jerk rows (cols (R, 3), vals (R, 3), rhs (R,)) over y: net changes
    start to start and end to end within k times the stage's duration's tangent c + g y
    (``stage_time_tangent``, below the duration); first, end (N, 2) forms of the acceleration (of amax)."""
    N = len(c)
    i = np.arange(N - 1)
    cols = np.stack([i, i + 1, i + 2], axis=1)
    s2s = np.stack([-first[:-1, 0], first[1:, 0] - first[:-1, 1], first[1:, 1]], axis=1)
    e2e = np.stack([-end[:-1, 0], end[1:, 0] - end[:-1, 1], end[1:, 1]], axis=1)
    t = 0.5 * k * np.stack([g[:-1, 0], g[:-1, 1] + g[1:, 0], g[1:, 1]], axis=1)  # the two stages' mean
    ends_cols = np.array([[0, 1, 1], [N - 1, N, N]])
    ends_vals = np.array([[first[0, 0], first[0, 1], 0.0], [end[-1, 0], end[-1, 1], 0.0]])
    ends_t = 0.5 * k * np.array([[g[0, 0], g[0, 1], 0.0], [g[-1, 0], g[-1, 1], 0.0]])
    ends_rhs = 0.5 * k * np.array([c[0], c[-1]])
    rhs = 0.5 * k * (c[:-1] + c[1:])
    return (np.concatenate([cols, cols, cols, cols, ends_cols, ends_cols]),
            np.concatenate([s2s - t, -s2s - t, e2e - t, -e2e - t, ends_vals - ends_t, -ends_vals - ends_t]),
            np.concatenate([rhs, rhs, rhs, rhs, ends_rhs, ends_rhs]))


def relaxed_solve(x, env, dq, ddq, amax, jerk):
    """x_dot^2 (N+1,) on the grid x by the relaxed programs (module docstring)."""
    from scipy.optimize import linprog

    N, dof = dq.shape[0], dq.shape[2]
    top = float(env.max())
    d = np.diff(x)
    first, end = jm._accel_forms(d, dq, ddq, top / amax[None, None, :])
    i = np.arange(N)
    pair = np.tile(np.stack([i, i + 1, i + 1], axis=1), (4 * dof, 1))
    forms = np.concatenate([np.c_[s * f[:, :, j], np.zeros(N)] for j in range(dof) for f in (first, end)
                            for s in (1.0, -1.0)])
    limited = [j for j in range(dof) if math.isfinite(jerk[j])]
    upper = env / top
    col = np.where(upper > 0, upper, 1.0)
    # a start: the planner's own programs (feasible, so the first durations are finite)
    y = jm.solve_grid(x, env, dq, ddq, amax, jerk * jm.window_factor(), None, 2) / top
    # slowed uniformly until it keeps the relaxed rows (their ratio scales as y^1.5): from a feasible
    # point every pass is feasible (the tangent is below the duration)
    y = y / max(1.0, _ratio(x, y, top, first, end, jerk, amax, limited)) ** (2 / 3)
    grow, duration = GROW, jm.profile(x, y * top)[2][-1]
    for _ in range(PASSES):
        c, g = jm.stage_time_tangent(d, y, top)
        rows = [(pair, forms, np.ones(len(pair)))]
        rows += [bound_rows(first[:, :, j], end[:, :, j], jerk[j] / amax[j], c, g) for j in limited]
        A, b = jm._rows(*(np.concatenate(part) for part in zip(*rows)), col)
        # -dT/dy: the time's exact gradient at y (a point at rest stays there)
        weight = np.zeros(N + 1)
        weight[:-1] -= g[:, 0]
        weight[1:] -= g[:, 1]
        weight *= col
        bound = np.minimum(upper, grow * y)
        res = linprog(-weight / weight.max(), A_ub=A, b_ub=b, bounds=np.c_[y / grow / col, bound / col],
                      method="highs-ds", options={"primal_feasibility_tolerance": 1e-10})
        new = None if res.status != 0 else np.clip(res.x * col, y / grow, bound)
        trial = math.inf if new is None else jm.profile(x, new * top)[2][-1]
        if trial < duration:
            gain, y, duration = 1.0 - trial / duration, new, trial
            if gain < CONVERGED:
                break
        else:
            grow = math.sqrt(grow)
            if grow < 1.001:
                break
    STATS["violation"] = max(STATS["violation"], _ratio(x, y, top, first, end, jerk, amax, limited))
    return y * top


def _ratio(x, y, top, first, end, jerk, amax, limited) -> float:
    """The largest ratio of a relaxed row's left side to its budget at y's own durations."""
    dt = np.diff(jm.profile(x, y * top)[2])
    worst = 0.0
    for j in limited:
        cols, vals, rhs = bound_rows(first[:, :, j], end[:, :, j], jerk[j] / amax[j], dt, np.zeros((len(dt), 2)))
        lhs = (vals * y[cols]).sum(axis=1)
        worst = max(worst, float(np.max(lhs / np.maximum(rhs, 1e-300))))
    return worst


def bound_run(ctx, piece):
    """The relaxed re-timing of one RunPiece from rest to rest (no check, no slow-down)."""
    if len(piece.xdd) == 0 or piece.xd[0] != 0 or piece.xd[-1] != 0:
        return piece
    e_ratio, planned, true, c = jm._channels(ctx, piece)
    jerk = true.jerk[:c] * SCALE
    if not np.any(np.isfinite(jerk)):
        return piece
    rp = RunPath(ctx.kin, piece.path, e_ratio, piece.layer)
    with np.errstate(divide="ignore"):
        path_jerk = float(np.min(jerk / np.abs(rp.stage_derivatives(piece.x, np.array([0.5]))[0][:, 0]).max(axis=0)))
    x, env = jm.fine_grid(piece, path_jerk)
    dq, ddq = rp.stage_derivatives(x, np.array([0.0, 1.0]))
    y = relaxed_solve(x, env, dq, ddq, planned.acceleration[:c], jerk)
    xd, xdd, t = jm.profile(x, y)
    return replace(piece, x=x, xd=xd, xdd=xdd, t=t, active_time=float(t[-1]))


def main():
    global STAGE, SCALE
    args = sys.argv[1:]
    while args[:1] in (["--stage"], ["--scale"]):
        if args[0] == "--stage":
            STAGE = float(args[1]) * 1e-3
        else:
            SCALE = float(args[1])
        args = args[2:]
    names = args or PRINTERS
    jm.STAGE = STAGE
    jm.limit_run = bound_run
    print(f"stage {STAGE * 1e3:g} ms, jerk_max x {SCALE:g}")
    print("| printer | mode | print s, jerk off | bound | ratio | row violation | CPU s |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        for mode in ("feed", "machine"):
            off = plan(star_part(name), load_printer(name, {"planning.jerk_limit": "off"}), speed_limit=mode,
                       workers=1).duration
            STATS["violation"] = 0.0
            t0 = time.process_time()
            on = plan(star_part(name), load_printer(name, {"planning.jerk_limit": "on"}), speed_limit=mode,
                      workers=1).duration
            cpu = time.process_time() - t0
            print(f"| {name} | {mode} | {off:.2f} | {on:.2f} | {on / off:.3f} | {STATS['violation']:.3f} | {cpu:.0f} |",
                  flush=True)


if __name__ == "__main__":
    main()
