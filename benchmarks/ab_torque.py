"""A/B benchmark (not a test): the planning stage's CPU time and print time with the torque limits
off and on (``[planning] torque_limit``), in one process, one worker, alternating.

    python benchmarks/ab_torque.py examples/parts/calibration_cube.stl --mode machine
    python benchmarks/ab_torque.py PARTS/featuretype.STL --scale 20 --mode feed
    python benchmarks/ab_torque.py examples/parts/calibration_cube.stl --printer linear_kossel --mode machine \
        --set joints.acceleration_max=30000     # what the torque rows allow once the constant limit is lifted

The part is sliced once; each variant is planned ``--pairs`` times (``time.process_time``, which on
a shared machine counts stolen time too: the smallest of each is the least disturbed).
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from deltaslice import load_printer  # noqa: E402
from deltaslice.pipeline import load_toolpath  # noqa: E402
from deltaslice.planning import plan  # noqa: E402


def toml_value(text: str):
    """A --set value as the CLI reads it: a TOML literal (number, list, string), else the bare text."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("part")
    ap.add_argument("--printer", default="delta_etitc")
    ap.add_argument("--mode", default="feed", choices=("feed", "machine"))
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="a printer-file override for both variants (repeatable)")
    args = ap.parse_args(argv)
    overrides = {key: toml_value(text) for key, text in (o.split("=", 1) for o in args.overrides)}
    toolpath = load_toolpath(args.part, load_printer(args.printer, overrides), scale=args.scale)
    cpu = {"off": [], "on": []}
    for _ in range(args.pairs):
        for limit in cpu:
            printer = load_printer(args.printer, {**overrides, "planning.torque_limit": limit})
            t = time.process_time()
            traj = plan(toolpath, printer, speed_limit=args.mode, workers=1)
            cpu[limit].append(time.process_time() - t)
            print(f"torque_limit {limit}: planning {cpu[limit][-1]:.2f} CPU-s, print time {traj.duration:.1f} s",
                  flush=True)
    off, on = min(cpu["off"]), min(cpu["on"])
    print(f"least of {args.pairs}: off {off:.2f} CPU-s, on {on:.2f} CPU-s ({on / off:.1f}x)")


if __name__ == "__main__":
    main()
