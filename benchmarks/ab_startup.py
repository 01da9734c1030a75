"""A/B benchmark (not a test): wall time from the process's start to the start of planning (start-up
and slicing, where numba loads beside the slicing workers) of this checkout against another
source tree, the command line as a user runs it, the two trees in a random order each round.

    git worktree add /tmp/base 5737ad1
    python benchmarks/ab_startup.py --base /tmp/base [--part featuretype.STL --scale 20] [--rounds 15]

Each run is the CLI's compile with ``planning.plan`` replaced by an exit that prints the time
since the interpreter started running this probe. Prints each round's two times and their
ratio, then the median of each tree and of the ratios, and in how many rounds this tree was the
faster. Compile both trees' bytecode first (``python -m compileall -q deltaslice``).
"""

from __future__ import annotations

import argparse
import random
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PARTS = ROOT.parent / "shared" / "parts"

# Run with the tree as the working directory and first on sys.path (ahead of an editable install).
PROBE = """
import os, sys, time
start = time.perf_counter()
sys.path.insert(0, os.getcwd())
import runpy
import deltaslice.planning as planning
def stop(*args, **kwargs):
    print(f"PREFIX {time.perf_counter() - start:.4f}", flush=True)
    os._exit(0)
planning.plan = stop
sys.argv = ["deltaslice", sys.argv[1], "--printer", "delta_etitc", "--scale", sys.argv[2], "-o", sys.argv[3], "--quiet"]
runpy.run_module("deltaslice", run_name="__main__")
"""


def prefix(tree: Path, part: Path, scale: float, out: Path) -> float:
    r = subprocess.run([sys.executable, "-c", PROBE, str(part), str(scale), str(out)], cwd=tree, capture_output=True,
                       text=True, timeout=600)
    lines = [line for line in r.stdout.splitlines() if line.startswith("PREFIX ")]
    if r.returncode != 0 or not lines:
        raise SystemExit(f"{tree}: the probe failed: {r.stderr[-2000:]}")
    return float(lines[-1].split()[1])


def ab_arguments(description: str, rounds: int) -> tuple[argparse.Namespace, Path]:
    """The A/B scripts' command line (--base, --part, --scale, --rounds) parsed, and the part's path."""
    ap = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", required=True, type=Path, help="the other source tree (a git worktree)")
    ap.add_argument("--part", default="featuretype.STL", help="a file in ../shared/parts, or a path")
    ap.add_argument("--scale", type=float, default=20.0)
    ap.add_argument("--rounds", type=int, default=rounds)
    args = ap.parse_args()
    part = Path(args.part) if Path(args.part).exists() else PARTS / args.part
    if not part.exists():
        raise SystemExit(f"{part}: no such part (../shared/parts is needed for the default)")
    return args, part


def main() -> None:
    args, part = ab_arguments(__doc__, rounds=15)
    out = Path("/tmp") / "ab_startup.dsl"
    here, base, ratios = [], [], []
    for k in range(args.rounds):
        order = [("this", ROOT), ("base", args.base.resolve())]
        random.shuffle(order)
        t = {name: prefix(tree, part, args.scale, out) for name, tree in order}
        here.append(t["this"])
        base.append(t["base"])
        ratios.append(t["this"] / t["base"])
        print(f"round {k + 1}: this {t['this']:.3f} s, base {t['base']:.3f} s, ratio {ratios[-1]:.3f}", flush=True)
    faster = sum(r < 1 for r in ratios)
    print(f"medians: this {statistics.median(here):.3f} s, base {statistics.median(base):.3f} s; "
          f"median ratio {statistics.median(ratios):.3f}; this tree faster in {faster} of {len(ratios)}")


if __name__ == "__main__":
    main()
