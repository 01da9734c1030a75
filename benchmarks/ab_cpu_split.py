"""A/B benchmark (not a test): whole compiles of a part with this checkout against another source
tree, the CPU split between the main process and its workers (slicing, planning, sampling).

    git worktree add /tmp/base 34fa0e7
    (cd /tmp/base && python -m compileall -q deltaslice); python -m compileall -q deltaslice
    python benchmarks/ab_cpu_split.py --base /tmp/base [--part featuretype.STL --scale 20] [--rounds 8]

Each run compiles in a fresh interpreter in the tree's directory (the tree first on the path), through
``deltaslice.cli.main`` (the console script leaves with ``os._exit`` and reports nothing after), then
reads ``getrusage``: the main process's own CPU (user + system, every thread) and its reaped
workers'. The trees alternate in a random order each round; prints every run and the medians. The
main process competes with its workers for the two cores: CPU it saves is time the workers get.
"""

from __future__ import annotations

import json
import os
import random
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from ab_startup import ab_arguments  # noqa: E402

_RUN = """
import json, os, resource, sys, time
t = time.perf_counter()
import deltaslice.cli
try:
    deltaslice.cli.main(sys.argv[1:], standalone_mode=False)
except SystemExit:
    pass
me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
print(json.dumps([time.perf_counter() - t, me.ru_utime + me.ru_stime, kids.ru_utime + kids.ru_stime]))
sys.stdout.flush()
os._exit(0)
"""


def compile_once(tree: Path, part: Path, scale: float, out: Path) -> list[float]:
    """[wall s, main process CPU s, workers' CPU s] of one compile from ``tree``."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    r = subprocess.run([sys.executable, "-c", _RUN, str(part), "--printer", "delta_etitc", "--scale", str(scale),
                        "-o", str(out), "--quiet"], cwd=tree, env=env, capture_output=True, text=True, timeout=1200)
    if r.returncode != 0 or not r.stdout.strip():
        raise SystemExit(f"{tree}: the compile failed (exit {r.returncode}): {r.stderr[-2000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def main() -> None:
    args, part = ab_arguments(__doc__, rounds=8)
    trees = {"this": ROOT, "base": args.base.resolve()}
    runs = {name: [] for name in trees}
    with tempfile.TemporaryDirectory(prefix="ab_cpu_split_") as tmp:
        for k in range(args.rounds):
            order = list(trees)
            random.shuffle(order)
            for name in order:
                wall, main_cpu, workers = compile_once(trees[name], part, args.scale, Path(tmp) / f"{name}.dsl")
                runs[name].append((wall, main_cpu, workers))
                print(f"round {k + 1} {name}: wall {wall:.2f} s, main process {main_cpu:.2f} CPU-s, "
                      f"workers {workers:.2f} CPU-s", flush=True)
    for name, rows in runs.items():
        wall, main_cpu, workers = (statistics.median(r[i] for r in rows) for i in range(3))
        print(f"{name}: medians wall {wall:.2f} s, main process {main_cpu:.2f} CPU-s, workers {workers:.2f} CPU-s")


if __name__ == "__main__":
    main()
