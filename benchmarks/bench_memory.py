"""Memory benchmark (not a test): a spiral-vase G-code from PrusaSlicer (one continuous run, no
path simplification possible: a 300-lobed wavy cylinder, r = 30 +- 0.8 mm, 0.1 mm layers) compiled
for linear_kossel, at several heights, to see how peak memory and time grow with the print.

    python benchmarks/bench_memory.py [--heights 12.5,25] [--workers 1]
    python benchmarks/bench_memory.py --spiral [--heights 12.5,25] [--trace]

Prints per height: G-code size and moves, compile wall time, plan time, peak RSS (wait4, the
process and its workers). ``--trace`` also samples the main process's RSS every 0.1 s and prints
the largest seen during each stage its progress output names (reading, planning, writing).

PrusaSlicer 2.5 does not spiral this part (its perimeters split each lobe into variable-width
pieces, no move carries both Z and E): its file is 10 layers a mm of about 1,700 short runs each.
``--spiral`` writes a true spiral-vase G-code instead (:func:`spiral_gcode`): one extrusion run
from the first move to the last, the case of a single run far too long to plan at once.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def vase(h: float, path: Path) -> None:
    import shapely.geometry as sg
    import trimesh

    th = np.linspace(0, 2 * np.pi, 6000, endpoint=False)
    r = 30 + 0.8 * np.sin(300 * th)
    trimesh.creation.extrude_polygon(sg.Polygon(np.c_[r * np.cos(th), r * np.sin(th)]), h).export(path)


def spiral_gcode(h: float, path: Path, points_per_turn: int = 2000, lobes: int = 100, pitch: float = 0.1) -> int:
    """A spiral vase as PrusaSlicer writes one (absolute E, a ;LAYER_CHANGE a turn, Z rising along
    every move): a wavy cylinder r = 30 +- 0.8 mm climbing ``pitch`` mm a turn to height h, one
    continuous extrusion. Returns its moves."""
    n = int(round(h / pitch * points_per_turn))
    k = np.arange(1, n + 1)
    th = 2 * np.pi * k / points_per_turn
    r = 30 + 0.8 * np.sin(lobes * th)
    x, y, z = r * np.cos(th), r * np.sin(th), 0.2 + pitch * k / points_per_turn
    step = np.hypot(np.diff(x, prepend=30.0), np.diff(y, prepend=0.0))
    e = np.cumsum(step * 0.45 * pitch / (np.pi * 1.75**2 / 4))
    with open(path, "w") as f:
        f.write("G21\nG90\nM82\nG92 E0\nG1 Z0.2 F7800\nG1 X30 Y0\nG1 F1800\n")
        for turn in range(0, n, points_per_turn):
            f.write(f";LAYER_CHANGE\n;Z:{z[turn]:.3f}\n")
            sl = slice(turn, turn + points_per_turn)
            f.writelines(f"G1 X{a:.3f} Y{b:.3f} Z{c:.4f} E{d:.5f}\n" for a, b, c, d in
                         zip(x[sl].tolist(), y[sl].tolist(), z[sl].tolist(), e[sl].tolist()))
    return n


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _trace(proc) -> threading.Thread:
    """A thread sampling ``proc``'s RSS every 0.1 s while reading its progress lines from stderr;
    its ``peaks`` map each stage ("start" before the first line) to the largest RSS seen in it."""
    state = {"stage": "start"}
    peaks = {}

    def read():
        buf = ""
        while ch := proc.stderr.read(1):
            if ch in "\r\n":
                if ":" in buf:
                    state["stage"] = buf.split(":")[0].strip()
                buf = ""
            else:
                buf += ch

    def sample():
        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        while proc.poll() is None:
            rss = _rss_mb(proc.pid)
            peaks[state["stage"]] = max(peaks.get(state["stage"], 0.0), rss)
            time.sleep(0.1)
        reader.join(timeout=5)

    thread = threading.Thread(target=sample, daemon=True)
    thread.peaks = peaks
    thread.start()
    return thread


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--heights", default="12.5,25")
    ap.add_argument("--workers", default="1")
    ap.add_argument("--spiral", action="store_true", help="a true spiral vase written by this script (one run)")
    ap.add_argument("--trace", action="store_true", help="the main process's peak RSS per stage, sampled every 0.1 s")
    args = ap.parse_args()
    if not args.spiral and not shutil.which("prusa-slicer"):
        sys.exit("prusa-slicer not found (apt-get install prusa-slicer)")
    d = Path(tempfile.mkdtemp())
    print("| height mm | G-code MB | moves | compile s | plan s | peak RSS MB |")
    print("|---|---|---|---|---|---|")
    for h in (float(x) for x in args.heights.split(",")):
        stl, gcode = d / f"vase{h}.stl", d / f"vase{h}.gcode"
        if args.spiral:
            spiral_gcode(h, gcode)
        else:
            vase(h, stl)
            subprocess.run(["prusa-slicer", "--export-gcode", "--spiral-vase", "--perimeters", "1", "--top-solid-layers", "0",
                            "--bottom-solid-layers", "1", "--fill-density", "0", "--layer-height", "0.1",
                            "--gcode-resolution", "0.0125", "--center", "0,0", "-o", str(gcode), str(stl)],
                           check=True, capture_output=True)
        moves = sum(1 for line in open(gcode) if line.startswith("G1"))
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "deltaslice", str(gcode), "--printer", "linear_kossel",
                                 "-o", str(d / "out.dsl"), "--workers", args.workers] + ([] if args.trace else ["--quiet"]),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        stages = _trace(proc) if args.trace else None
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        out = proc.stdout.read()
        m = re.search(r"plan ([\d.]+) s", out)
        print(f"| {h:g} | {gcode.stat().st_size / 1e6:.1f} | {moves} | {wall:.1f} | {m.group(1) if m else '?'} | "
              f"{usage.ru_maxrss / 1024:.0f} |", flush=True)
        if stages is not None:
            stages.join()
            print("    peak RSS MB by stage: " + ", ".join(f"{k} {v:.0f}" for k, v in stages.peaks.items()), flush=True)
        if os.waitstatus_to_exitcode(status) != 0:
            print(proc.stderr.read(), file=sys.stderr)
    shutil.rmtree(d)


if __name__ == "__main__":
    main()
