"""A/B benchmark (not a test): planning CPU time of this checkout against another source tree
(a git worktree of an earlier commit) on one part, one worker, processes alternating.

    git worktree add /tmp/base 6e4ac4b
    python benchmarks/ab_plan.py --base /tmp/base [--part featuretype.STL --scale 20] [--pairs 3] [--workers 2]

Each process slices the part, plans it once to warm up, then twice more, and reports the smaller
CPU time of the two (``time.process_time``: on this shared machine it counts the stolen time too,
so pairs are what compare; the smaller of two is the least disturbed). Prints per pair both times
and their ratio, the median ratio, and the print time each tree planned (they should agree).
With ``--workers N`` (N > 1) the planning runs in N worker processes and the wall time is
compared instead (this process's CPU would leave the workers' out). The processes alternate
which tree goes first. Compile both trees' bytecode first (``python -m compileall -q deltaslice``):
where PYTHONDONTWRITEBYTECODE is set, a fresh worktree has none.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PARTS = ROOT.parent / "shared" / "parts"

# Run with the tree as the working directory: ``python -c`` puts it first on sys.path, ahead of
# an editable install of this checkout.
PROBE = """
import sys, time, warnings
warnings.simplefilter("ignore")
from deltaslice import load_printer
from deltaslice.pipeline import load_toolpath
from deltaslice.planning import plan
printer = load_printer(sys.argv[1])
toolpath = load_toolpath(sys.argv[2], printer, scale=float(sys.argv[3]))
workers = int(sys.argv[4])
clock = time.process_time if workers == 1 else time.perf_counter
plan(toolpath, printer, workers=workers)
cpu = []
for _ in range(2):
    c = clock()
    traj = plan(toolpath, printer, workers=workers)
    cpu.append(clock() - c)
print(min(cpu), traj.duration)
"""


def measure(tree: Path, printer: str, part: str, scale: float, workers: int) -> tuple[float, float]:
    out = subprocess.run([sys.executable, "-c", PROBE, printer, part, str(scale), str(workers)], cwd=tree, check=True,
                         capture_output=True, text=True).stdout.split()
    return float(out[0]), float(out[1])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--base", required=True, help="the other source tree (a git worktree)")
    ap.add_argument("--part", default="featuretype.STL", help="a mesh or G-code; relative: in ../shared/parts")
    ap.add_argument("--scale", type=float, default=20.0)
    ap.add_argument("--printer", default=str(ROOT / "printers" / "delta_etitc.toml"))
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--workers", type=int, default=1, help="planning workers (over 1: wall time, not CPU)")
    args = ap.parse_args()
    part = Path(args.part) if Path(args.part).is_absolute() else PARTS / args.part
    if not part.exists():
        sys.exit(f"{part} not found")
    base = Path(args.base).resolve()
    what = "CPU" if args.workers == 1 else f"wall ({args.workers} workers)"
    print(f"| pair | this tree {what} s | base {what} s | ratio | print time s (this / base) |")
    print("|---|---|---|---|---|")
    ratios = []
    for k in range(args.pairs):
        order = (ROOT, base) if k % 2 == 0 else (base, ROOT)
        got = {tree: measure(tree, args.printer, str(part), args.scale, args.workers) for tree in order}
        (new, d_new), (old, d_old) = got[ROOT], got[base]
        ratios.append(new / old)
        print(f"| {k + 1} | {new:.2f} | {old:.2f} | {new / old:.3f} | {d_new:.4f} / {d_old:.4f} |", flush=True)
    print(f"\nmedian ratio (this tree / base): {statistics.median(ratios):.3f}")


if __name__ == "__main__":
    main()
