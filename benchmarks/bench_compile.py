"""Compile benchmark (not a test): deltaslice's full compile (slice + plan + emit) against
PrusaSlicer's slice of the same mesh, with the fast solver, toppra's solver and the conventional
planner (``--planner trapezoid``), on delta_etitc.

    python benchmarks/bench_compile.py [--runs 3] [--toppra-runs 1] [--parts tube,featuretype,...]

Each compile is a whole process (``python -m deltaslice PART --printer ... -o out.dsl --quiet``),
the variants alternating run by run so drift hits them alike; medians. Its summary gives the
slice / plan / total wall time measured inside the process (emit = total - slice - plan; start-up
and imports are the process wall time minus total; a mesh's slice holds numba's import and first
load, which run while the slicing workers slice) and the planned print time; peak RSS is the
largest of the process and its planning workers (``wait4``). PrusaSlicer gets the equivalent ini
of ``bench_slicing.py`` and the same scale. The tube is the ~4,000-triangle part of
``bench_planning.py``; the others come from ../shared/parts (skipped when absent).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_planning import tube_part  # noqa: E402
from bench_slicing import prusa_ini  # noqa: E402

PARTS = {
    "tube": (None, 1.0),
    "featuretype": ("featuretype.STL", 20.0),
    "counter": ("counter.unitsmm.STL", 0.33),
    "extruder_idler": ("extruder_idler.obj", 1.0),
}


def run_rss(cmd):
    """Like run, with the peak RSS (MB) of the process and its reaped children via wait4."""
    t0 = time.perf_counter()
    out_f, err_f = tempfile.TemporaryFile("w+"), tempfile.TemporaryFile("w+")
    proc = subprocess.Popen(cmd, stdout=out_f, stderr=err_f, text=True, cwd=ROOT)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    out_f.seek(0)
    err_f.seek(0)
    return wall, usage.ru_maxrss / 1024, proc.returncode, out_f.read(), err_f.read()


def parse(summary: str) -> dict:
    m = re.search(r"wall time: slice ([\d.]+) s, plan ([\d.]+) s, total ([\d.]+) s", summary)
    d = re.search(r"print time: ([\d.]+) s", summary)
    if not m or not d:
        return {}
    sl, pl, tot = map(float, m.groups())
    return {"slice": sl, "plan": pl, "emit": tot - sl - pl, "total": tot, "duration": float(d.group(1))}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--toppra-runs", type=int, default=1, help="runs with --solver toppra (slow)")
    ap.add_argument("--parts", default=",".join(PARTS))
    ap.add_argument("--printer", default="printers/delta_etitc.toml")
    args = ap.parse_args()
    shared = ROOT.parent / "shared" / "parts"
    printer_path = str(ROOT / args.printer)
    prusa = shutil.which("prusa-slicer")
    tmp = Path(tempfile.mkdtemp(prefix="bench_compile_"))
    from deltaslice import load_printer

    ini = tmp / "prusa.ini"
    ini.write_text(prusa_ini(load_printer(printer_path)))
    rows = []
    for name in args.parts.split(","):
        fname, scale = PARTS[name]
        if fname is None:
            part = tmp / "tube.stl"
            tube_part(part, 25.0, 20.0)
        else:
            part = shared / fname
            if not part.exists():
                print(f"skip {name}: {part} absent", file=sys.stderr)
                continue
        base = [sys.executable, "-m", "deltaslice", str(part), "--printer", printer_path, "-o", str(tmp / f"{name}.dsl"),
                "--quiet", "--scale", str(scale)]
        variants = {
            "fast": base + ["--solver", "fast"],
            "trapezoid": base + ["--planner", "trapezoid"],
            "toppra": base + ["--solver", "toppra"],
        }
        if prusa:
            variants["prusa"] = [prusa, "--export-gcode", "--load", str(ini), "--scale", str(scale), str(part), "-o", str(tmp / f"{name}.gcode")]
        res = {k: [] for k in variants}
        errors = {}
        for r in range(args.runs):
            for k, cmd in variants.items():
                if k == "toppra" and r >= args.toppra_runs:
                    continue
                if k in errors:
                    continue
                wall, rss, rc, out, err = run_rss(cmd)
                if rc != 0:
                    errors[k] = (err.strip().splitlines() or ["?"])[-1]
                    continue
                res[k].append({"wall": wall, "rss": rss, **parse(out)})
                print(f"{name} {k} run {r}: {wall:.2f} s, {rss:.0f} MB", file=sys.stderr)
        rows.append((name, scale, res, errors))

    def med(lst, key):
        vals = [x[key] for x in lst if key in x]
        return statistics.median(vals) if vals else float("nan")

    print(f"printer {Path(args.printer).stem}; medians of {args.runs} alternating runs ({args.toppra_runs} with --solver toppra); seconds; peak RSS MB")
    print("| part (scale) | variant | process wall | slice | plan | emit | start-up | peak RSS | print time s | / PrusaSlicer |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, scale, res, errors in rows:
        ps = med(res.get("prusa", []), "wall")
        for k in ("fast", "toppra", "trapezoid", "prusa"):
            if k in errors:
                print(f"| {name} ({scale:g}) | {k} | failed: {errors[k]} | | | | | | | |")
                continue
            lst = res.get(k, [])
            if not lst:
                continue
            w = med(lst, "wall")
            if k == "prusa":
                print(f"| {name} ({scale:g}) | PrusaSlicer slice | {w:.2f} | | | | | {med(lst, 'rss'):.0f} | | 1.00x |")
                continue
            start = w - med(lst, "total")
            print(f"| {name} ({scale:g}) | {k} | {w:.2f} | {med(lst, 'slice'):.2f} | {med(lst, 'plan'):.2f} | {med(lst, 'emit'):.2f} "
                  f"| {start:.2f} | {med(lst, 'rss'):.0f} | {med(lst, 'duration'):.2f} | {w / ps:.1f}x |")
        if res.get("fast") and res.get("toppra"):
            a, b = med(res["fast"], "duration"), med(res["toppra"], "duration")
            print(f"| {name} ({scale:g}) | fast vs toppra print time | {100 * (a / b - 1):+.4f} % | | | | | | | |")
    print(f"(outputs in {tmp})")


if __name__ == "__main__":
    main()
