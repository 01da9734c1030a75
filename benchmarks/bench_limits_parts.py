"""Limits on real parts at 10 kHz (not a test): parts from ../shared/parts sliced for every printer
with an extruder (the laser gets the star-and-zig-zag part of tests/test_planning_limits.py),
planned with both speed limits, sampled at 10 kHz. Prints, per printer, part and mode, the
analytic stage-wise bound and the peak joint velocity / acceleration ratios by finite differences,
the tool channel's acceleration ratio (the filament's; a laser's power has no such limit), and, for a printer with
``[dynamics]`` and torque limits on, the peak torque use read back from raw second differences
(tests/test_torque_planning.py's ``use_of``: 1 on the stall torque or the safe speed-torque line);
with ``--dense``, also how many stages' stage-wise bound is below their evaluation at 257 points
(tests/test_planning_limits.py's ``stages_below_dense``: it should be none; slower). The jerk column:
every joint's largest third difference over 5 ms (``Limits`` ``third_differences``) over its jerk_max;
``--jerk-on`` plans with ``[planning] jerk_limit = "on"`` (off by default; the print times to compare);
``--workers N`` plans with N workers (2 by default; 1 to leave a shared machine's other core alone).
A part too large for a printer is tried at half and a quarter of its size.

    python benchmarks/bench_limits_parts.py [--dense] [--jerk-on] [--workers N] [--parts A,B] [PRINTER ...]
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from deltaslice.errors import MeshError, UnreachableError  # noqa: E402
from deltaslice.pipeline import load_toolpath  # noqa: E402
from deltaslice.planning import plan  # noqa: E402
from deltaslice.machine.dynamics import sampled_torques  # noqa: E402
from deltaslice.machine.limits import third_differences  # noqa: E402
from test_planning_limits import peak_ratios, printer_at, stages_below_dense, star_part  # noqa: E402
from test_torque_planning import use_of  # noqa: E402

PARTS_DIR = ROOT.parent / "shared" / "parts"
PARTS = ("pyramid.obj", "small_dorito.obj", "extruder_idler.obj", "20mm_cube.obj")
PRINTERS = ("delta_etitc", "delta_uady", "delta_ucb", "fivebar_atlas", "linear_kossel", "delta_espe_laser")
RATE = 10000


def toolpaths(printer, name, parts=PARTS):
    """(part, scale, toolpath) for each part that fits the printer at full, half or quarter size."""
    if printer.tool.channel_kind != "extruder":
        yield "star", 1.0, star_part(name, 4)
        return
    for part in parts:
        if not (PARTS_DIR / part).exists():
            continue
        for scale in (1.0, 0.5, 0.25):
            try:
                yield part, scale, load_toolpath(str(PARTS_DIR / part), printer, scale=scale)
                break
            except (MeshError, UnreachableError):
                continue


def main():
    args = sys.argv[1:]
    dense = "--dense" in args
    jerk_on = "--jerk-on" in args
    parts, workers = PARTS, 2
    if "--workers" in args:
        at = args.index("--workers")
        workers = int(args[at + 1])
        del args[at : at + 2]
    if "--parts" in args:
        at = args.index("--parts")
        parts = tuple(args[at + 1].split(","))
        del args[at : at + 2]
    names = [a for a in args if not a.startswith("--")] or PRINTERS
    worst, below_all = 0.0, 0
    for name in names:
        printer = printer_at(name, RATE)
        if jerk_on:
            printer = dataclasses.replace(printer, planning=dataclasses.replace(printer.planning, jerk_limit="on"))
        for part, scale, tp in toolpaths(printer, name, parts):
            for mode in ("feed", "machine"):
                t0 = time.perf_counter()
                traj = plan(tp, printer, speed_limit=mode, workers=workers)
                sv, sa = traj.stage_maxima()
                samples = traj.samples()
                rv, ra = peak_ratios(printer, samples, RATE)
                J = printer.n_joints
                jerk = (np.abs(third_differences(samples.q, RATE)).max(axis=0) / printer.limits.jerk[:J]).max()
                worst = max(worst, rv.max(), ra.max())
                channel = printer.tool.channel_values(samples.e, samples.tool)
                with np.errstate(divide="ignore"):  # a laser's power has no rate limit: ratio 0
                    tool_a = np.abs(np.diff(channel, 2)).max() * RATE**2 / printer.limits.acceleration[-1]
                torque = ""
                if printer.dynamics is not None and printer.planning.torque_limit == "on":
                    tau, qd = sampled_torques(printer, samples.q, RATE, window=1.0 / RATE)
                    torque = f" torque {use_of(printer, tau, qd)[2:-2].max():.4f}"
                travels = sum(p.kind == "travel" for p in traj.pieces)
                below = ""
                if dense:
                    stages, n_below = stages_below_dense(printer, traj)
                    below_all += n_below
                    below = f" stages {stages} below dense {n_below}"
                print(f"{name:17s} {part:20s} x{scale:<5g} {mode:7s} travels {travels:5d} stage-wise "
                      f"{max(sv.max(), sa.max()):.6f}  10 kHz v {rv.max():.4f} a {ra.max():.4f} tool a {tool_a:.4f} "
                      f"jerk {jerk:.3f} print {traj.duration:.1f} s"
                      f"{torque}{below} "
                      f"({time.perf_counter() - t0:.1f} s)", flush=True)
    print(f"worst 10 kHz ratio {worst:.4f}" + (f"; stages whose bound is below their dense evaluation: {below_all}" if dense else ""))


if __name__ == "__main__":
    main()
