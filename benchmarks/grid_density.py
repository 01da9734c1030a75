"""Grid density benchmark (not a test): how many stages the planner's grid takes and what print
time it gives, for the present grid constants and for others, on real parts.

    python benchmarks/grid_density.py                                  # featuretype at 20, delta_etitc
    python benchmarks/grid_density.py --part extruder_idler.obj --scale 1 ARC_STEP=0.3 MAX_STEP=8
    python benchmarks/grid_density.py --printer printers/linear_kossel.toml --part tube ARC_STEP=0.3,MAX_STEP=8
    python benchmarks/grid_density.py --part tube --printer printers/linear_kossel.toml REFINE=10 GROWTH=4 GROWTH=4,REFINE=10

Each variant sets constants of ``deltaslice.planning.stages`` (``ARC_STEP``, ``MAX_STEP``, ``GROWTH``,
``MIN_STEP``, and ``REFINE``, every stage split in that many: the dense-grid reference;
comma-separated NAME=VALUE) and plans the same toolpath in one process, one worker,
counting the stages of every initial grid (``stages.grid``, as the solver calls it). Prints stages and print time against
the present constants ("base", always first) and the planning CPU time (noisy on a shared machine:
the stages are what to compare). The stage-wise check keeps every variant within the limits.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_planning import tube_part  # noqa: E402

from deltaslice import load_printer  # noqa: E402
from deltaslice.pipeline import load_toolpath  # noqa: E402
from deltaslice.planning import plan  # noqa: E402
from deltaslice.planning import solver, stages  # noqa: E402

PARTS = ROOT.parent / "shared" / "parts"
CONSTANTS = ("ARC_STEP", "MAX_STEP", "GROWTH", "MIN_STEP", "REFINE")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("variants", nargs="*", help="NAME=VALUE[,NAME=VALUE...] of " + ", ".join(CONSTANTS))
    ap.add_argument("--part", default="featuretype.STL", help="'tube' (bench_planning's) or a mesh in ../shared/parts")
    ap.add_argument("--scale", type=float, default=20.0)
    ap.add_argument("--printer", default=str(ROOT / "printers" / "delta_etitc.toml"))
    args = ap.parse_args()
    printer = load_printer(args.printer)
    with tempfile.TemporaryDirectory() as tmp:
        if args.part == "tube":
            part, scale = Path(tmp) / "tube.stl", 1.0
            tube_part(part, 25.0, 20.0)
        else:
            part, scale = PARTS / args.part, args.scale
            if not part.exists():
                sys.exit(f"{part} not found")
        toolpath = load_toolpath(str(part), printer, scale=scale)
    base = {name: getattr(stages, name) for name in CONSTANTS}
    grid = solver.grid
    print(f"{args.part} (scale {scale:g}) on {printer.name}; base: "
          + ", ".join(f"{k} {v:g}" for k, v in base.items()))
    print("| variant | stages | vs base | print time s | vs base | planning CPU s |")
    print("|---|---|---|---|---|---|")
    ref = None
    for variant in ["base", *args.variants]:
        for name, value in base.items():
            setattr(stages, name, value)
        if variant != "base":
            for item in variant.split(","):
                name, value = item.split("=")
                if name not in CONSTANTS:
                    sys.exit(f"{name}: expected one of {', '.join(CONSTANTS)}")
                setattr(stages, name, int(value) if name == "REFINE" else float(value))
        stages = 0

        def counting(path, rest=None):
            nonlocal stages
            g = grid(path, rest)
            stages += len(g) - 1
            return g

        solver.grid = counting
        try:
            cpu = time.process_time()
            duration = plan(toolpath, printer, workers=1).duration
            cpu = time.process_time() - cpu
        finally:
            solver.grid = grid
        ref = ref or (stages, duration)
        print(f"| {variant} | {stages} | {stages / ref[0] - 1:+.1%} | {duration:.4f} | {duration / ref[1] - 1:+.4%} "
              f"| {cpu:.2f} |", flush=True)
    for name, value in base.items():
        setattr(stages, name, value)


if __name__ == "__main__":
    main()
