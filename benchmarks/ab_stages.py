"""A/B benchmark (not a test): one stage of featuretype's compile at a time, this checkout against
another source tree (a git worktree of an earlier commit), processes alternating in random order.

    git worktree add /tmp/base c3a8d8f
    python benchmarks/ab_stages.py --base /tmp/base --stage order|emit|plan [--rounds 6]

Stages (each from inputs captured once by this checkout into ``--cache``, default
``/tmp/deltaslice_ab_stages``: the layer plans, the toolpath and the planned pieces of
``../shared/parts/featuretype.STL`` at scale 20 on delta_etitc; both trees must unpickle them):
- ``order``: the main process's share of slicing, the layers ordered and their moves written from
  the captured layer plans (CPU, the smaller of three; a digest of the toolpath's columns, which
  should agree);
- ``emit``: the stream written from the captured pieces with two sampling workers and the limit
  monitor (wall, the main process's CPU, the workers' CPU; a digest of the bytes);
- ``plan``: the captured toolpath planned with two workers (wall, main CPU, workers' CPU; the
  planned duration). ``ab_plan.py`` compares planning too, each process slicing the part first,
  by CPU with one worker or by wall with several; this stage splits the parent's CPU from the
  workers' and slices nothing.
Prints every process's figures and the medians per tree. Compile both trees' bytecode first
(``python -m compileall -q deltaslice``); on this shared machine compare medians of many rounds.
"""

from __future__ import annotations

import argparse
import json
import random
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PART = ROOT.parent / "shared" / "parts" / "featuretype.STL"

# Run with the tree as the working directory: ``python -c`` puts it first on sys.path.
CAPTURE = """
import pickle, sys
from pathlib import Path
import deltaslice.pipeline as P
import deltaslice.slicing.slicer as S
from deltaslice import load_printer
from deltaslice.planning import plan
cache, part = Path(sys.argv[1]), sys.argv[2]
printer = load_printer("delta_etitc")
plans = []
layer_plans = S._layer_plans
def captured(*a, **k):
    for p in layer_plans(*a, **k):
        plans.append(p)
        yield p
S._layer_plans = captured
toolpath = P.load_toolpath(part, printer, scale=20, workers=1)
S._layer_plans = layer_plans
pickle.dump(plans, open(cache / "plans.pkl", "wb"))
pickle.dump(toolpath, open(cache / "toolpath.pkl", "wb"))
pickle.dump(plan(toolpath, printer, workers=2).pieces, open(cache / "pieces.pkl", "wb"))
"""

PROBE = """
import hashlib, json, os, pickle, sys, time
import numpy as np
from deltaslice import load_printer
stage, cache, part = sys.argv[1], sys.argv[2], sys.argv[3]
printer = load_printer("delta_etitc")
out = {}
if stage == "order":
    import deltaslice.slicing.slicer as S
    from deltaslice.mesh import load_mesh
    from deltaslice.slicing.heaters import start_heating
    from deltaslice.slicing.layers import layer_heights
    from deltaslice.slicing.ordering import MoveWriter
    from deltaslice.toolpath import ToolpathBuilder
    plans = pickle.load(open(os.path.join(cache, "plans.pkl"), "rb"))
    s, tool = printer.slicing, printer.tool
    height = float(load_mesh(part, scale=20).vertices[:, 2].max())
    top, _mid, thick = layer_heights(height, s.layer_height, s.first_layer_height)
    cpu = []
    for _ in range(3):
        t = time.process_time()
        b = ToolpathBuilder(start=(0.0, 0.0, 0.0))
        start_heating(b, tool)
        w = MoveWriter(b, s, tool, tool.filament_area)
        for li, p in enumerate(plans):
            w.new_layer(float(top[li]), li == 0)
            S._order_layer(w, p, float(thick[li]), s)
        w.finish()
        toolpath = b.build()
        cpu.append(time.process_time() - t)
    h = hashlib.sha1()
    for k in ("xyz", "feed", "e", "tool", "role", "layer"):
        h.update(np.ascontiguousarray(getattr(toolpath, k)).tobytes())
    out = {"cpu": min(cpu), "check": h.hexdigest()[:12]}
elif stage == "emit":
    import io
    from deltaslice.emit import write_trajectory
    from deltaslice.machine.limits import LimitMonitor
    from deltaslice.planning.trajectory import Trajectory
    traj = Trajectory(printer, pickle.load(open(os.path.join(cache, "pieces.pkl"), "rb")))
    next(iter(traj.iter_samples()))  # the sampling kernels loaded here, as after planning
    monitor = LimitMonitor(printer.limits, printer.tool, printer.planning.output_rate)
    f = io.BytesIO()
    t, c = time.perf_counter(), time.process_time()
    write_trajectory(traj, f, "stream", watch=monitor.watch, workers=2)
    ch = os.times()
    out = {"wall": time.perf_counter() - t, "main": time.process_time() - c,
           "workers": ch.children_user + ch.children_system, "check": hashlib.sha1(f.getvalue()).hexdigest()[:12]}
else:
    from deltaslice.planning import plan
    toolpath = pickle.load(open(os.path.join(cache, "toolpath.pkl"), "rb"))
    t, c = time.perf_counter(), time.process_time()
    traj = plan(toolpath, printer, workers=2)
    ch = os.times()
    out = {"wall": time.perf_counter() - t, "main": time.process_time() - c,
           "workers": ch.children_user + ch.children_system, "check": f"{traj.duration:.4f} s"}
print(json.dumps(out))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--base", required=True, help="the other source tree")
    ap.add_argument("--stage", choices=("order", "emit", "plan"), required=True)
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--cache", default="/tmp/deltaslice_ab_stages")
    args = ap.parse_args()
    if not PART.exists():
        sys.exit(f"{PART} is missing: this benchmark needs ../shared/parts")
    cache = Path(args.cache)
    if not (cache / "pieces.pkl").exists():
        cache.mkdir(parents=True, exist_ok=True)
        print(f"capturing featuretype's layer plans, toolpath and pieces into {cache} ...", flush=True)
        subprocess.run([sys.executable, "-c", CAPTURE, str(cache), str(PART)], cwd=ROOT, check=True)
    trees = {"this": ROOT, "base": Path(args.base).resolve()}
    results = {name: [] for name in trees}
    for r in range(args.rounds):
        for name in random.sample(list(trees), len(trees)):
            p = subprocess.run([sys.executable, "-c", PROBE, args.stage, str(cache), str(PART)], cwd=trees[name],
                               capture_output=True, text=True)
            if p.returncode:
                sys.exit(f"{name}: {p.stderr[-2000:]}")
            res = json.loads(p.stdout.strip().splitlines()[-1])
            results[name].append(res)
            print(f"round {r + 1} {name}: " + ", ".join(f"{k} {v:.3f}" if isinstance(v, float) else f"{k} {v}"
                                                       for k, v in res.items()), flush=True)
    for name, rows in results.items():
        keys = [k for k in rows[0] if k != "check"]
        print(f"{name} ({trees[name]}): " + ", ".join(f"{k} median {statistics.median(r[k] for r in rows):.3f} s"
                                                     for k in keys) + f"; {rows[0]['check']}")


if __name__ == "__main__":
    main()
