"""Brim (issue 53): loops touching the part's outer outline on the first layer only."""

from pathlib import Path

import numpy as np
import pytest
import shapely

from deltaslice.machine import load_printer
from deltaslice.mesh import load_mesh
from deltaslice.slicing import slice_mesh
from deltaslice.slicing.extrusion import bead_spacing
from deltaslice.slicing.skirt import brim_extent
from deltaslice.toolpath import Role

from . import meshes

# ../shared/parts beside the checkout (a worktree one level deeper looks one level further up)
PARTS = next((d / "shared" / "parts" for d in Path(__file__).resolve().parents[2:4] if (d / "shared" / "parts").is_dir()),
             Path(__file__).resolve().parents[1] / "shared" / "parts")


def _kossel(brim=5.0):
    return load_printer("linear_kossel", {"slicing.brim_width": brim})


def _first_layer_points(tp, role=None):
    w = tp.working & (tp.layer == 0)
    if role is not None:
        w &= tp.role == role
    return np.concatenate([tp.starts[w, :2], tp.xyz[w, :2]])


def _outside(points, region):
    """Signed distance of points outside ``region`` (shapely), mm: negative inside."""
    pts = shapely.points(points)
    d = shapely.distance(region.boundary, pts)
    return np.where(shapely.contains(region, pts), -d, d)


def _check_cube_brim(tp, p, square):
    s = p.slicing
    w = s.first_layer_width
    sp = bead_spacing(w, s.first_layer_height)
    extent = brim_extent(s.brim_width, w, sp)
    d = _outside(_first_layer_points(tp), square)
    # the first layer's extrusion reaches at least 4.5 mm beyond the part (bead edge)
    assert d.max() + w / 2 >= 4.5, d.max()
    # the brim: outside the part, its innermost bead touching the outline, as wide as asked
    skirt_pts = _first_layer_points(tp, Role.SKIRT)
    ds = _outside(skirt_pts, square)
    brim = ds < extent + 1e-6
    assert brim.sum() > 100
    assert ds[brim].min() > 0 and ds[brim].min() - w / 2 <= 0.05 * w, ds[brim].min()
    assert abs(ds[brim].max() + w / 2 - extent) < 0.02 and extent <= s.brim_width + 1e-9
    # the skirt keeps its distance from the brim's edge
    assert ds[~brim].min() - w / 2 >= extent + s.skirt_distance - 0.02
    # first layer only
    assert not np.any(tp.working & (tp.layer > 0) & (tp.role == Role.SKIRT))


def test_brim_lies_outside_the_box_touches_it_and_is_5_mm_wide():
    p = _kossel()
    tp = slice_mesh(meshes.box(20, 20, 2), p.slicing, p.tool)
    _check_cube_brim(tp, p, shapely.box(-10, -10, 10, 10))


def test_no_brim_by_default_and_none_in_holes():
    p = load_printer("linear_kossel")
    assert p.slicing.brim_width == 0
    tp = slice_mesh(meshes.box(20, 20, 1), p.slicing, p.tool)
    d = _outside(_first_layer_points(tp, Role.SKIRT), shapely.box(-10, -10, 10, 10))
    assert d.min() >= p.slicing.skirt_distance  # only the skirt
    p = _kossel()
    tp = slice_mesh(meshes.cube_with_hole(20.0, 4.0), p.slicing, p.tool)
    pts = _first_layer_points(tp, Role.SKIRT)
    assert np.hypot(pts[:, 0], pts[:, 1]).min() > 10.0


@pytest.mark.skipif(not (PARTS / "20mm_cube.obj").is_file(), reason="../shared/parts is absent")
def test_brim_on_the_20mm_cube():
    p = _kossel()
    mesh = load_mesh(PARTS / "20mm_cube.obj")
    tp = slice_mesh(mesh, p.slicing, p.tool)
    lo, hi = mesh.vertices[:, :2].min(axis=0), mesh.vertices[:, :2].max(axis=0)
    _check_cube_brim(tp, p, shapely.box(*lo, *hi))
