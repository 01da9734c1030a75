"""Slicing benchmark: deltaslice against prusa-slicer on the same meshes and settings.

    python benchmarks/bench_slicing.py [--runs 5] [--printer printers/delta_etitc.toml]

Writes the parts into a temporary directory (examples/parts/make_parts.py), writes
an equivalent PrusaSlicer ini from the printer file's [slicing] and [tool] tables,
then alternates runs of both slicers and reports median wall times (each
measured as a whole process: ``python -m deltaslice slice`` and
``prusa-slicer --export-gcode``), extruded filament volume and layer count.
Not a test: run it by hand; results go in docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import math
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def prusa_ini(printer) -> str:
    s, t = printer.slicing, printer.tool
    first_speed = s.first_layer_speed
    return "\n".join(
        [
            f"layer_height = {s.layer_height}",
            f"first_layer_height = {s.first_layer_height}",
            f"perimeters = {s.perimeters}",
            f"top_solid_layers = {s.top_solid_layers}",
            f"bottom_solid_layers = {s.bottom_solid_layers}",
            "top_solid_min_thickness = 0",
            "bottom_solid_min_thickness = 0",
            f"fill_density = {round(s.fill_density * 100)}%",
            "fill_pattern = rectilinear",
            "top_fill_pattern = rectilinear",
            "bottom_fill_pattern = rectilinear",
            f"fill_angle = {math.degrees(s.fill_angle):g}",
            f"infill_overlap = {round(s.infill_overlap * 100)}%",
            f"nozzle_diameter = {t.nozzle_diameter}",
            f"filament_diameter = {t.filament_diameter}",
            f"extrusion_multiplier = {s.extrusion_multiplier}",
            f"extrusion_width = {s.perimeter_width}",
            f"perimeter_extrusion_width = {s.perimeter_width}",
            f"external_perimeter_extrusion_width = {s.perimeter_width}",
            f"infill_extrusion_width = {s.infill_width}",
            f"solid_infill_extrusion_width = {s.infill_width}",
            f"top_infill_extrusion_width = {s.infill_width}",
            f"first_layer_extrusion_width = {s.first_layer_width}",
            f"perimeter_speed = {s.perimeter_speed}",
            f"external_perimeter_speed = {s.external_perimeter_speed}",
            f"infill_speed = {s.infill_speed}",
            f"solid_infill_speed = {s.solid_infill_speed}",
            f"top_solid_infill_speed = {s.solid_infill_speed}",
            f"first_layer_speed = {first_speed}",
            f"travel_speed = {s.travel_speed}",
            f"skirts = {s.skirt_loops}",
            f"skirt_distance = {s.skirt_distance}",
            "skirt_height = 1",
            "min_skirt_length = 0",
            "brim_width = 0",
            f"retract_length = {t.retract_length}",
            f"retract_speed = {t.retract_speed}",
            f"retract_lift = {t.z_hop}",
            f"retract_before_travel = {t.retract_min_travel}",
            "gap_fill_enabled = 0",
            "thin_walls = 0",
            "ensure_vertical_shell_thickness = 0",
            "infill_every_layers = 1",
            "solid_infill_every_layers = 0",
            "support_material = 0",
            "use_relative_e_distances = 0",
            "gcode_flavor = reprap",
            "start_gcode = ",
            "end_gcode = ",
            "bed_shape = -100x-100,100x-100,100x100,-100x100",
            "complete_objects = 0",
            "",
        ]
    )


def timed(cmd) -> float:
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"failed: {' '.join(map(str, cmd))}\n{r.stderr[-2000:]}")
    return dt


def volume_and_layers(gcode: Path, filament_diameter: float):
    from deltaslice.gcode import read_gcode

    tp = read_gcode(gcode)
    work = tp.working
    area = math.pi * filament_diameter**2 / 4
    # layers holding extrusion (PrusaSlicer may announce a layer change at the end)
    layers = len(set(tp.layer[work].tolist()))
    return float(tp.e[work].sum() * area), layers, len(tp)


def main(argv=None):
    from deltaslice.machine import load_printer

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--printer", default="printers/delta_etitc.toml")
    args = ap.parse_args(argv)
    prusa = shutil.which("prusa-slicer")
    if prusa is None:
        raise SystemExit("prusa-slicer not found on PATH")
    printer = load_printer(ROOT / args.printer)
    tmp = Path(tempfile.mkdtemp(prefix="bench_slicing_"))
    subprocess.run([sys.executable, str(ROOT / "examples/parts/make_parts.py"), "--bench", str(tmp)], check=True,
                   capture_output=True)
    shutil.copy(ROOT / "examples/parts/calibration_cube.stl", tmp / "calibration_cube.stl")
    ini = tmp / "prusa.ini"
    ini.write_text(prusa_ini(printer))
    rows = []
    for part in ("calibration_cube.stl", "twisted_vase.stl"):
        stl = tmp / part
        ours_out, theirs_out = tmp / (stl.stem + "_ds.gcode"), tmp / (stl.stem + "_ps.gcode")
        ours_cmd = [sys.executable, "-m", "deltaslice", "slice", str(stl), "--printer", str(ROOT / args.printer),
                    "-o", str(ours_out), "--quiet"]
        theirs_cmd = [prusa, "--export-gcode", "--load", str(ini), str(stl), "-o", str(theirs_out)]
        t_ours, t_theirs = [], []
        for _ in range(args.runs):  # alternate so drift hits both alike
            t_ours.append(timed(ours_cmd))
            t_theirs.append(timed(theirs_cmd))
        v_o, l_o, m_o = volume_and_layers(ours_out, printer.tool.filament_diameter)
        v_t, l_t, m_t = volume_and_layers(theirs_out, printer.tool.filament_diameter)
        rows.append((part, statistics.median(t_ours), statistics.median(t_theirs), v_o, v_t, l_o, l_t, m_o, m_t))
    print(f"printer {printer.name}; {args.runs} alternating runs each; wall time of the whole process")
    print("| part | deltaslice s | prusa-slicer s | time ratio | deltaslice mm^3 | prusa-slicer mm^3 | volume diff | layers (ds/ps) | moves (ds/ps) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for part, to, tt, vo, vt, lo, lt, mo, mt in rows:
        print(f"| {part} | {to:.2f} | {tt:.2f} | {to / tt:.2f}x | {vo:.0f} | {vt:.0f} | {100 * (vo - vt) / vt:+.1f} % | {lo}/{lt} | {mo}/{mt} |")
    print(f"(files in {tmp})")


if __name__ == "__main__":
    main()
