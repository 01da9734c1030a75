"""Limits on the continuous motion: the star-and-zig-zag part of tests/test_planning_limits.py
planned for every printer in both speed modes at a 10 kHz output rate. Prints, per printer and
mode, the peak joint velocity / acceleration ratio by finite differences, the analytic
stage-wise bound, the peak joint jerk (third differences at 10 kHz) against jerk_max for the
toppra pieces and for the whole output, and the duration change with a 10x denser grid.

    python benchmarks/bench_limits.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from deltaslice.planning import plan, stages  # noqa: E402
from test_planning_limits import Z0, _run_peaks, peak_ratios, printer_at, star_part  # noqa: E402

RATE = 10000


def jerk_peaks(traj, rate):
    """Peak |third difference| / jerk_max per joint: (toppra pieces only, whole output)."""
    from deltaslice.planning.pieces import RunPiece

    jmax = np.array([j.jerk_max for j in traj.printer.joints], float)
    runs = np.zeros(len(jmax))
    for piece in traj.pieces:
        if isinstance(piece, RunPiece) and piece.duration > 4 / rate:
            q = piece.sample(traj.kin, np.arange(0.0, piece.duration, 1.0 / rate))[0]
            runs = np.maximum(runs, np.abs(np.diff(q, 3, axis=0)).max(axis=0) * rate**3 / jmax)
    q = traj.samples(rate).q
    whole = np.abs(np.diff(q, 3, axis=0)).max(axis=0) * rate**3 / jmax
    return runs, whole


def main():
    print("| printer | mode | duration s | FD vel | FD acc | stage bound | run jerk / jerk_max | output jerk / jerk_max | dense grid dt |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in sorted(Z0):
        printer = printer_at(name, RATE)
        toolpath = star_part(name)
        for mode in ("feed", "machine"):
            stages.REFINE = 1
            traj = plan(toolpath, printer, speed_limit=mode, workers=1)
            rv, ra = peak_ratios(printer, traj.samples(RATE), RATE)
            sv, sa = traj.stage_maxima()
            jr, jw = jerk_peaks(traj, RATE)
            stages.REFINE = 10
            fine = plan(toolpath, printer, speed_limit=mode, workers=1)
            stages.REFINE = 1
            runs = lambda t: sum(p.duration for p in t.pieces if p.kind == "run")  # noqa: E731
            d = (runs(traj) - runs(fine)) / runs(fine)
            print(
                f"| {name} | {mode} | {traj.duration:.3f} | {rv.max():.4f} | {ra.max():.4f} | {max(sv.max(), sa.max()):.4f} "
                f"| {jr.max():.0f} | {jw.max():.0f} | {100 * d:+.2f} % |",
                flush=True,
            )


if __name__ == "__main__":
    main()
