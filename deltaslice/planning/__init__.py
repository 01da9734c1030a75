"""Planning: Toolpath -> Trajectory.

``plan(toolpath, printer)`` splits the toolpath into runs (consecutive working
moves with one tool state) and travels, plans every run time-optimally in joint
space with toppra (in parallel processes), every travel with ruckig (or toppra
when the joint-space move would not clear the part), and returns a
:class:`~.trajectory.Trajectory`. ``planner="trapezoid"`` gives the conventional
Cartesian planner instead (:mod:`.trapezoid`), made safe for the joint limits.
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from ..errors import DeltasliceError, UnreachableError
from ..toolpath import Toolpath
from .fastpath import SOLVERS
from .topp import RunSpec, plan_run
from .trajectory import Trajectory
from .travel import plan_travel

__all__ = ["plan", "Trajectory", "split_runs", "check_reachable"]

_WORKER = {}


def check_reachable(toolpath: Toolpath, printer) -> None:
    """Raise UnreachableError naming the layer and position of the first point out of reach."""
    kin = printer.kinematics()
    pts = np.concatenate([toolpath.start[None], toolpath.xyz])
    ok = kin.reachable(pts)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        layer = int(toolpath.layer[max(i - 1, 0)]) if len(toolpath) else 0
        p = pts[i]
        q = kin.inverse(p[None])[0]
        why = "no real inverse kinematics"
        if np.all(np.isfinite(q)):
            lo, hi = kin.position_min, kin.position_max
            bad = np.flatnonzero((q < lo - 1e-9) | (q > hi + 1e-9))
            if bad.size:
                j = int(bad[0])
                why = f"joint {j + 1} would be at {q[j]:.4g}, outside {lo[j]:.4g}..{hi[j]:.4g}"
            elif kin.condition(q[None])[0] >= kin.singularity_limit:
                why = f"too close to a singularity (Jacobian condition {kin.condition(q[None])[0]:.0f})"
            else:
                why = "beyond a mechanical limit (ball-joint tilt)"
        raise UnreachableError(
            f"layer {layer}: x = {p[0]:.2f}, y = {p[1]:.2f}, z = {p[2]:.2f} mm is out of reach of {printer.name} ({why})"
        )


def split_runs(toolpath: Toolpath):
    """[(i, j)] half-open ranges of working moves with one tool value each."""
    out = []
    for i, j in toolpath.runs():
        tool = toolpath.tool[i:j]
        cuts = np.flatnonzero(np.diff(tool) != 0) + 1
        edges = np.concatenate([[0], cuts, [j - i]]) + i
        out.extend(zip(edges[:-1].tolist(), edges[1:].tolist()))
    return out


def _run_spec(toolpath: Toolpath, i: int, j: int) -> RunSpec:
    start = toolpath.start if i == 0 else toolpath.xyz[i - 1]
    pts = np.concatenate([start[None], toolpath.xyz[i:j]])
    return RunSpec(pts, toolpath.feed[i:j].copy(), toolpath.e[i:j].copy(), float(toolpath.tool[i]), int(toolpath.layer[i]))


def _init_worker(printer):
    _WORKER["printer"] = printer
    _WORKER["kin"] = printer.kinematics()


def _plan_chunk(args):
    """Plan a chunk of jobs in print order: ("run", RunSpec) or ("travel", plan_travel's keywords)."""
    jobs, speed_limit, solver = args
    printer, kin = _WORKER["printer"], _WORKER["kin"]
    out = []
    for kind, job in jobs:
        if kind == "travel":
            out.append(plan_travel(kin, printer, speed_limit=speed_limit, solver=solver, **job))
            continue
        res = plan_run(kin, printer, job, speed_limit, solver=solver)
        out.append(res if isinstance(res, list) else [res])
    return out


def plan(toolpath: Toolpath, printer, *, speed_limit="feed", planner="toppra", workers=None, progress=None, solver="fast") -> Trajectory:
    """Plan a toolpath for a printer.

    speed_limit: "feed" obeys the toolpath's feed rates; "machine" only the actuators' limits.
    planner: "toppra" (time-optimal, joint space) or "trapezoid" (conventional, made safe).
    workers: processes for the runs (default: all cores). progress: callable(done, total) or None.
    solver: "fast" (:mod:`.reachability`, compiled) or "toppra" (toppra's seidel solver), for the
    time-optimal planner's runs and travels.
    """
    if speed_limit not in ("feed", "machine"):
        raise DeltasliceError(f"speed_limit must be 'feed' or 'machine', not {speed_limit!r}")
    if len(toolpath) == 0:
        raise DeltasliceError("the toolpath has no moves: nothing to plan")
    check_reachable(toolpath, printer)
    if planner == "trapezoid":
        from .trapezoid import plan_safe

        return plan_safe(toolpath, printer, speed_limit=speed_limit, progress=progress)
    if planner != "toppra":
        raise DeltasliceError(f"planner must be 'toppra' or 'trapezoid', not {planner!r}")
    if solver not in SOLVERS:
        raise DeltasliceError(f"solver must be one of {', '.join(SOLVERS)}, not {solver!r}")

    ranges = split_runs(toolpath)
    # Runs and the travels between them (and before the first / after the last), in print order;
    # a travel needs only the toolpath, so both are planned in the worker processes.
    jobs = []
    pos = toolpath.start
    printed_top = 0.0
    prev_end = 0
    for i, j in ranges:
        if i > prev_end:
            jobs.append(("travel", _travel_args(toolpath, prev_end, i, pos, printed_top)))
        jobs.append(("run", _run_spec(toolpath, i, j)))
        pos = toolpath.xyz[j - 1]
        printed_top = max(printed_top, float(toolpath.xyz[i:j, 2].max()))
        prev_end = j
    if prev_end < len(toolpath):
        jobs.append(("travel", _travel_args(toolpath, prev_end, len(toolpath), pos, printed_top)))
    workers = max(1, workers or os.cpu_count() or 1)
    pieces = []
    chunk = max(1, min(64, len(jobs) // (4 * workers) or 1))
    chunks = [jobs[k : k + chunk] for k in range(0, len(jobs), chunk)]
    results = []
    if workers == 1 or len(jobs) < 8:
        _init_worker(printer)
        for n, c in enumerate(chunks):
            results.extend(_plan_chunk((c, speed_limit, solver)))
            if progress:
                progress(n + 1, len(chunks))
    else:
        with ProcessPoolExecutor(workers, initializer=_init_worker, initargs=(printer,)) as pool:
            for n, res in enumerate(pool.map(_plan_chunk, [(c, speed_limit, solver) for c in chunks])):
                results.extend(res)
                if progress:
                    progress(n + 1, len(chunks))
    for res in results:
        pieces.extend(res)
    e_start = 0.0
    return Trajectory(printer, pieces, planner="toppra", speed_limit=speed_limit, e_start=e_start)


def _travel_args(toolpath, i, j, pos, printed_top) -> dict:
    """plan_travel's keywords for the non-working moves [i, j) that go from pos to the start of move j."""
    target = toolpath.xyz[j - 1]
    e = toolpath.e[i:j]
    layer = int(toolpath.layer[min(j, len(toolpath) - 1)])
    return dict(
        a=np.asarray(pos, float),
        b=np.asarray(target, float),
        layer=layer,
        printed_top=printed_top,
        retract=float(e[e < 0].sum()),
        unretract=float(e[e > 0].sum()),
        via=toolpath.xyz[i : j - 1].copy(),
        feed=float(toolpath.feed[i:j][np.linalg.norm(toolpath.xyz[i:j] - np.concatenate([[pos], toolpath.xyz[i : j - 1]]), axis=1) > 0].max(initial=0.0)) or None,
    )
