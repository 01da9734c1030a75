"""Torque read-back: compile parts for a printer with dynamics data, read the joints back from the
setpoint CSV, and put them through the family's inverse dynamics with the printer file's masses
(issue 56). Accelerations are finite differences averaged over 5 ms (a box filter of the second
differences: the mean acceleration over the window, what the arms' inertia feels; a single
second difference at 1 kHz shows every planner stage's step).

Per plan it prints the peak torque and its ratio to stall, the share of time any actuator is over
its stall torque, the share of samples where a driving actuator is past its speed-torque line (of
all samples, any joint; and of the joint samples where the actuator drives), what gravity alone
and the velocity (Coriolis, centripetal) terms alone take at most, and where the peak is.

    python benchmarks/bench_torque.py                       # delta_etitc: cube feed and machine, star machine
    python benchmarks/bench_torque.py --printer delta_uady --cases cube:feed
    python benchmarks/bench_torque.py --set planning.torque_limit=off          # the plans without torque limits
    python benchmarks/bench_torque.py --printer delta_ucb --cases ../shared/parts/featuretype.STL@20:feed
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from deltaslice.machine import load_printer  # noqa: E402
from deltaslice.machine.dynamics import ACCELERATION_WINDOW as WINDOW  # noqa: E402
from deltaslice.machine.dynamics import sampled_torques  # noqa: E402

STAR = {"outer": 20.0, "inner": 8.0, "height": 10.0}  # mm: tests/test_planning_limits.py's star, as a prism


def star_prism(path: Path) -> Path:
    """A ten-pointed star (36 and 108 deg corners), outer radius 20 mm, inner 8 mm, 10 mm tall, as an STL."""
    import trimesh
    from shapely.geometry import Polygon

    k = np.arange(10)
    r = np.where(k % 2 == 0, STAR["outer"], STAR["inner"])
    poly = Polygon(np.c_[r * np.cos(k * np.pi / 5), r * np.sin(k * np.pi / 5)])
    trimesh.creation.extrude_polygon(poly, STAR["height"]).export(path)
    return path


def compile_csv(part: Path, printer: str, mode: str, out: Path, workers: int, overrides=(), scale: float = 1.0) -> Path:
    if not out.exists():
        sets = [arg for o in overrides for arg in ("--set", o)]
        run = subprocess.run([sys.executable, "-m", "deltaslice", "compile", str(part), "--printer", printer,
                              "--speed-limit", mode, "-o", str(out), "--workers", str(workers), "--scale", f"{scale:g}",
                              *sets], cwd=ROOT,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if run.returncode:
            raise SystemExit(f"compile of {part.name} ({mode}) failed:\n{run.stderr[-2000:]}")
    return out


def read_csv(path: Path, n_joints: int):
    """(rate Hz, q (N, J)) of a setpoint CSV."""
    rate = None
    rows = []
    with open(path) as f:
        for line in f:
            if line.startswith("#"):
                if line.startswith("# rate_hz:"):
                    rate = float(line.split(":")[1])
                continue
            if line[0].isdigit():
                rows.append(line)
    data = np.loadtxt(rows, delimiter=",", usecols=range(1, 1 + n_joints))
    return rate, data


def read_back(printer, q: np.ndarray, rate: float) -> dict:
    """The torque figures of joints q (N, J) sampled at rate Hz."""
    dt = 1.0 / rate
    tau, qd = sampled_torques(printer, q, rate)
    gravity = printer.joint_torques(q, 0 * qd, 0 * qd)
    velocity = printer.joint_torques(q, qd, 0 * qd) - gravity
    act = printer.dynamics.actuators
    stall = np.array(act.stall)
    ratio = np.abs(tau) / stall
    over = act.over_line(qd, tau)
    driving = tau * qd > 0
    k = int(np.nanargmax(ratio.max(axis=1)))
    p = printer.kinematics().forward(q[k][None])[0]
    return {
        "duration": len(q) * dt,
        "peak": float(np.nanmax(np.abs(tau))),
        "peak_ratio": float(np.nanmax(ratio)),
        "over_stall": float(np.mean(np.any(ratio > 1, axis=1))),
        "over_line": float(np.mean(np.any(over, axis=1))),
        "over_line_driving": float(over.sum() / max(1, driving.sum())),
        "gravity": float(np.nanmax(np.abs(gravity) / stall)),
        "velocity_terms": float(np.nanmax(np.abs(velocity) / stall)),
        "where": p,
        "joints": [np.degrees(v) if kind == "revolute" else v for v, kind in zip(q[k], printer.limits.kinds)],
        "nan": int(np.sum(~np.isfinite(tau).all(axis=1))),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--printer", default="delta_etitc")
    ap.add_argument("--cases", default="cube:feed,cube:machine,star:machine",
                    help="comma-separated part:mode, part cube, star or a mesh's path (PATH@SCALE to scale it), "
                         "mode feed or machine")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--keep", type=Path, default=None, help="directory to keep (and reuse) the compiled CSVs in")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="a printer-file override for the compiles, e.g. planning.torque_limit=off (repeatable)")
    args = ap.parse_args(argv)
    printer = load_printer(args.printer, dict(o.split("=", 1) for o in args.overrides))
    if printer.dynamics is None:
        raise SystemExit(f"{args.printer}: no [dynamics] table")
    stall = np.array(printer.dynamics.actuators.stall)
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        parts = {"cube": ROOT / "examples" / "parts" / "calibration_cube.stl"}
        print(f"{printer.name}: stall {', '.join(f'{s:g}' for s in stall)} (N m or N); accelerations averaged over "
              f"{WINDOW * 1e3:g} ms")
        print("| plan | print time s | peak torque (x stall) | time any over stall | time any over speed-torque line "
              "| of driving joint samples | gravity alone (x stall) | velocity terms alone (x stall) | peak at (x, y, z mm; joints deg or mm) |")
        print("|---|---|---|---|---|---|---|---|---|")
        for case in args.cases.split(","):
            part, mode = case.rsplit(":", 1)
            part, _, scale = part.partition("@")
            scale = float(scale or 1.0)
            if part == "star" and part not in parts:
                parts["star"] = star_prism(work / "star10.stl")
            mesh = parts.get(part) or Path(part)
            tag = "".join(f"_{o.replace('=', '-')}" for o in args.overrides)
            scaled = f"x{scale:g}" if scale != 1.0 else ""
            csv = compile_csv(mesh, args.printer, mode, work / f"{printer.name}_{mesh.stem}{scaled}_{mode}{tag}.csv",
                              args.workers, args.overrides, scale)
            rate, q = read_csv(csv, printer.n_joints)
            r = read_back(printer, q, rate)
            where = ", ".join(f"{v:.1f}" for v in r["where"])
            angles = ", ".join(f"{v:.0f}" for v in r["joints"])
            name = (mesh.stem if part not in parts else part) + (f" x{scale:g}" if scaled else "")
            print(f"| {name}, {mode} | {r['duration']:.1f} | {r['peak']:.2f} ({r['peak_ratio']:.2f}x) "
                  f"| {100 * r['over_stall']:.1f} % | {100 * r['over_line']:.1f} % | {100 * r['over_line_driving']:.1f} % "
                  f"| {r['gravity']:.2f} | {r['velocity_terms']:.3f} | {where}; {angles} |", flush=True)
            if r["nan"]:
                print(f"  ({r['nan']} samples where the model gives NaN: singular or out of reach)")


if __name__ == "__main__":
    main()
