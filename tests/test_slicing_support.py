"""Supports (issue 53): under every overhang, never inside the part, breaking away by a gap."""

from pathlib import Path

import numpy as np
import pytest
import shapely
import trimesh

from deltaslice.errors import PrinterFileError
from deltaslice.machine import load_printer
from deltaslice.mesh import load_mesh
from deltaslice.slicing import slice_mesh
from deltaslice.slicing.sections import mesh_sections
from deltaslice.slicing.gapfill import to_shapely
from deltaslice.toolpath import Role

from . import meshes

PARTS = next((d / "shared" / "parts" for d in Path(__file__).resolve().parents[2:4] if (d / "shared" / "parts").is_dir()),
             Path(__file__).resolve().parents[1] / "shared" / "parts")
SUPPORT = (Role.SUPPORT, Role.SUPPORT_INTERFACE)


def _printer(**over):
    return load_printer("linear_kossel", {"slicing.support": "auto", **{f"slicing.{k}": v for k, v in over.items()}})


def cantilever():
    """A 4 x 10 x 10 mm post at x -10..-6 holding a 20 x 10 x 2 mm plate at z 10..12: a 16 mm
    cantilever over the bed."""
    post = trimesh.creation.box((4, 10, 10))
    post.apply_translation((-8, 0, 5))
    plate = trimesh.creation.box((20, 10, 2))
    plate.apply_translation((0, 0, 11))
    return meshes._mesh(trimesh.boolean.union([post, plate], engine="manifold"), "cantilever")


def u_shape():
    """A 20 x 10 x 1 mm foot, a 2 mm wall at x -10..-8, a 20 x 10 x 1 mm roof at z 8..9: the
    roof overhangs the foot, not the bed."""
    parts = []
    for size, at in (((20, 10, 1), (0, 0, 0.5)), ((2, 10, 7), (-9, 0, 4.5)), ((20, 10, 1), (0, 0, 8.5))):
        b = trimesh.creation.box(size)
        b.apply_translation(at)
        parts.append(b)
    return meshes._mesh(trimesh.boolean.union(parts, engine="manifold"), "U")


def _support_moves(tp):
    return tp.working & np.isin(tp.role, [int(r) for r in SUPPORT])


def _points(tp, mask):
    return np.concatenate([tp.starts[mask], tp.xyz[mask]])


def _check_clear_of_the_part(tp, mesh, p):
    """Every support bead keeps support_xy_gap from the part's section on its layer, and the
    support_z_gap from the part's sections above and below."""
    s = p.slicing
    sup = _support_moves(tp)
    mids = tp.layer_z - np.diff(np.concatenate([[0.0], tp.layer_z])) / 2
    sections = mesh_sections(mesh, mids)
    gap_layers = int(round(s.support_z_gap / s.layer_height))
    for li in np.unique(tp.layer[sup]):
        m = sup & (tp.layer == li)
        pts = shapely.points(_points(tp, m)[:, :2])
        for k in range(max(0, li - gap_layers), min(len(sections), li + gap_layers + 1)):
            if sections[k].is_empty():
                continue
            part = to_shapely(sections[k])
            clearance = s.support_xy_gap + s.infill_width / 2 if k == li else 0.0
            d = shapely.distance(part, pts)
            assert d.min() >= clearance - 0.02, (li, k, d.min(), clearance)


def test_cantilever_is_supported_on_every_layer_below_it():
    p = _printer()
    mesh = cantilever()
    tp = slice_mesh(mesh, p.slicing, p.tool)
    s = p.slicing
    sup = _support_moves(tp)
    bottom = np.flatnonzero(tp.layer_z > 10.0 + 1e-6)[0]  # first layer of the plate
    gap = int(round(s.support_z_gap / s.layer_height))
    layers = set(np.unique(tp.layer[sup]).tolist())
    assert layers == set(range(0, bottom - gap)), sorted(layers)
    for li in range(bottom - gap):
        m = sup & (tp.layer == li)
        xy = _points(tp, m)[:, :2]
        # under the cantilever, not under the post, reaching across the whole span
        assert xy[:, 0].min() >= -6.0 + s.support_xy_gap - 0.02
        assert xy[:, 0].min() < -6.0 + s.support_xy_gap + s.infill_width
        assert xy[:, 0].max() > 10.0 - s.support_spacing and np.abs(xy[:, 1]).max() <= 5.0 + 1e-6
        assert xy[:, 1].max() - xy[:, 1].min() > 10.0 - s.support_spacing
    # the interface: the top support_interface_layers layers, dense, across the body's lines
    iface = tp.working & (tp.role == Role.SUPPORT_INTERFACE)
    assert set(np.unique(tp.layer[iface]).tolist()) == set(range(bottom - gap - s.support_interface_layers, bottom - gap))
    assert not np.any(tp.working & (tp.role == Role.SUPPORT) & (tp.layer >= bottom - gap - s.support_interface_layers))
    _check_clear_of_the_part(tp, mesh, p)


def test_no_support_by_default_or_without_overhangs():
    assert load_printer("linear_kossel").slicing.support == "none"
    p = load_printer("linear_kossel")
    assert not _support_moves(slice_mesh(cantilever(), p.slicing, p.tool)).any()
    p = _printer()
    assert not _support_moves(slice_mesh(meshes.box(10, 10, 5), p.slicing, p.tool)).any()
    # a 45 deg cone leans less than support_angle (50 deg) from vertical: it holds itself up
    cone = trimesh.creation.cone(radius=6.0, height=6.0, sections=64)
    cone.apply_transform(trimesh.transformations.rotation_matrix(np.pi, (1, 0, 0)))
    cone.apply_translation((0, 0, 6.0))
    tp = slice_mesh(meshes._mesh(cone, "upside-down cone"), p.slicing, p.tool)
    assert not _support_moves(tp).any()


def test_support_stands_on_the_part_everywhere_and_not_at_all_on_the_buildplate_only():
    mesh = u_shape()
    p = _printer()
    tp = slice_mesh(mesh, p.slicing, p.tool)
    sup = _support_moves(tp)
    assert sup.any()
    # it stands on the foot, a z gap above it
    gap = int(round(p.slicing.support_z_gap / p.slicing.layer_height))
    foot_top = int(np.flatnonzero(tp.layer_z <= 1.0 + 1e-6)[-1])
    assert tp.layer[sup].min() == foot_top + gap + 1
    _check_clear_of_the_part(tp, mesh, p)
    p = _printer(support_type="buildplate")
    assert not _support_moves(slice_mesh(mesh, p.slicing, p.tool)).any()


def test_grid_pattern_turns_the_lines_every_layer():
    p = _printer(support_pattern="grid", support_interface_layers=0)
    tp = slice_mesh(cantilever(), p.slicing, p.tool)
    angles = []
    for li in (3, 4):
        m = tp.working & (tp.role == Role.SUPPORT) & (tp.layer == li)
        d = (tp.xyz - tp.starts)[m, :2]
        a = np.round(np.degrees(np.arctan2(d[:, 1], d[:, 0])) % 180).astype(int) % 180
        angles.append(int(np.argmax(np.bincount(a, np.hypot(d[:, 0], d[:, 1]), minlength=180))))  # the lines' angle
    assert abs(angles[0] - angles[1]) == 90, angles


@pytest.mark.parametrize("key,value,bound", [("support", "yes", "one of none, auto"), ("support_angle", 95.0, "<= 89"),
                                             ("support_spacing", 0.1, "infill_width"),
                                             ("support_type", "bed", "everywhere, buildplate")])
def test_support_keys_are_validated_at_load(key, value, bound):
    with pytest.raises(PrinterFileError) as err:
        load_printer("linear_kossel", {f"slicing.{key}": value})
    assert f"slicing.{key}" in str(err.value) and bound in str(err.value), str(err.value)


@pytest.mark.skipif(not (PARTS / "U_overhang.obj").is_file(), reason="../shared/parts is absent")
def test_u_overhang_cantilever_is_supported_on_every_layer_below_it():
    p = _printer()
    mesh = load_mesh(PARTS / "U_overhang.obj")
    tp = slice_mesh(mesh, p.slicing, p.tool)
    s = p.slicing
    gap = int(round(s.support_z_gap / s.layer_height))
    # U_overhang: a 10 x 10 x 1 mm foot, a 1 mm wall at y -5..-4, a 10 x 10 x 1 mm roof at z 10..11
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    foot_top = int(np.flatnonzero(tp.layer_z <= lo[2] + 1.0 + 1e-6)[-1])
    roof = int(np.flatnonzero(tp.layer_z > hi[2] - 1.0 + 1e-6)[0])
    sup = _support_moves(tp)
    assert set(np.unique(tp.layer[sup]).tolist()) == set(range(foot_top + gap + 1, roof - gap))
    for li in range(foot_top + gap + 1, roof - gap):
        xy = _points(tp, sup & (tp.layer == li))[:, :2]
        assert xy[:, 1].min() >= lo[1] + 1.0 + s.support_xy_gap - 0.02  # beside the wall, not in it
        assert xy[:, 1].max() > hi[1] - s.support_spacing
    _check_clear_of_the_part(tp, mesh, p)


def test_support_roles_survive_a_gcode_round_trip():
    from deltaslice.gcode import gcode_text, parse_gcode

    p = _printer()
    tp = slice_mesh(cantilever(), p.slicing, p.tool)
    text = gcode_text(tp, p)
    assert ";TYPE:Support material\n" in text and ";TYPE:Support material interface\n" in text
    back = parse_gcode(text, printer=p)
    for role in SUPPORT:
        assert np.sum(back.working & (back.role == role)) == np.sum(tp.working & (tp.role == role))
    cura = parse_gcode(";TYPE:SUPPORT\nG1 X1 Y0 Z0.2 E0.1 F600\n;TYPE:SUPPORT-INTERFACE\nG1 X2 Y0 E0.2\n", printer=p)
    assert cura.role[cura.working].tolist() == [Role.SUPPORT, Role.SUPPORT_INTERFACE]


def test_the_skirt_goes_around_the_first_layers_support():
    p = load_printer("linear_kossel", {"slicing.support": "auto", "slicing.skirt_loops": 1})
    tp = slice_mesh(cantilever(), p.slicing, p.tool)
    first = tp.working & (tp.layer == 0)
    sup = _points(tp, first & np.isin(tp.role, [int(r) for r in SUPPORT]))[:, :2]
    skirt = _points(tp, first & (tp.role == Role.SKIRT))[:, :2]
    assert len(sup) and len(skirt)
    hull = shapely.MultiPoint(sup).convex_hull
    d = shapely.distance(hull, shapely.points(skirt))
    assert d.min() >= p.slicing.skirt_distance, d.min()


def test_support_sliced_in_workers_is_the_support_sliced_here():
    from deltaslice.pool import can_fork

    if not can_fork():
        pytest.skip("no fork here")
    p = _printer()
    one = slice_mesh(cantilever(), p.slicing, p.tool)
    two = slice_mesh(cantilever(), p.slicing, p.tool, workers=2)
    assert one.equals(two, atol=0)
