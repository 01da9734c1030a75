"""Slicing benchmark: deltaslice against prusa-slicer on the same meshes and settings.

    python benchmarks/bench_slicing.py [--runs 5] [--printer printers/delta_etitc.toml]

Writes the parts into a temporary directory (examples/parts/make_parts.py), writes
an equivalent PrusaSlicer ini from the printer file's [slicing] and [tool] tables,
then alternates runs of both slicers and reports median wall times (each
measured as a whole process: ``python -m deltaslice slice`` and
``prusa-slicer --export-gcode``), extruded filament volume and layer count.
Not a test: run it by hand; results go in docs/benchmarks.md.

    python benchmarks/bench_slicing.py --real [--parts extruder_idler.obj bridge.obj ...]

slices the real parts in ../shared/parts (at the scales of its README) with both
slicers once each, PrusaSlicer with its own features on, and compares the
G-code layer by layer on a 0.05 mm raster: the part of the mesh cross-section
that PrusaSlicer covers with perimeters, gap fill, solid or bridge infill and
deltaslice leaves without any bead (deltaslice's beads grown by 0.1 mm, so a
bead placed a hair differently is not a void), islands of the cross-section
PrusaSlicer extrudes on and deltaslice does not, travels, retractions, extruded
volume, moves, wall time and peak memory (``/usr/bin/time``) of each process, and the time of ``slice_mesh`` alone (in this
process, imports warm, mesh loaded) against PrusaSlicer's whole process.
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
            f"gcode_resolution = {s.gcode_resolution}",
            f"solid_infill_below_area = {s.solid_infill_below_area:g}",
            f"bridge_speed = {s.bridge_speed}",
            f"bridge_flow_ratio = {s.bridge_flow}",
            f"skirts = {s.skirt_loops}",
            f"skirt_distance = {s.skirt_distance}",
            "skirt_height = 1",
            "min_skirt_length = 0",
            "brim_width = 0",
            f"retract_length = {t.retract_length}",
            f"retract_speed = {t.retract_speed}",
            f"retract_lift = {t.z_hop}",
            f"retract_before_travel = {t.retract_min_travel}",
            # PrusaSlicer's own features on (its 2.5 defaults: Arachne perimeters, gap fill,
            # bridges, overhangs, solid infill below 70 mm^2) plus thin walls
            "gap_fill_enabled = 1",
            "thin_walls = 1",
            "ensure_vertical_shell_thickness = 1",
            "overhangs = 1",
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


# real parts and their scales (../shared/parts/README.md)
REAL_PARTS = {
    "extruder_idler.obj": 1.0, "idler_riser.STL": 25.4, "featuretype.STL": 20.0, "A.obj": 1.0, "bridge.obj": 1.0,
    "20mm_cube.obj": 1.0, "7_8ths_cube.stl": 1.0, "pyramid.obj": 1.0, "overhang.obj": 1.0, "U_overhang.obj": 1.0,
    "sloping_hole.obj": 1.0, "cube_with_concave_hole.obj": 1.0, "two_hollow_squares.obj": 1.0, "Prusa.stl": 0.5,
    "plate_holes.STL": 0.35,
}
PX = 0.05  # raster pixel, mm
TOLERANCE = 0.1  # mm: deltaslice's beads grown by this before comparing
FILL_ROLES = ("EXTERNAL_PERIMETER", "PERIMETER", "SOLID_INFILL", "TOP_SOLID_INFILL", "OVERHANG_PERIMETER",
              "BRIDGE_INFILL", "GAP_FILL")


def timed_mem(cmd) -> tuple[float, float, str]:
    """Wall time (s), peak resident memory (MB) and stdout of a whole process."""
    t0 = time.perf_counter()
    r = subprocess.run(["/usr/bin/time", "-f", "MAXRSS %M", *map(str, cmd)], capture_output=True, text=True, cwd=ROOT)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"failed: {' '.join(map(str, cmd))}\n{r.stderr[-2000:]}")
    rss = [ln for ln in r.stderr.splitlines() if ln.startswith("MAXRSS")]
    return dt, float(rss[-1].split()[1]) / 1024 if rss else float("nan"), r.stdout


def gcode_stats(tp, filament_diameter: float) -> dict:
    """Travels (moves between runs), retractions, volume (mm^3), moves of a toolpath read from G-code."""
    import numpy as np

    work = tp.working
    starts = np.flatnonzero(work & ~np.concatenate([[False], work[:-1]]))
    retracts = int(np.sum((~work) & (tp.e < 0)))
    area = math.pi * filament_diameter**2 / 4
    return {"travels": max(len(starts) - 1, 0), "retracts": retracts, "volume": float(tp.e[work].sum() * area),
            "moves": int(work.sum())}


def _layer_index(tp, z_tops):
    """Layer of each move by the z it is printed at (PrusaSlicer and deltaslice number layers alike
    only when both print every layer)."""
    import numpy as np

    return np.searchsorted(z_tops + 1e-3, tp.xyz[:, 2])


def coverage_raster(tp, moves, height: float, origin, shape, filament_area: float, grow: float):
    """Boolean raster (rows = y) of the beads of ``moves`` (indices into ``tp``): each move a
    line as wide as its extruded volume says (rectangle width + the rounded ends'
    h * (1 - pi/4)), grown by ``grow`` mm."""
    import numpy as np
    from PIL import Image, ImageDraw

    img = Image.new("1", (shape[1], shape[0]), 0)
    d = ImageDraw.Draw(img)
    if len(moves):
        prev = np.concatenate([[tp.start], tp.xyz])[moves]
        cur = tp.xyz[moves]
        length = np.linalg.norm(cur[:, :2] - prev[:, :2], axis=1)
        ok = length > 1e-6
        w = np.zeros(len(moves))
        w[ok] = tp.e[moves][ok] * filament_area / (length[ok] * height) + height * (1 - math.pi / 4)
        w = (w + 2 * grow) / PX
        a = (prev[:, :2] - origin) / PX
        b = (cur[:, :2] - origin) / PX
        for (ax, ay), (bx, by), wi in zip(a[ok].tolist(), b[ok].tolist(), w[ok].tolist()):
            d.line([(ax, ay), (bx, by)], fill=1, width=max(int(round(wi)), 1))
            r = wi / 2
            d.ellipse([bx - r, by - r, bx + r, by + r], fill=1)
    return np.asarray(img, bool)


def section_raster(polys, origin, shape):
    """Even-odd raster of cross-section contours."""
    import numpy as np
    from PIL import Image, ImageDraw

    acc = np.zeros(shape, bool)
    for p in polys:
        img = Image.new("1", (shape[1], shape[0]), 0)
        ImageDraw.Draw(img).polygon([tuple(q) for q in ((np.asarray(p) - origin) / PX).tolist()], fill=1)
        acc ^= np.asarray(img, bool)
    return acc


def compare(stl: Path, scale: float, ours_gc: Path, theirs_gc: Path, printer) -> dict:
    """Per-part void and island figures (see the module docstring)."""
    import numpy as np
    from scipy import ndimage

    from deltaslice.gcode import read_gcode
    from deltaslice.mesh import load_mesh
    from deltaslice.slicing.layers import layer_heights
    from deltaslice.toolpath import Role

    s = printer.slicing
    mesh = load_mesh(stl, scale=scale)
    manifold = mesh.to_manifold()
    height = float(mesh.vertices[:, 2].max())
    tops, mids, thick = layer_heights(height, s.layer_height, s.first_layer_height)
    ours, theirs = read_gcode(ours_gc), read_gcode(theirs_gc)
    fill_roles = np.array([int(getattr(Role, r)) for r in FILL_ROLES])
    area_fil = math.pi * printer.tool.filament_diameter**2 / 4
    lo = mesh.vertices[:, :2].min(axis=0) - 2.0
    hi = mesh.vertices[:, :2].max(axis=0) + 2.0
    shape = (int(math.ceil((hi[1] - lo[1]) / PX)), int(math.ceil((hi[0] - lo[0]) / PX)))
    li_o, li_t = _layer_index(ours, tops), _layer_index(theirs, tops)
    section_total = void_total = 0.0
    lost = 0
    void_layers = 0
    for li, z in enumerate(mids):
        polys = manifold.slice(float(z)).to_polygons()
        if not polys:
            continue
        sec = section_raster(polys, lo, shape)
        mo = np.flatnonzero((li_o == li) & ours.working)
        mt = np.flatnonzero((li_t == li) & theirs.working & np.isin(theirs.role, fill_roles))
        cov_o = coverage_raster(ours, mo, thick[li], lo, shape, area_fil, TOLERANCE)
        cov_t = coverage_raster(theirs, mt, thick[li], lo, shape, area_fil, 0.0)
        void = sec & cov_t & ~cov_o
        section_total += sec.sum() * PX * PX
        v = void.sum() * PX * PX
        void_total += v
        void_layers += v > 0.5  # mm^2
        lab, n = ndimage.label(sec)
        if n:
            t_any = ndimage.maximum(cov_t | coverage_raster(theirs, np.flatnonzero((li_t == li) & theirs.working), thick[li], lo, shape, area_fil, 0.0), lab, np.arange(1, n + 1))
            o_any = ndimage.maximum(cov_o, lab, np.arange(1, n + 1))
            lost += int(np.sum(np.asarray(t_any, bool) & ~np.asarray(o_any, bool)))
    return {"section": section_total, "void": void_total, "void_layers": int(void_layers), "lost": lost}


def real(args, printer, prusa):
    parts_dir = ROOT.parent / "shared" / "parts"
    if not parts_dir.is_dir():
        raise SystemExit(f"{parts_dir} not found")
    tmp = Path(tempfile.mkdtemp(prefix="bench_slicing_real_"))
    ini = tmp / "prusa.ini"
    ini.write_text(prusa_ini(printer))
    names = args.parts or list(REAL_PARTS)[:5]
    rows = []
    from deltaslice.gcode import read_gcode

    for name in names:
        scale = REAL_PARTS.get(name, 1.0)
        stl = parts_dir / name
        ours_out, theirs_out = tmp / (stl.stem + "_ds.gcode"), tmp / (stl.stem + "_ps.gcode")
        ours_cmd = [sys.executable, "-m", "deltaslice", "slice", str(stl), "--printer", str(ROOT / args.printer),
                    "--scale", str(scale), "-o", str(ours_out), "--quiet"]
        theirs_cmd = [prusa, "--export-gcode", "--load", str(ini), "--scale", str(scale), "--center", "0,0",
                      str(stl), "-o", str(theirs_out)]
        try:
            t_o, m_o, _ = timed_mem(ours_cmd)
            t_t, m_t, _ = timed_mem(theirs_cmd)
        except SystemExit as e:  # one part failing does not lose the table
            print(f"{name}: {e}", file=sys.stderr)
            continue
        # slicing alone: slice_mesh in this process, imports warm, mesh already loaded
        from deltaslice.mesh import load_mesh
        from deltaslice.slicing import slice_mesh

        mesh = load_mesh(stl, scale=scale)
        t0 = time.perf_counter()
        slice_mesh(mesh, printer.slicing, printer.tool)
        t_in = time.perf_counter() - t0
        so = gcode_stats(read_gcode(ours_out), printer.tool.filament_diameter)
        st = gcode_stats(read_gcode(theirs_out), printer.tool.filament_diameter)
        c = compare(stl, scale, ours_out, theirs_out, printer)
        rows.append((name, scale, c, so, st, t_o, t_t, m_o, m_t, t_in))
        print(name, c, so, st, f"{t_o:.2f}s/{t_t:.2f}s", file=sys.stderr)
    print(f"printer {printer.name}; one run each; raster {PX} mm, deltaslice beads grown {TOLERANCE} mm")
    print("| part (scale) | void mm^2 (% of section) | layers with void | islands lost | travels ds/ps | retracts ds/ps "
          "| volume mm^3 ds/ps | moves ds/ps | wall s ds/ps | slice_mesh s (/ps wall) | peak MB ds/ps |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for name, scale, c, so, st, t_o, t_t, m_o, m_t, t_in in rows:
        pct = 100 * c["void"] / c["section"] if c["section"] else 0.0
        print(f"| {name} ({scale:g}) | {c['void']:.1f} ({pct:.2f} %) | {c['void_layers']} | {c['lost']} "
              f"| {so['travels']}/{st['travels']} ({so['travels'] / max(st['travels'], 1):.2f}x) "
              f"| {so['retracts']}/{st['retracts']} | {so['volume']:.0f}/{st['volume']:.0f} | {so['moves']}/{st['moves']} "
              f"| {t_o:.2f}/{t_t:.2f} ({t_o / t_t:.2f}x) | {t_in:.2f} ({t_in / t_t:.2f}x) | {m_o:.0f}/{m_t:.0f} |")
    print(f"(files in {tmp})")


def main(argv=None):
    from deltaslice.machine import load_printer

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--printer", default="printers/delta_etitc.toml")
    ap.add_argument("--real", action="store_true", help="the real parts in ../shared/parts instead")
    ap.add_argument("--parts", nargs="*", help="with --real: file names (default: the issue's five parts)")
    args = ap.parse_args(argv)
    prusa = shutil.which("prusa-slicer")
    if prusa is None:
        raise SystemExit("prusa-slicer not found on PATH")
    printer = load_printer(ROOT / args.printer)
    if args.real:
        return real(args, printer, prusa)
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
