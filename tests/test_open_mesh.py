"""Meshes as users have them: open, non-manifold, badly wound, 3MF with objects and
transforms, STL with trailing bytes; sliced layer by layer where manifold3d cannot."""

from __future__ import annotations

import dataclasses
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from deltaslice.errors import MeshError, MeshWarning
from deltaslice.mesh import load_mesh, mesh_from_arrays
from deltaslice.slicing import slice_mesh
from deltaslice.slicing.layers import layer_heights
from deltaslice.slicing.sections import _chain_segments, _close_open, cut_segments, mesh_sections, open_sections

from . import meshes
from .conftest import ROOT, printer

PARTS = ROOT.parent / "shared" / "parts"


def _layers(mesh, h=0.2):
    top, mid, thick = layer_heights(float(mesh.vertices[:, 2].max()), h, h)
    return mid, thick


def _open_box(size=20.0, subdivisions=0):
    """A box without its +x side: a hole each layer crosses with a size-mm gap
    (4 edges, 16 with two subdivisions: more than the hole filler closes)."""
    tm = trimesh.creation.box((size, size, size))
    for _ in range(subdivisions):
        tm = tm.subdivide()
    tm.apply_translation((0, 0, size / 2))
    side = np.isclose(tm.face_normals[:, 0], 1.0)
    tm.update_faces(~side)
    return tm


# ------------------------------------------------------------------ building blocks


def test_cut_of_a_closed_mesh_chains_into_one_loop_per_layer():
    tm = trimesh.creation.icosphere(3, radius=10)
    z = np.array([-5.0, 0.01, 7.3])
    layer, start, end, points = cut_segments(tm.vertices, tm.faces, z)
    order, chain, is_cycle = _chain_segments(start, end)
    assert is_cycle.all() and len(is_cycle) == 3
    # consecutive segments of a chain share their node: end of one is the start of the next
    same = chain[1:] == chain[:-1]
    assert np.array_equal(end[order[:-1]][same], start[order[1:]][same])
    # counter-clockwise (positive area) with the inside on the left
    for c in range(3):
        pts = points[start[order[chain == c]]]
        x, y = pts[:, 0], pts[:, 1]
        assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0


@settings(max_examples=40, deadline=None)
@given(st.lists(st.integers(3, 12), min_size=1, max_size=6), st.integers(0, 2**31 - 1))
def test_chaining_recovers_shuffled_cycles(sizes, seed):
    rng = np.random.default_rng(seed)
    starts, ends, base = [], [], 0
    for n in sizes:
        nodes = base + np.arange(n)
        starts.append(nodes)
        ends.append(np.roll(nodes, -1))
        base += n
    start, end = np.concatenate(starts), np.concatenate(ends)
    perm = rng.permutation(len(start))
    order, chain, is_cycle = _chain_segments(start[perm], end[perm])
    assert is_cycle.all() and len(is_cycle) == len(sizes)
    assert sorted(np.bincount(chain).tolist()) == sorted(sizes)
    s, e = start[perm][order], end[perm][order]
    same = chain[1:] == chain[:-1]
    assert np.array_equal(e[:-1][same], s[1:][same])


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 60), st.lists(st.integers(1, 60), max_size=8), st.integers(0, 2**31 - 1))
def test_chain_labels_are_connected_components(n, cuts, seed):
    """Chains and cycles of links labelled as scipy's connected_components labels them (the
    same numbering), by pointer jumping."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from deltaslice.slicing.sections import _chain_labels

    rng = np.random.default_rng(seed)
    perm = rng.permutation(n)
    nxt = np.full(n, -1)
    bounds = sorted({0, n, *[c for c in cuts if c < n]})
    for a, b in zip(bounds[:-1], bounds[1:]):
        group = perm[a:b]
        nxt[group[:-1]] = group[1:]
        if len(group) > 1 and rng.random() < 0.5:
            nxt[group[-1]] = group[0]  # a cycle
    linked = nxt >= 0
    graph = coo_matrix((np.ones(int(linked.sum())), (np.flatnonzero(linked), nxt[linked])), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    ours_count, ours = _chain_labels(nxt)
    assert ours_count == count and np.array_equal(ours, label)


def test_close_open_joins_pieces_and_reversed_pieces():
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    pieces = [square[:2], square[2:][::-1]]  # the second piece runs backwards
    loops, gaps, rev = _close_open(pieces)
    assert len(loops) == 1 and len(loops[0]) == 4
    assert gaps.sum() == pytest.approx(20.0)  # two 10 mm sides were missing
    assert rev == 1


# ------------------------------------------------------------------ open, flipped, non-manifold


def test_open_box_is_closed_layer_by_layer_with_the_gap_reported():
    tm = _open_box(20)
    z = np.arange(0.1, 20, 0.2)
    sections, report = open_sections(tm.vertices, tm.faces, z)
    assert [s.area() for s in sections] == pytest.approx([400.0] * len(z))
    assert report.layers == len(z) and report.gaps == len(z)
    assert report.gap_mm == pytest.approx(20.0 * len(z)) and report.max_gap_mm == pytest.approx(20.0)


def test_open_box_file_loads_slices_and_warns(tmp_path):
    tm = _open_box(20, subdivisions=2)
    m = load_mesh(meshes.write(tm, tmp_path / "open.stl"))
    assert not m.closed
    with pytest.warns(MeshWarning, match=r"closed \d+ gaps in \d+ of \d+ layers, [\d.]+ mm in total"):
        tp = slice_mesh(m, printer("delta_etitc").slicing, printer("delta_etitc").tool)
    assert tp.summary()["layers"] > 10 and tp.summary()["filament_mm"] > 0


def test_pipeline_echoes_the_closing_note(tmp_path):
    from deltaslice.pipeline import load_toolpath

    tm = _open_box(20, subdivisions=2)
    notes = []
    load_toolpath(meshes.write(tm, tmp_path / "open.stl"), printer("delta_etitc"), echo=notes.append)
    assert any(n.startswith("mesh: ") and "not a closed solid" in n for n in notes)
    assert any("closed" in n and "mm in total" in n for n in notes)


def test_flipped_faces_of_a_closed_box_are_rewound(tmp_path):
    tm = meshes.cube_trimesh(20)
    f = tm.faces.copy()
    f[[1, 4, 7]] = f[[1, 4, 7], ::-1]
    m = load_mesh(meshes.write(trimesh.Trimesh(tm.vertices, f, process=False), tmp_path / "flip.obj", "obj"))
    assert m.closed and m.volume == pytest.approx(8000)
    assert any("fixed the winding of 3 faces" in r for r in m.repairs)


def test_flipped_faces_sliced_even_odd_when_the_winding_is_not_trusted():
    tm = _open_box(20)
    f = tm.faces.copy()
    f[::3] = f[::3, ::-1]
    z = np.arange(0.1, 20, 0.2)
    sections, report = open_sections(tm.vertices, f, z, consistent=False)
    assert [s.area() for s in sections] == pytest.approx([400.0] * len(z))
    # the flipped faces split the chains where they meet: joined exactly, only the real gap counts
    assert report.gap_mm == pytest.approx(20.0 * len(z)) and report.reversed > 0


def test_non_manifold_pair_of_cubes_sliced(tmp_path):
    a = meshes.cube_trimesh(10)
    b = meshes.cube_trimesh(10)
    b.apply_translation((10, 10, 0))
    m = load_mesh(meshes.write(trimesh.util.concatenate([a, b]), tmp_path / "nm.stl"))
    mid, _ = _layers(m)
    sections = mesh_sections(m, mid)
    assert [s.area() for s in sections] == pytest.approx([200.0] * len(mid))


def test_zero_area_faces_of_a_watertight_mesh_are_kept(tmp_path):
    """A T-junction closed by a sliver (A, M, B) with M the midpoint of AB: dropping
    the sliver would open edges AM, MB and AB."""
    s = 20.0
    v = np.array(
        [[0, 0, 0], [s, 0, 0], [s, s, 0], [0, s, 0], [0, 0, s], [s, 0, s], [s, s, s], [0, s, s], [s / 2, 0, s]]
    )
    F, E, C0, D0, A, B, C, D, M = range(9)
    faces = [
        [F, D0, C0], [F, C0, E],  # bottom
        [A, B, C], [A, C, D],  # top
        [F, E, M], [E, B, M], [F, M, A],  # front, split at M
        [A, M, B],  # the zero-area sliver
        [E, C0, C], [E, C, B],  # +x
        [C0, D0, D], [C0, D, C],  # +y
        [D0, F, A], [D0, A, D],  # -x
    ]
    tm = trimesh.Trimesh(v, faces, process=False)
    trimesh.repair.fix_winding(tm)
    assert tm.is_watertight and (tm.area_faces == 0).sum() == 1
    m = load_mesh(meshes.write(tm, tmp_path / "sliver.obj", "obj"))
    assert m.closed and len(m.faces) == 14
    assert abs(m.volume) == pytest.approx(8000)
    assert not any("dropped" in r for r in m.repairs)


def test_duplicate_faces_dropped_only_when_safe():
    tm = meshes.cube_trimesh(10)
    f = np.vstack([tm.faces, tm.faces[:2]])
    m = mesh_from_arrays(tm.vertices, f)
    assert m.closed and len(m.faces) == 12 and any("duplicate" in r for r in m.repairs)


@settings(max_examples=12, deadline=None)
@given(st.sets(st.integers(0, 79), max_size=6), st.sets(st.integers(0, 79), max_size=20))
def test_holes_and_flips_never_crash(removed, flipped):
    """Any mix of missing and flipped faces: a MeshError or a sliced part, never a traceback."""
    tm = trimesh.creation.icosphere(1, radius=8)
    f = tm.faces.copy()
    idx = sorted(flipped)
    f[idx] = f[idx, ::-1]
    keep = ~np.isin(np.arange(len(f)), sorted(removed))
    try:
        m = mesh_from_arrays(tm.vertices, f[keep])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MeshWarning)
            slice_mesh(m, printer("delta_etitc").slicing, printer("delta_etitc").tool)
    except MeshError:
        pass


def test_volume_conserved_through_the_open_path():
    """A closed part forced through the layer-by-layer cut: area x height = volume."""
    tm = trimesh.creation.torus(12, 5, major_sections=64, minor_sections=32)
    closed = mesh_from_arrays(tm.vertices, tm.faces, name="torus")
    assert closed.closed
    forced = dataclasses.replace(closed, closed=False)
    mid, thick = _layers(forced, 0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", MeshWarning)  # a closed mesh leaves nothing to close
        sections = mesh_sections(forced, mid)
    area = sum(s.area() * h for s, h in zip(sections, thick))
    assert area == pytest.approx(closed.volume, rel=0.02)
    ref = [s.area() for s in mesh_sections(closed, mid)]
    assert [s.area() for s in sections] == pytest.approx(ref, rel=1e-6, abs=1e-6)


# ------------------------------------------------------------------ files: STL, 3MF


def test_binary_stl_with_trailing_bytes(tmp_path):
    path = meshes.write(meshes.cube_trimesh(20), tmp_path / "c.stl")
    path.write_bytes(path.read_bytes() + b"\x00garbage" * 5)
    m = load_mesh(path)
    assert m.closed and len(m.faces) == 12 and m.volume == pytest.approx(8000)
    assert any("ignored 40 bytes" in r for r in m.repairs)


def test_binary_stl_whose_header_starts_with_solid(tmp_path):
    path = meshes.write(meshes.cube_trimesh(20), tmp_path / "c.stl")
    data = bytearray(path.read_bytes())
    data[:10] = b"solid cube"
    path.write_bytes(bytes(data))
    assert load_mesh(path).volume == pytest.approx(8000)


_CT = """<?xml version="1.0" encoding="UTF-8"?>
<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">
<Default Extension="rels" ContentType="application/vnd.openxmlformats-package.relationships+xml"/>
<Default Extension="model" ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>
</Types>"""
_RELS = """<?xml version="1.0" encoding="UTF-8"?>
<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">
<Relationship Target="/3D/3dmodel.model" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>
</Relationships>"""


def _write_3mf(path: Path, objects, items, unit="millimeter"):
    """objects: {id: trimesh}; items: [(id, 3x4 transform as 12 numbers or None)]."""
    parts = [f'<?xml version="1.0" encoding="UTF-8"?>\n<model unit="{unit}" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02"><resources>']
    for oid, tm in objects.items():
        vs = "".join(f'<vertex x="{x!r}" y="{y!r}" z="{z!r}"/>' for x, y, z in tm.vertices.tolist())
        ts = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in tm.faces.tolist())
        parts.append(f'<object id="{oid}" type="model"><mesh><vertices>{vs}</vertices><triangles>{ts}</triangles></mesh></object>')
    parts.append("</resources><build>")
    for oid, t in items:
        attr = f' transform="{" ".join(map(str, t))}"' if t is not None else ""
        parts.append(f'<item objectid="{oid}"{attr}/>')
    parts.append("</build></model>")
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("[Content_Types].xml", _CT)
        z.writestr("_rels/.rels", _RELS)
        z.writestr("3D/3dmodel.model", "".join(parts))
    return path


def test_3mf_two_objects_with_transforms(tmp_path):
    box = trimesh.creation.box((10, 10, 10))
    cyl = trimesh.creation.cylinder(radius=5, height=10, sections=32)
    # box at (50, 0, 5); the cylinder turned 90 deg about x (lying along y) at (80, 0, 5)
    t_box = [1, 0, 0, 0, 1, 0, 0, 0, 1, 50, 0, 5]
    t_cyl = [1, 0, 0, 0, 0, 1, 0, -1, 0, 80, 0, 5]
    path = _write_3mf(tmp_path / "two.3mf", {1: box, 2: cyl}, [(1, t_box), (2, t_cyl)])
    m = load_mesh(path, keep_position=True)
    assert m.closed
    assert any("read 2 objects" in r and "2 placed by their build transforms" in r for r in m.repairs)
    assert np.allclose(m.bounds, [[45, -5, 0], [85, 5, 10]], atol=1e-6)
    assert m.volume == pytest.approx(1000 + np.pi * 25 * 10, rel=0.01)
    tp = slice_mesh(m, printer("delta_etitc").slicing, printer("delta_etitc").tool)
    assert tp.summary()["layers"] == 25


def test_3mf_written_by_trimesh_and_inch_units(tmp_path):
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box((1, 1, 1)), node_name="a", geom_name="left", transform=trimesh.transformations.translation_matrix((2, 0, 0.5)))
    scene.add_geometry(trimesh.creation.box((1, 1, 1)), node_name="b", geom_name="right", transform=trimesh.transformations.translation_matrix((-2, 0, 0.5)))
    path = tmp_path / "scene.3mf"
    path.write_bytes(trimesh.exchange.threemf.export_3MF(scene))
    m = load_mesh(path, keep_position=True)
    assert np.allclose(m.bounds, [[-2.5, -0.5, 0], [2.5, 0.5, 1]], atol=1e-9)
    assert any("read 2 objects (left, right), 2 placed by their build transforms" in r for r in m.repairs)
    inch = _write_3mf(tmp_path / "inch.3mf", {1: trimesh.creation.box((1, 1, 1))}, [(1, None)], unit="inch")
    m = load_mesh(inch)
    assert np.allclose(m.bounds[1] - m.bounds[0], 25.4)
    assert any("model unit inch" in r for r in m.repairs)


def test_tiny_part_gets_a_units_hint_and_placement_in_file_units(tmp_path):
    tm = trimesh.creation.box((1.5, 1.0, 0.5))
    tm.apply_translation((10, 0, 0))
    m = load_mesh(meshes.write(tm, tmp_path / "tiny.stl"))
    assert any("only 1.5 mm across: drawn in inches? try --scale 25.4" in r for r in m.repairs)
    assert "1.5 x 1 x 0.5 file units" in m.placement and "x-y centre (10, 0)" in m.placement
    m = load_mesh(meshes.write(tm, tmp_path / "tiny.stl"), scale=25.4)
    assert "scaled 25.4x to 38.1 x 25.4 x 12.7 mm" in m.placement
    assert not any("across" in r for r in m.repairs)


def test_a_successful_load_tells_where_the_part_went(tmp_path):
    """The placement line reaches the user on success too, not only in a refusal."""
    from deltaslice.pipeline import load_toolpath

    tm = trimesh.creation.box((0.8, 0.8, 0.4))
    tm.apply_translation((3, -2, 1))
    notes = []
    load_toolpath(meshes.write(tm, tmp_path / "inch.stl"), printer("delta_etitc"), scale=25.4, echo=notes.append)
    placed = [n for n in notes if n.startswith("mesh: placed:")]
    assert len(placed) == 1, notes
    assert "0.8 x 0.8 x 0.4 file units, x-y centre (3, -2), bottom z 0.8" in placed[0]
    assert "scaled 25.4x to 20.32 x 20.32 x 10.16 mm" in placed[0]


def test_error_for_a_part_too_big_names_its_placement(tmp_path):
    from deltaslice.errors import UnreachableError
    from deltaslice.mesh import check_fits

    m = load_mesh(meshes.write(trimesh.creation.box((2, 2, 2)), tmp_path / "c.stl"), scale=100)
    with pytest.raises(UnreachableError, match=r"2 x 2 x 2 file units.*scaled 100x"):
        check_fits(m, printer("delta_etitc"))


def test_ascii_stl_in_any_encoding_and_bad_numbers(tmp_path):
    text = trimesh.exchange.stl.export_stl_ascii(meshes.cube_trimesh(20)).replace("solid", "solid caf\xe9", 1)
    (tmp_path / "latin.stl").write_bytes(text.encode("latin-1"))
    assert load_mesh(tmp_path / "latin.stl").volume == pytest.approx(8000)
    lines = text.splitlines()
    k = next(i for i, line in enumerate(lines) if "vertex" in line and i > 10)
    lines[k] = "      vertex 1.0 2,5 3.0"
    (tmp_path / "bad.stl").write_text("\n".join(lines), encoding="latin-1")
    with pytest.raises(MeshError, match=rf"line {k + 1}: 'vertex 1.0 2,5 3.0': expected three numbers"):
        load_mesh(tmp_path / "bad.stl")


def test_triangle_soup_is_refused_naming_the_layer():
    """Disconnected triangles enclose nothing: closing would invent most of every outline."""
    rng = np.random.default_rng(3)
    v = rng.uniform(0, 20, (300, 3))
    m = mesh_from_arrays(v, np.arange(300).reshape(-1, 3))
    assert not m.closed
    mid, _ = _layers(m)
    with pytest.raises(MeshError, match=r"too broken to slice: at layer \d+ \(z = [\d.]+ mm\).*invent \d+ %"):
        mesh_sections(m, mid)


def test_obj_that_is_not_utf8(tmp_path):
    text = "# caf\xe9 (latin-1)\nv 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    (tmp_path / "latin.obj").write_bytes(text.encode("latin-1"))
    assert load_mesh(tmp_path / "latin.obj").volume == pytest.approx(1000 / 6)


# ------------------------------------------------------------------ the real parts


#: (file, scale, full): ``full`` slices with delta_etitc's own settings; the two big parts
#: (6 and 10 s at 0.4 mm layers) with 1 mm layers, so the default run stays short.
REAL = [
    ("frog_legs.obj", 1.0, True),
    ("teapot.stl", 1.0, True),
    ("seam_test_object.3mf", 1.0, False),
    ("bunny.ply", 500.0, True),
    ("cycloidal.ply", 25.4, False),
]


@pytest.mark.skipif(not PARTS.is_dir(), reason=f"{PARTS} absent (real parts are not shipped)")
@pytest.mark.parametrize("name,scale,full", REAL)
def test_real_parts_load_and_slice(name, scale, full):
    """The meshes PrusaSlicer slices and deltaslice refused: each loads, every layer
    has area, area x height is the mesh volume within a few %, and the part slices
    for delta_etitc through the pipeline."""
    from deltaslice.pipeline import load_toolpath

    etitc = printer("delta_etitc")
    m = load_mesh(PARTS / name, scale=scale)
    if name == "seam_test_object.3mf":
        assert m.closed and not any("dropped" in r for r in m.repairs)  # the 11 zero-area faces stay
    mid, thick = _layers(m, etitc.slicing.layer_height)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)
        sections = mesh_sections(m, mid)
    areas = np.array([s.area() for s in sections])
    assert (areas[:-1] > 0).all()
    assert float((areas * thick).sum()) == pytest.approx(abs(m.volume), rel=0.05)
    h = etitc.slicing.layer_height if full else 1.0
    used = etitc if full else dataclasses.replace(etitc, slicing=dataclasses.replace(etitc.slicing, layer_height=h, first_layer_height=h))
    tp = load_toolpath(PARTS / name, used, scale=scale)
    height = float(m.vertices[:, 2].max())
    assert tp.summary()["layers"] >= int(height / h) - 1 and tp.summary()["filament_mm"] > 0
