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
PrusaSlicer extrudes on and deltaslice does not, overlap (raster cells two or
more moves cover over cells one or more cover, each move a flat-ended rectangle
as wide as the plastic it carries spreads at the layer's height), travel length
and count, retractions, overhang perimeter length, extruded volume, wall time and
peak memory (``/usr/bin/time``) of each process, and the time of ``slice_mesh``
alone (in this process, imports warm, mesh loaded) against PrusaSlicer's whole
process. ``--pictures DIR`` writes, per part, a PNG of the layer where the two
differ most (see ``layer_picture``).
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
    "plate_holes.STL": 0.35, "small_dorito.obj": 1.0,
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
    """Travels (count of moves between runs) and their xy length between the first and the last
    extrusion (mm), retractions, overhang perimeter length (mm), volume (mm^3), moves of a
    toolpath read from G-code."""
    import numpy as np

    from deltaslice.toolpath import Role

    work = tp.working
    starts = np.flatnonzero(work & ~np.concatenate([[False], work[:-1]]))
    retracts = int(np.sum((~work) & (tp.e < 0)))
    area = math.pi * filament_diameter**2 / 4
    dxy = np.hypot(*(tp.xyz[:, :2] - tp.starts[:, :2]).T)
    travel = ~work
    if work.any():
        first, last = int(np.argmax(work)), len(work) - int(np.argmax(work[::-1]))
        travel[:first] = travel[last:] = False
    else:
        travel[:] = False
    overhang = work & (tp.role == int(Role.OVERHANG_PERIMETER))
    return {"travels": max(len(starts) - 1, 0), "travel_mm": float(dxy[travel].sum()), "retracts": retracts,
            "overhang_mm": float(dxy[overhang].sum()), "volume": float(tp.e[work].sum() * area),
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


def count_raster(tp, moves, height: float, origin, shape, filament_area: float, piece: float = 1.0):
    """(rows = y) int32 raster: how many of ``moves`` cover each cell. Each move is a flat-ended
    rectangle as wide as its plastic spreads at ``height`` (E x filament area / (length x height):
    Slic3r's spacing, so beads laid at it touch without overlapping). Vectorised: moves cut into
    pieces at most ``piece`` mm long, every cell of a piece's bounding box tested at once."""
    import numpy as np

    count = np.zeros(shape[0] * shape[1], np.int32)
    if not len(moves):
        return count.reshape(shape)
    prev = np.concatenate([[tp.start], tp.xyz])[moves][:, :2]
    cur = tp.xyz[moves][:, :2]
    length = np.linalg.norm(cur - prev, axis=1)
    ok = length > 1e-6
    prev, cur, length = (prev[ok] - origin) / PX, (cur[ok] - origin) / PX, length[ok]
    half = tp.e[moves][ok] * filament_area / (length * height) / PX / 2
    n = np.maximum(np.ceil(length / piece), 1).astype(np.int64)
    seg = np.repeat(np.arange(len(n)), n)
    k = np.arange(len(seg)) - np.repeat(np.cumsum(n) - n, n)
    t0, t1 = k / n[seg], (k + 1) / n[seg]  # piece = [t0, t1) of its move, in fractions
    a, d = prev[seg], (cur - prev)[seg]
    p0, p1 = a + d * t0[:, None], a + d * t1[:, None]
    h = half[seg]
    lo = np.floor(np.minimum(p0, p1) - h[:, None]).astype(np.int64)
    hi = np.ceil(np.maximum(p0, p1) + h[:, None]).astype(np.int64)
    lo = np.clip(lo, 0, [shape[1], shape[0]])
    hi = np.clip(hi, 0, [shape[1], shape[0]])
    nx, ny = hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1]
    cells = np.maximum(nx, 0) * np.maximum(ny, 0)
    ln = np.linalg.norm(d, axis=1)
    u = d / ln[:, None]
    bounds = np.searchsorted(np.cumsum(cells), np.arange(0, cells.sum() + 4_000_000, 4_000_000))
    start = 0
    for stop in np.unique(np.append(bounds[1:], len(cells))):  # chunks of about 4 M cells
        sel = np.arange(start, stop)
        start = stop
        c = cells[sel]
        if not c.sum():
            continue
        pi = np.repeat(sel, c)
        j = np.arange(len(pi)) - np.repeat(np.cumsum(c) - c, c)
        x = lo[pi, 0] + j % nx[pi]
        y = lo[pi, 1] + j // nx[pi]
        rx, ry = x + 0.5 - a[pi, 0], y + 0.5 - a[pi, 1]
        along = (rx * u[pi, 0] + ry * u[pi, 1]) / ln[pi]
        across = np.abs(rx * u[pi, 1] - ry * u[pi, 0])
        inside = (along >= t0[pi]) & (along < t1[pi]) & (across <= h[pi])
        count += np.bincount((y * shape[1] + x)[inside], minlength=len(count)).astype(np.int32)
    return count.reshape(shape)


PALETTE = [255, 255, 255, 215, 215, 215, 60, 110, 200, 220, 30, 30, 255, 150, 0, 0, 0, 0]


def layer_picture(path: Path, sec, count_o, count_t, missing_o, missing_t, title: str, max_width: int = 900):
    """PNG of one layer, deltaslice left, PrusaSlicer right. Each panel: white outside the part,
    light grey the section no bead covers, blue cells one move covers, red two or more (overlap),
    orange where the other slicer lays a dense bead (perimeter, solid, bridge, gap fill) and this
    one no bead within 0.1 mm. Downsampled by blocks (each block the colour most of its cells
    have, red and orange counted double)."""
    import numpy as np
    from PIL import Image, ImageDraw

    def panel(count, missing):
        img = np.where(sec, 1, 0).astype(np.uint8)
        img[count == 1] = 2
        img[count >= 2] = 3
        img[missing] = 4
        return img

    a, b = panel(count_o, missing_o), panel(count_t, missing_t)
    rows, cols = np.nonzero((a > 0) | (b > 0))
    if not len(rows):
        return
    a = a[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    b = b[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    f = max(1, math.ceil(2 * a.shape[1] / max_width))
    hh, ww = (a.shape[0] // f) * f, (a.shape[1] // f) * f

    def down(img):
        if f == 1:
            return img
        blocks = img[:hh, :ww].reshape(hh // f, f, ww // f, f).transpose(0, 2, 1, 3).reshape(hh // f, ww // f, f * f)
        counts = np.stack([(blocks == v).sum(axis=2) for v in range(5)], axis=2)
        counts[..., 3:] *= 2  # overlap and missing beads are thin: they win a block at a third of its cells
        return counts.argmax(axis=2).astype(np.uint8)

    a, b = down(a)[::-1], down(b)[::-1]  # rows = y: flip so +y is up
    gap, top = 8, 28
    out = np.zeros((a.shape[0] + top, 2 * a.shape[1] + gap), np.uint8)
    out[top:, :a.shape[1]] = a
    out[top:, a.shape[1] + gap:] = b
    im = Image.fromarray(out, "P")
    im.putpalette(PALETTE)
    d = ImageDraw.Draw(im)
    d.text((2, 1), title, fill=5)
    d.text((2, 14), "deltaslice", fill=5)
    d.text((a.shape[1] + gap + 2, 14), "PrusaSlicer 2.5", fill=5)
    im.save(path, optimize=True)


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


def compare(stl: Path, scale: float, ours_gc: Path, theirs_gc: Path, printer, picture: Path | None = None) -> dict:
    """Per-part void, island and overlap figures (see the module docstring), and the layer where
    the two differ most: the most cells one slicer covers with a dense bead (perimeter, solid,
    bridge, gap fill) and the other leaves without any bead within 0.1 mm, both ways; its picture
    in ``picture`` if given."""
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
    over = {"o": [0, 0], "t": [0, 0]}  # cells covered twice or more, once or more
    worst = (-1.0, None)
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
        n_o = count_raster(ours, np.flatnonzero((li_o == li) & ours.working), thick[li], lo, shape, area_fil)
        n_t = count_raster(theirs, np.flatnonzero((li_t == li) & theirs.working), thick[li], lo, shape, area_fil)
        for key, n_ in (("o", n_o), ("t", n_t)):
            over[key][0] += int((n_ >= 2).sum())
            over[key][1] += int((n_ >= 1).sum())
        dense_o = coverage_raster(ours, np.flatnonzero((li_o == li) & ours.working & np.isin(ours.role, fill_roles)),
                                  thick[li], lo, shape, area_fil, 0.0)
        any_t = coverage_raster(theirs, np.flatnonzero((li_t == li) & theirs.working), thick[li], lo, shape, area_fil,
                                TOLERANCE)
        miss_o, miss_t = cov_t & ~cov_o, dense_o & ~any_t
        differ = float(miss_o.sum() + miss_t.sum()) * PX * PX
        if differ > worst[0]:
            worst = (differ, (li, float(z), sec, n_o, n_t, miss_o, miss_t))
    out = {"section": section_total, "void": void_total, "void_layers": int(void_layers), "lost": lost,
           "overlap_o": over["o"][0] / max(over["o"][1], 1), "overlap_t": over["t"][0] / max(over["t"][1], 1),
           "differ_layer": None}
    if worst[1] is not None:
        li, z, sec, n_o, n_t, miss_o, miss_t = worst[1]
        out["differ_layer"] = (li, z, worst[0])
        if picture is not None:
            layer_picture(picture, sec, n_o, n_t, miss_o, miss_t,
                          f"{stl.name} x{scale:g} layer {li} z {z:.2f}: {worst[0]:.0f} mm^2 differ")
    return out


def real(args, printer, prusa):
    parts_dir = Path(args.parts_dir) if args.parts_dir else next(
        (d / "shared" / "parts" for d in ROOT.parents[:2] if (d / "shared" / "parts").is_dir()), ROOT.parent / "shared" / "parts")
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
        pic = None
        if args.pictures:
            Path(args.pictures).mkdir(parents=True, exist_ok=True)
            pic = Path(args.pictures) / f"slicing_{stl.stem}.png"
        c = compare(stl, scale, ours_out, theirs_out, printer, pic)
        rows.append((name, scale, c, so, st, t_o, t_t, m_o, m_t, t_in))
        print(name, c, so, st, f"{t_o:.2f}s/{t_t:.2f}s", file=sys.stderr)
    print(f"printer {printer.name}; one run each; raster {PX} mm, deltaslice beads grown {TOLERANCE} mm")
    print("| part (scale) | void mm^2 (% of section) | layers with void | islands lost | overlap % of extruded cells ds/ps "
          "| volume mm^3 ds/ps (ratio) | travel length mm ds/ps (ratio) | travels (count) ds/ps | retracts (count) ds/ps "
          "| overhang perimeter mm ds/ps | wall s ds/ps | slice_mesh s (/ps wall) | peak MB ds/ps | most different layer (z mm: mm^2) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, scale, c, so, st, t_o, t_t, m_o, m_t, t_in in rows:
        pct = 100 * c["void"] / c["section"] if c["section"] else 0.0
        dl = c["differ_layer"]
        worst = f"{dl[0]} ({dl[1]:.2f}: {dl[2]:.0f})" if dl else "-"
        print(f"| {name} ({scale:g}) | {c['void']:.1f} ({pct:.2f} %) | {c['void_layers']} | {c['lost']} "
              f"| {100 * c['overlap_o']:.1f}/{100 * c['overlap_t']:.1f} "
              f"| {so['volume']:.0f}/{st['volume']:.0f} ({so['volume'] / max(st['volume'], 1e-9):.3f}) "
              f"| {so['travel_mm']:.0f}/{st['travel_mm']:.0f} ({so['travel_mm'] / max(st['travel_mm'], 1e-9):.2f}x) "
              f"| {so['travels']}/{st['travels']} | {so['retracts']}/{st['retracts']} "
              f"| {so['overhang_mm']:.1f}/{st['overhang_mm']:.1f} "
              f"| {t_o:.2f}/{t_t:.2f} ({t_o / t_t:.2f}x) | {t_in:.2f} ({t_in / t_t:.2f}x) | {m_o:.0f}/{m_t:.0f} | {worst} |")
    print(f"(files in {tmp})")


def main(argv=None):
    from deltaslice.machine import load_printer

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--printer", default="printers/delta_etitc.toml")
    ap.add_argument("--real", action="store_true", help="the real parts in ../shared/parts instead")
    ap.add_argument("--parts", nargs="*", help="with --real: file names (default: the first five of REAL_PARTS)")
    ap.add_argument("--parts-dir", help="with --real: the folder of real parts (default: ../shared/parts)")
    ap.add_argument("--pictures", help="with --real: write slicing_<part>.png of the most different layer here")
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
