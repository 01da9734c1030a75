"""Solid volume (issue 53): at 100 % fill a part's plastic is the sliced volume within 2 %."""

from pathlib import Path

import numpy as np
import pytest

from deltaslice.machine import load_printer
from deltaslice.mesh import load_mesh
from deltaslice.slicing import slice_mesh
from deltaslice.slicing.sections import mesh_sections
from deltaslice.toolpath import Role

from . import meshes

PARTS = next((d / "shared" / "parts" for d in Path(__file__).resolve().parents[2:4] if (d / "shared" / "parts").is_dir()),
             Path(__file__).resolve().parents[1] / "shared" / "parts")


def _solid(name):
    return load_printer(name, {"slicing.fill_density": 1.0, "slicing.skirt_loops": 0})


def _ratio(mesh, p):
    """Plastic laid over the volume of the layers' sections (area x thickness: the layer stack
    may end up to half a layer above the part), and over the mesh's own volume."""
    tp = slice_mesh(mesh, p.slicing, p.tool)
    th = np.diff(np.concatenate([[0.0], tp.layer_z]))
    sliced = sum(c.area() * t for c, t in zip(mesh_sections(mesh, tp.layer_z - th / 2), th))
    vol = tp.extruded_volume(p.tool.filament_diameter)
    return vol / sliced, vol / mesh.volume, tp


@pytest.mark.parametrize("printer", ["delta_etitc", "linear_kossel"])
@pytest.mark.parametrize("make", [lambda: meshes.box(20, 20, 6), lambda: meshes.cube_with_hole(20.0, 4.0), meshes.step,
                                  lambda: meshes.cylinder(8.0, 5.0)])
def test_solid_parts_lay_their_sliced_volume(printer, make):
    per_layer, _, tp = _ratio(make(), _solid(printer))
    assert 0.98 <= per_layer <= 1.02, per_layer
    assert not np.any(tp.working & (tp.role == Role.INFILL))


def test_sparse_parts_keep_their_solid_shells_exact():
    """At 20 % the sparse lines are not scaled; the solid layers are, so the shells are no heavier
    than the solid part's same layers."""
    p = load_printer("linear_kossel", {"slicing.skirt_loops": 0})
    tp = slice_mesh(meshes.box(20, 20, 6), p.slicing, p.tool)
    solid = tp.working & np.isin(tp.role, [Role.SOLID_INFILL, Role.TOP_SOLID_INFILL])
    sparse = tp.working & (tp.role == Role.INFILL)
    assert solid.any() and sparse.any()
    fpm = tp.e / np.maximum(tp.lengths, 1e-12)
    # same width and height: the sparse lines keep the bead model's flow, the solid ones no more than it
    later = tp.layer > 0
    assert np.median(fpm[solid & later]) <= np.median(fpm[sparse & later]) + 1e-12


@pytest.mark.skipif(not PARTS.is_dir(), reason="../shared/parts is absent")
@pytest.mark.parametrize("name,scale", [("20mm_cube.obj", 1.0), ("small_dorito.obj", 1.0), ("sloping_hole.obj", 1.0),
                                        ("featuretype.STL", 20.0)])
def test_real_solid_parts_extrude_their_mesh_volume(name, scale):
    mesh = load_mesh(PARTS / name, scale=scale)
    _, of_mesh, _ = _ratio(mesh, _solid("delta_etitc"))
    assert 0.98 <= of_mesh <= 1.02, (name, of_mesh)


def test_grid_infill_lays_both_directions_on_every_layer_with_the_same_plastic():
    base = {"slicing.skirt_loops": 0, "slicing.top_solid_layers": 0, "slicing.bottom_solid_layers": 0}
    lines = load_printer("linear_kossel", base)
    grid = load_printer("linear_kossel", {**base, "slicing.fill_pattern": "grid"})
    mesh = meshes.box(30, 30, 3)
    a = slice_mesh(mesh, lines.slicing, lines.tool)
    b = slice_mesh(mesh, grid.slicing, grid.tool)
    for tp in (a, b):
        assert np.any(tp.working & (tp.role == Role.INFILL))
    va = a.e[a.working & (a.role == Role.INFILL)].sum()
    vb = b.e[b.working & (b.role == Role.INFILL)].sum()
    # the same lines' plastic, plus a second set of links along the outline (10 % on a 30 mm square)
    assert va < vb < 1.15 * va
    for li in (3, 4):
        m = b.working & (b.role == Role.INFILL) & (b.layer == li)
        d = (b.xyz - b.starts)[m, :2]
        long = np.hypot(d[:, 0], d[:, 1]) > 5.0
        angles = set((np.round(np.degrees(np.arctan2(d[long, 1], d[long, 0]))) % 180).astype(int).tolist())
        assert {45, 135} <= angles, angles
