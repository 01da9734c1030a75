"""Profile a full compile (slice + plan + emit) of one part with cProfile; prints the top
entries by cumulative time. Planning runs in one process so the profile sees it.

    python benchmarks/profile_compile.py                       # the tube part bench_planning.py builds
    python benchmarks/profile_compile.py /work/shared/parts/featuretype.STL --scale 20
    python benchmarks/profile_compile.py PART --solver toppra --top 40
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_planning import tube_part  # noqa: E402

from deltaslice import load_printer  # noqa: E402
from deltaslice.pipeline import compile_part  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("part", nargs="?", help="mesh or G-code (default: the benchmark tube)")
    ap.add_argument("--printer", default=str(ROOT / "printers" / "delta_etitc.toml"))
    ap.add_argument("--scale", type=float, default=1.0)
    ap.add_argument("--solver", default=None, help="planning solver (fast|toppra); default: the planner's default")
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--sort", default="cumulative", help="pstats sort key (cumulative, tottime, ...)")
    args = ap.parse_args()
    printer = load_printer(args.printer)
    with tempfile.TemporaryDirectory() as tmp:
        part = args.part
        if part is None:
            part = str(Path(tmp) / "tube.stl")
            tube_part(Path(part), 25.0, 20.0)
        extra = {"solver": args.solver} if args.solver else {}
        opts = {"scale": args.scale} if args.scale != 1.0 else {}
        prof = cProfile.Profile()
        t0 = time.perf_counter()
        prof.enable()
        summary = compile_part(part, printer, output=str(Path(tmp) / "out.dsl"), workers=1, **opts, **extra)
        prof.disable()
        wall = time.perf_counter() - t0
    print(summary)
    print(f"wall (profiled): {wall:.2f} s")
    pstats.Stats(prof).sort_stats(args.sort).print_stats(args.top)


if __name__ == "__main__":
    main()
