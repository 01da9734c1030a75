"""Jerk on the star part (not a test): tests/test_planning_limits.py's star and zig-zag planned with
one worker at each printer's output rate, with ``[planning] jerk_limit`` on and off; prints per
printer and speed mode the print time, the planning CPU time and every joint's largest third
difference over 5 ms (``Limits`` ``third_differences``) over its jerk_max.

    python benchmarks/bench_jerk.py [PRINTER ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from deltaslice import load_printer  # noqa: E402
from deltaslice.machine.limits import third_differences  # noqa: E402
from deltaslice.planning import plan  # noqa: E402
from test_planning_limits import star_part  # noqa: E402

PRINTERS = ("delta_etitc", "linear_kossel", "fivebar_atlas", "delta_uady")


def main():
    names = sys.argv[1:] or PRINTERS
    print("| printer | mode | print s, jerk off | jerk on | ratio | jerk / jerk_max off | on | CPU s off | on |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in names:
        for mode in ("feed", "machine"):
            row = {}
            for jerk in ("off", "on"):
                printer = load_printer(name, {"planning.jerk_limit": jerk})
                t0 = time.process_time()
                traj = plan(star_part(name), printer, speed_limit=mode, workers=1)
                cpu = time.process_time() - t0
                samples = traj.samples()
                J = printer.n_joints
                d3 = np.abs(third_differences(samples.q, printer.planning.output_rate)).max(axis=0)
                row[jerk] = (traj.duration, float((d3 / printer.limits.jerk[:J]).max()), cpu)
            off, on = row["off"], row["on"]
            print(f"| {name} | {mode} | {off[0]:.2f} | {on[0]:.2f} | {on[0] / off[0]:.3f} | {off[1]:.2f} | {on[1]:.2f} | "
                  f"{off[2]:.2f} | {on[2]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
