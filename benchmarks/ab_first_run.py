"""A/B benchmark (not a test): the README's first compile with an empty numba cache (issue 50's
bar), this checkout against other source trees or environments, alternated, then the same
command warm.

    git worktree add --detach /tmp/base 21c7ef9
    python benchmarks/ab_first_run.py --rounds 3 base=/tmp/base head=. "o1=.:NUMBA_OPT=1"

A variant is NAME=TREE[:VAR=VALUE,...]: the tree is the working directory and first on
PYTHONPATH (ahead of an editable install), the variables are added to the environment. Each
cold run gets a fresh NUMBA_CACHE_DIR; the warm run after it reuses that cache. Prints, per
run, the load average before it, the cold wall s, its CPU s (user+sys of every process), the
longest silence on stderr (s), the warm wall s and the output's md5; then each variant's
medians. Run it on a quiet machine: the bar is the quiet wall time.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

CUBE = ["-m", "deltaslice", "examples/parts/calibration_cube.stl", "--printer", "delta_etitc"]


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_once(tree: str, env: dict, cache: str, out: str) -> tuple[float, float, float]:
    """(wall s, CPU s, longest silence on stderr s) of one compile of the cube."""
    env = {**os.environ, **env, "PYTHONPATH": os.path.abspath(tree), "NUMBA_CACHE_DIR": cache}
    cpu0, t0 = _children_cpu(), time.monotonic()
    proc = subprocess.Popen([sys.executable, *CUBE, "-o", out], cwd=tree, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    last, silence = t0, 0.0
    while True:
        chunk = os.read(proc.stderr.fileno(), 65536)
        now = time.monotonic()
        silence, last = max(silence, now - last), now
        if not chunk:
            break
    if proc.wait() != 0:
        raise SystemExit(f"{tree}: the compile exited {proc.returncode}")
    return time.monotonic() - t0, _children_cpu() - cpu0, silence


def parse(spec: str) -> tuple[str, str, dict]:
    name, _, rest = spec.partition("=")
    tree, _, variables = rest.partition(":")
    env = dict(v.split("=", 1) for v in variables.split(",") if v)
    return name, tree, env


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("variants", nargs="+", help="NAME=TREE[:VAR=VALUE,...]")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    variants = [parse(v) for v in args.variants]
    results = {name: [] for name, _, _ in variants}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.rounds):
            for name, tree, env in variants:
                load = os.getloadavg()[0]
                cache, out = tempfile.mkdtemp(dir=tmp), os.path.join(tmp, f"{name}.dsl")
                wall, cpu, silence = run_once(tree, env, cache, out)
                warm, _, _ = run_once(tree, env, cache, out)
                md5 = hashlib.md5(open(out, "rb").read()).hexdigest()[:8]
                results[name].append((wall, cpu, silence, warm))
                print(f"{name:8} load {load:4.2f}  cold {wall:6.2f} s  CPU {cpu:6.2f} s  silence {silence:4.2f} s  "
                      f"warm {warm:5.2f} s  md5 {md5}", flush=True)
    for name, rows in results.items():
        med = [statistics.median(col) for col in zip(*rows)]
        print(f"{name:8} median: cold {med[0]:.2f} s, CPU {med[1]:.2f} s, silence {med[2]:.2f} s, warm {med[3]:.2f} s")


if __name__ == "__main__":
    main()
