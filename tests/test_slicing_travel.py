"""Travels (issue 53): a hole's loops printed together, solid and sparse infill ordered together,
travel length against PrusaSlicer's on the same settings."""

import importlib.util
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import trimesh

from deltaslice.gcode import read_gcode
from deltaslice.machine import load_printer
from deltaslice.mesh import load_mesh
from deltaslice.slicing import slice_mesh
from deltaslice.toolpath import Role

from . import meshes

ROOT = Path(__file__).resolve().parents[1]
PARTS = next((d / "shared" / "parts" for d in Path(__file__).resolve().parents[2:4] if (d / "shared" / "parts").is_dir()),
             ROOT.parent / "shared" / "parts")


def plate_with_holes():
    """A 30 x 30 x 2 mm plate with a 3 x 3 grid of 4 mm holes 9 mm apart."""
    plate = trimesh.creation.box((30, 30, 2))
    plate.apply_translation((0, 0, 1))
    holes = []
    for x in (-9, 0, 9):
        for y in (-9, 0, 9):
            c = trimesh.creation.cylinder(radius=2.0, height=6, sections=32)
            c.apply_translation((x, y, 1))
            holes.append(c)
    return meshes._mesh(trimesh.boolean.difference([plate, *holes], engine="manifold"), "plate with holes")


def _travel_xy(tp):
    """xy length of the travels between the first and the last working move, mm."""
    w = tp.working
    d = np.hypot(*(tp.xyz[:, :2] - tp.starts[:, :2]).T)
    first, last = int(np.argmax(w)), len(w) - int(np.argmax(w[::-1]))
    sel = ~w
    sel[:first] = sel[last:] = False
    return float(d[sel].sum())


def test_each_holes_loops_are_printed_together():
    p = load_printer("linear_kossel", {"slicing.skirt_loops": 0})
    tp = slice_mesh(plate_with_holes(), p.slicing, p.tool)
    loops = (Role.EXTERNAL_PERIMETER, Role.PERIMETER)
    for li in range(1, tp.n_layers):
        sl = tp.layer_slices()[li]
        runs = [(a, b) for a, b in tp.runs() if sl.start <= a < sl.stop and tp.role[a] in loops]
        roles = [int(tp.role[a]) for a, _ in runs]
        # inner loop, external loop; inner loop, external loop; ...: ten outlines (nine holes and the plate)
        assert roles == [Role.PERIMETER, Role.EXTERNAL_PERIMETER] * 10, roles
        for (a, b), (c, _d) in zip(runs[::2], runs[1::2]):
            # a hole's external loop starts right beside where its inner loop ended
            assert np.hypot(*(tp.xyz[b - 1, :2] - tp.starts[c, :2])) < 2 * p.slicing.perimeter_width


def test_a_solid_strip_does_not_cost_a_trip_across_the_island():
    """Solid and sparse infill are ordered together: the travels of a layer with both are not
    longer than two island widths."""
    p = load_printer("linear_kossel", {"slicing.skirt_loops": 0})
    tp = slice_mesh(meshes.step(), p.slicing, p.tool)
    for li in range(tp.n_layers):
        sl = tp.layer_slices()[li]
        roles = set(tp.role[sl][tp.working[sl]].tolist())
        if Role.INFILL in roles and Role.SOLID_INFILL in roles:
            sub = tp.subset(sl)
            assert _travel_xy(sub) < 2 * 20.0


def _prusa_ini(printer) -> str:
    spec = importlib.util.spec_from_file_location("bench_slicing", ROOT / "benchmarks" / "bench_slicing.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.prusa_ini(printer)


@pytest.mark.skipif(not PARTS.is_dir(), reason="../shared/parts is absent")
@pytest.mark.parametrize("name,scale", [("plate_holes.STL", 0.35), ("small_dorito.obj", 1.0)])
def test_travel_length_within_115_percent_of_prusaslicer(name, scale, tmp_path):
    exe = shutil.which("prusa-slicer")
    if exe is None:
        pytest.skip("prusa-slicer is not installed")
    p = load_printer("delta_etitc")
    ini = tmp_path / "p.ini"
    ini.write_text(_prusa_ini(p))
    out = tmp_path / "ps.gcode"
    run = subprocess.run([exe, "--export-gcode", "--load", str(ini), "--scale", str(scale), "--center", "0,0",
                          str(PARTS / name), "-o", str(out)], capture_output=True, text=True)
    if run.returncode != 0:
        pytest.skip(f"prusa-slicer failed: {run.stderr[-300:]}")
    ours = _travel_xy(slice_mesh(load_mesh(PARTS / name, scale=scale), p.slicing, p.tool))
    theirs = _travel_xy(read_gcode(out))
    assert ours <= 1.15 * theirs, (ours, theirs)
