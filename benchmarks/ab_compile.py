"""A/B benchmark (not a test): whole compiles of a part with this checkout against another source
tree, the command line as a user runs it, the two trees in a random order each round.

    git worktree add /tmp/base dbbb350
    (cd /tmp/base && python -m compileall -q deltaslice); python -m compileall -q deltaslice
    python benchmarks/ab_compile.py --base /tmp/base [--part featuretype.STL --scale 20] [--rounds 30]

Each run is ``python -m deltaslice PART --printer delta_etitc --scale S -o OUT --quiet`` in the
tree's directory (the tree first on the path, ahead of an installed copy). Prints each round's wall
times and CPU times (the process and its workers: user + system) and their ratios, then the
medians of each tree and of the per-round ratios, and whether the two trees wrote the same bytes.
On a shared machine whose speed drifts, the per-round ratio is the figure to quote: one round runs
both trees within seconds of each other.
"""

from __future__ import annotations

import filecmp
import os
import random
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from ab_startup import ab_arguments  # noqa: E402


def compile_once(tree: Path, part: Path, scale: float, out: Path) -> tuple[float, float]:
    """(wall s, CPU s of the process and its reaped workers) of one compile from ``tree``."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "deltaslice", str(part), "--printer", "delta_etitc", "--scale", str(scale),
                        "-o", str(out), "--quiet"], cwd=tree, env=env, capture_output=True, text=True, timeout=1200)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"{tree}: the compile failed (exit {r.returncode}): {r.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    args, part = ab_arguments(__doc__, rounds=30)
    trees = {"this": ROOT, "base": args.base.resolve()}
    times = {name: [] for name in trees}
    wall_ratio, cpu_ratio, same = [], [], True
    with tempfile.TemporaryDirectory(prefix="ab_compile_") as tmp:
        outs = {name: Path(tmp) / f"{name}.dsl" for name in trees}
        for k in range(args.rounds):
            order = list(trees)
            random.shuffle(order)
            t = {name: compile_once(trees[name], part, args.scale, outs[name]) for name in order}
            same = same and filecmp.cmp(outs["this"], outs["base"], shallow=False)
            for name in trees:
                times[name].append(t[name])
            wall_ratio.append(t["this"][0] / t["base"][0])
            cpu_ratio.append(t["this"][1] / t["base"][1])
            print(f"round {k + 1}: this {t['this'][0]:.2f} s ({t['this'][1]:.2f} CPU-s), base {t['base'][0]:.2f} s "
                  f"({t['base'][1]:.2f} CPU-s); ratios wall {wall_ratio[-1]:.3f}, CPU {cpu_ratio[-1]:.3f}", flush=True)
    med = {name: [statistics.median(x[i] for x in times[name]) for i in (0, 1)] for name in trees}
    print(f"medians: this {med['this'][0]:.3f} s ({med['this'][1]:.2f} CPU-s), base {med['base'][0]:.3f} s "
          f"({med['base'][1]:.2f} CPU-s); per-round ratios: wall {statistics.median(wall_ratio):.3f}, "
          f"CPU {statistics.median(cpu_ratio):.3f}; this tree faster in {sum(r < 1 for r in wall_ratio)} of "
          f"{len(wall_ratio)}; {'the same bytes' if same else 'OUTPUTS DIFFER'}")


if __name__ == "__main__":
    main()
