"""Laser benchmark (not a test): print time of a vector engraving on delta_espe_laser,
deltaslice's time-optimal planner against the conventional Cartesian planner made safe
(``--planner trapezoid``), on the same toolpath, with ``--speed-limit machine`` (the natural
mode for engraving) and, for context, ``feed``.

    python benchmarks/bench_laser.py [--runs 3] [--width 60]

The job is the example's generated badge (examples/engrave_image.py: frame, disc, ring,
grey ramp), traced in vector mode. The planners run alternately ``--runs`` times; print
times are deterministic (the trajectory's duration), wall times are medians. Prints a
Markdown table.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "examples"))

from engrave_image import draw_badge  # noqa: E402

from deltaslice import load_printer  # noqa: E402
from deltaslice.engrave import engrave  # noqa: E402
from deltaslice.planning import plan  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--width", type=float, default=60.0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    printer = load_printer(ROOT / "printers" / "delta_espe_laser.toml")
    with tempfile.TemporaryDirectory() as tmp:
        image = Path(tmp) / "badge.png"
        draw_badge(image)
        toolpath = engrave(image, printer, {"mode": "vector", "width": args.width})
    s = toolpath.summary()
    print(f"job: badge.png, vector, {args.width:g} mm wide: {s['moves']} moves, {len(toolpath.runs())} strokes, "
          f"{s['working_length_mm']:.0f} mm burnt, {s['travel_length_mm']:.0f} mm of travel\n")
    print("| speed limit | planner | print time s | planning wall s (median) |")
    print("|---|---|---|---|")
    for speed_limit in ("machine", "feed"):
        times = {"toppra": [], "trapezoid": []}
        wall = {"toppra": [], "trapezoid": []}
        for _ in range(args.runs):
            for planner in ("toppra", "trapezoid"):  # alternating, so load drifts hit both alike
                t0 = time.perf_counter()
                traj = plan(toolpath, printer, speed_limit=speed_limit, planner=planner, workers=args.workers)
                wall[planner].append(time.perf_counter() - t0)
                times[planner].append(traj.duration)
        for planner in ("toppra", "trapezoid"):
            print(f"| {speed_limit} | {planner} | {np.median(times[planner]):.2f} | {np.median(wall[planner]):.2f} |")
        ratio = np.median(times["trapezoid"]) / np.median(times["toppra"])
        print(f"| {speed_limit} | **trapezoid / toppra** | **{ratio:.2f}x** | |")


if __name__ == "__main__":
    main()
