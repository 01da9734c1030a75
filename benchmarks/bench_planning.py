"""Planning benchmark (not a test): deltaslice's joint-space planner against the conventional
Cartesian planner, on delta_etitc and delta_ucb, for a sliced layer stack of a ~4,000-triangle
part, a 40 mm circle and a 40 mm square (scaled to fit the UCB's small workspace).

    python benchmarks/bench_planning.py [--quick]

Prints a Markdown table: print time with the slicer's feeds and with --speed-limit machine,
against the baseline "as firmware runs it" (typical delta settings) and "safe" (largest uniform
limits that keep every joint within its limits at the output rate); the firmware baseline's
joint-limit violations; the fraction of time a limit is active; planning wall time; peak memory.
"""

from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from deltaslice import load_printer  # noqa: E402
from deltaslice.pipeline import load_toolpath  # noqa: E402
from deltaslice.planning import plan  # noqa: E402
from deltaslice.planning.trapezoid import corner_violations, plan_firmware, plan_safe  # noqa: E402
from deltaslice.toolpath import Role, ToolpathBuilder  # noqa: E402


def tube_part(path: Path, outer: float, height: float) -> int:
    """A tube with ~4,000 triangles (500 sections), written as STL. Returns the triangle count."""
    ring = trimesh.creation.annulus(r_min=outer * 0.6, r_max=outer, height=height, sections=500)
    ring.export(path)
    return len(ring.faces)


def outline(printer, shape: str, size: float):
    """One closed 40 mm (or scaled) circle or square at the first layer, as a toolpath."""
    z = printer.slicing.first_layer_height
    h = size / 2
    if shape == "circle":
        th = np.linspace(0, 2 * np.pi, 181)
        xy = np.c_[h * np.cos(th), h * np.sin(th)]
    else:
        xy = np.array([[-h, -h], [h, -h], [h, h], [-h, h], [-h, -h]])
    b = ToolpathBuilder((xy[0, 0], xy[0, 1], z + 1))
    b.new_layer(z)
    b.add([[xy[0, 0], xy[0, 1], z]], printer.slicing.travel_speed, 0, 0, Role.TRAVEL)
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    ratio = printer.slicing.perimeter_width * z / printer.tool.filament_area
    b.add(np.c_[xy[1:], np.full(len(xy) - 1, z)], printer.slicing.perimeter_speed, seg * ratio, 1, Role.PERIMETER)
    return b.build()


def run_case(printer, name, toolpath, workers):
    row = {"case": name, "moves": len(toolpath), "layers": toolpath.n_layers}
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for mode in ("feed", "machine"):
        t0 = time.perf_counter()
        ours = plan(toolpath, printer, speed_limit=mode, workers=workers)
        row[f"plan_s_{mode}"] = time.perf_counter() - t0
        fw = plan_firmware(toolpath, printer, speed_limit=mode)
        safe = plan_safe(toolpath, printer, speed_limit=mode)
        viol = corner_violations(fw)
        row[f"ours_{mode}"] = ours.duration
        row[f"firmware_{mode}"] = fw.duration
        row[f"safe_{mode}"] = safe.duration
        row[f"safe_scale_{mode}"] = safe.info["scale"]
        row[f"viol_{mode}"] = viol
        row[f"active_{mode}"] = ours.active_fraction
    row["peak_rss_mb"] = max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, rss0) / 1024
    return row


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="fewer layers")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for pname, outer, height, size in (("delta_etitc", 25.0, 20.0, 40.0), ("delta_ucb", 20.0, 6.0, 40.0)):
            printer = load_printer(Path(__file__).resolve().parents[1] / "printers" / f"{pname}.toml")
            stl = Path(tmp) / f"tube_{pname}.stl"
            tris = tube_part(stl, outer, height / (2 if args.quick else 1))
            t0 = time.perf_counter()
            stack = load_toolpath(stl, printer)
            slice_s = time.perf_counter() - t0
            cases = [(f"tube {tris} triangles (sliced)", stack)]
            cases += [(f"{size:g} mm {shape}", outline(printer, shape, size if pname != "delta_ucb" else 40.0)) for shape in ("circle", "square")]
            for name, tp in cases:
                row = run_case(printer, name, tp, args.workers)
                row["printer"] = pname
                row["slice_s"] = slice_s if "sliced" in name else 0.0
                rows.append(row)
                print(f"done {pname} {name}", file=sys.stderr)

    print("| printer | case | moves | feed: ours / firmware / safe (s) | ours vs safe | machine: ours / firmware / safe (s) | ours vs safe | firmware violations (feed; machine): events, worst acc | limit active (feed; machine) | plan wall s (feed; machine) | peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        vf, vm = r["viol_feed"], r["viol_machine"]
        print(
            f"| {r['printer']} | {r['case']} | {r['moves']} "
            f"| {r['ours_feed']:.2f} / {r['firmware_feed']:.2f} / {r['safe_feed']:.2f} | {r['safe_feed'] / r['ours_feed']:.2f}x "
            f"| {r['ours_machine']:.2f} / {r['firmware_machine']:.2f} / {r['safe_machine']:.2f} | {r['safe_machine'] / r['ours_machine']:.2f}x "
            f"| {vf['events']}, {100 * vf['worst_acceleration_ratio']:.0f} %; {vm['events']}, {100 * vm['worst_acceleration_ratio']:.0f} % "
            f"| {100 * r['active_feed']:.1f} %; {100 * r['active_machine']:.1f} % "
            f"| {r['plan_s_feed']:.2f}; {r['plan_s_machine']:.2f} | {r['peak_rss_mb']:.0f} |"
        )


if __name__ == "__main__":
    main()
