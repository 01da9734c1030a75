import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from deltaslice.errors import DeltasliceError, MeshError, UnreachableError
from deltaslice.mesh import check_fits, load_mesh
from deltaslice.machine import load_printer

from . import meshes


@pytest.fixture(scope="module")
def etitc():
    return load_printer("printers/delta_etitc.toml")


@pytest.mark.parametrize("kind", ["stl", "stl_ascii", "obj"])
def test_load_formats_and_placement(tmp_path, kind):
    tm = meshes.cube_trimesh(20)
    tm.apply_translation((30, -12, 7))
    suffix = "obj" if kind == "obj" else "stl"
    path = meshes.write(tm, tmp_path / f"c.{suffix}", file_type=kind)
    m = load_mesh(path)
    assert np.allclose(m.bounds, [[-10, -10, 0], [10, 10, 20]])
    assert m.volume == pytest.approx(8000)
    kept = load_mesh(path, keep_position=True)
    assert np.allclose(kept.bounds, [[20, -22, 0], [40, -2, 20]])


def test_scale_and_rotate(tmp_path):
    tm = trimesh.creation.box((40, 10, 5))
    path = meshes.write(tm, tmp_path / "bar.stl")
    m = load_mesh(path, scale=0.5, rotate_z=90)
    ext = m.bounds[1] - m.bounds[0]
    assert np.allclose(ext, [5, 20, 2.5], atol=1e-9)
    assert m.bounds[0, 2] == 0


def test_inside_out_and_small_hole_are_repaired(tmp_path):
    tm = meshes.cube_trimesh(20)
    tm.invert()
    m = load_mesh(meshes.write(tm, tmp_path / "inv.stl"))
    assert m.volume == pytest.approx(8000)
    assert any("outward" in r for r in m.repairs)
    tm = meshes.cube_trimesh(20)
    tm.update_faces(np.arange(len(tm.faces)) != 3)
    m = load_mesh(meshes.write(tm, tmp_path / "hole.stl"))
    assert m.volume == pytest.approx(8000)
    assert any("filled 1 small hole" in r for r in m.repairs)


def test_degenerate_faces_dropped(tmp_path):
    tm = meshes.cube_trimesh(10)
    v, f = tm.vertices, tm.faces
    f2 = np.vstack([f, [[0, 0, 1]]])
    text = "".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in f2)
    (tmp_path / "d.obj").write_text(text)
    m = load_mesh(tmp_path / "d.obj")
    assert len(m.faces) == 12
    assert any("degenerate" in r for r in m.repairs)


def test_empty_file(tmp_path):
    (tmp_path / "e.stl").write_bytes(b"")
    with pytest.raises(MeshError, match="empty"):
        load_mesh(tmp_path / "e.stl")


def test_truncated_binary_stl(tmp_path):
    path = meshes.write(meshes.cube_trimesh(), tmp_path / "c.stl")
    data = path.read_bytes()
    path.write_bytes(data[:300])
    with pytest.raises(MeshError, match="truncated binary STL.*12 triangles"):
        load_mesh(path)


def test_nan_vertices(tmp_path):
    tm = meshes.cube_trimesh()
    v = tm.vertices.copy()
    v[3, 1] = np.nan
    text = "".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in tm.faces)
    (tmp_path / "n.obj").write_text(text)
    with pytest.raises(MeshError, match="NaN"):
        load_mesh(tmp_path / "n.obj")


def test_absurd_size(tmp_path):
    path = meshes.write(trimesh.creation.box((1e6, 10, 10)), tmp_path / "big.stl")
    with pytest.raises(MeshError, match="absurd size"):
        load_mesh(path)


def test_open_mesh_kept_with_location(tmp_path):
    s = trimesh.creation.icosphere(3, radius=10)
    s.update_faces(np.arange(len(s.faces)) >= 60)
    m = load_mesh(meshes.write(s, tmp_path / "open.stl"))
    assert not m.closed and m.winding_consistent
    assert any(re.search(r"not a closed solid: \d+ holes? \(\d+ boundary edges.*near \(.*file coordinates", r) for r in m.repairs)
    with pytest.raises(MeshError, match="not a closed solid"):
        m.to_manifold()


def test_non_manifold_edges_kept(tmp_path):
    a = meshes.cube_trimesh(10)
    b = meshes.cube_trimesh(10)
    b.apply_translation((10, 10, 0))  # touches a along one edge
    both = trimesh.util.concatenate([a, b])
    m = load_mesh(meshes.write(both, tmp_path / "nm.stl"))
    assert not m.closed
    assert any("non-manifold edges" in r for r in m.repairs)


def test_garbage_and_missing(tmp_path):
    (tmp_path / "g.stl").write_text("solid x\n facet normal 0 0 1\n outer loop\n vertex 1 2\n")
    with pytest.raises(MeshError):
        load_mesh(tmp_path / "g.stl")
    with pytest.raises(MeshError, match="no such file"):
        load_mesh(tmp_path / "missing.stl")
    with pytest.raises(MeshError, match="scale"):
        load_mesh(tmp_path / "g.stl", scale=-1)


@pytest.mark.parametrize("seed", range(5))
def test_fit_outline_is_the_convex_hull(seed):
    """check_fits' outline: the corners of the convex hull (scipy's qhull, as before it was
    GEOS's), its sides cut to 2 mm at most; points on a line give their extremes."""
    from scipy.spatial import ConvexHull

    from deltaslice.mesh import _hull_xy

    xy = np.random.default_rng(seed).normal(size=(300, 2)) * 40
    outline = _hull_xy(xy)
    corners = {tuple(p) for p in xy[ConvexHull(xy).vertices]}
    assert corners <= {tuple(p) for p in outline}
    side = np.linalg.norm(np.diff(np.vstack([outline, outline[:1]]), axis=0), axis=1)
    assert side.max() <= 2.0 + 1e-9
    line = _hull_xy(np.c_[np.linspace(0, 10, 7), np.zeros(7)])
    assert line[:, 0].min() == 0.0 and line[:, 0].max() == 10.0 and not line[:, 1].any()


def test_check_fits(tmp_path, etitc):
    check_fits(meshes.box(40, 40, 40), etitc)
    with pytest.raises(UnreachableError, match=r"mm of radius too large"):
        check_fits(meshes.cylinder(radius=95, height=10), etitc)
    with pytest.raises(UnreachableError, match=r"30.00 mm more than"):
        check_fits(meshes.box(20, 20, 150), etitc)


def test_cli_reports_mesh_error_without_traceback(tmp_path):
    import subprocess
    import sys

    (tmp_path / "e.stl").write_bytes(b"")
    r = subprocess.run(
        [sys.executable, "-m", "deltaslice", "slice", str(tmp_path / "e.stl"), "--printer", "printers/delta_etitc.toml",
         "-o", str(tmp_path / "o.gcode")],
        capture_output=True, text=True,
    )
    assert r.returncode != 0
    assert "empty" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "o.gcode").exists()
    assert issubclass(MeshError, DeltasliceError)


def _repaired_by_trimesh(monkeypatch, vertices, faces, stl):
    """What _repair gives when the numpy path for a sound surface is switched off."""
    import deltaslice.mesh.repair as m

    with monkeypatch.context() as mp:
        mp.setattr(m, "_sound_surface", lambda *_: None)
        return m._repair(vertices, faces, "part", stl=stl)


def _sound_variants():
    """(name, vertices, faces): closed surfaces as files give them, inside out, with shuffled and
    unreferenced vertices, corners repeated as an STL stores them, and a tiny part (whose rounded
    positions fit trimesh's packed hash)."""
    rng = np.random.default_rng(3)
    for name, mesh in [("cylinder", meshes.cylinder(7.0, 5.0, 48)), ("hole", meshes.cube_with_hole()),
                       ("ring", meshes.ring()), ("tiny", meshes.box(0.004, 0.003, 0.002))]:
        v, f = np.array(mesh.vertices), np.array(mesh.faces)
        yield name, v, f
        yield name + " inside out", v, f[:, ::-1].copy()
        perm = rng.permutation(len(v))
        where = np.empty_like(perm)
        where[perm] = np.arange(len(perm))
        yield name + " shuffled, one vertex unused", np.vstack([v[perm], [[1.0, 2.0, 3.0]]]), where[f]
        yield name + " as STL corners", v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3)


@pytest.mark.parametrize("stl", [False, True])
def test_sound_surface_repaired_without_trimesh_as_trimesh_repairs_it(monkeypatch, stl):
    import deltaslice.mesh.repair as m

    for name, v, f in _sound_variants():
        assert m._sound_surface(v, f) is not None, name
        ours = m._repair(v, f, "part", stl=stl)
        theirs = _repaired_by_trimesh(monkeypatch, v, f, stl)
        assert np.array_equal(ours.vertices, theirs.vertices), name
        assert np.array_equal(ours.faces, theirs.faces), name
        assert (ours.notes, ours.closed, ours.consistent) == (theirs.notes, theirs.closed, theirs.consistent), name


def test_surfaces_needing_repair_are_not_taken_as_sound():
    import deltaslice.mesh.repair as m

    v, f = np.array(meshes.cube_trimesh(10).vertices), np.array(meshes.cube_trimesh(10).faces)
    flipped = f.copy()
    flipped[0] = flipped[0, ::-1]  # one face wound against its neighbours
    for name, faces in [("open", f[1:]), ("repeated vertex", np.vstack([f, [[0, 0, 1]]])),
                        ("duplicate face", np.vstack([f, f[:1]])), ("inconsistent winding", flipped)]:
        assert m._sound_surface(v, faces) is None, name


def test_a_sound_stl_loads_without_importing_trimesh(tmp_path):
    """Importing trimesh costs about 0.4 s of every compile: a closed STL needs none of it."""
    import subprocess
    import sys

    path = meshes.write(meshes.cube_with_hole(), tmp_path / "part.stl")
    code = ("import sys; from deltaslice.mesh import load_mesh; m = load_mesh(sys.argv[1]); "
            "print(m.closed, 'trimesh' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["True", "False"]


def test_arrays_without_triangles_are_a_mesh_error():
    from deltaslice.mesh import mesh_from_arrays

    for vertices in (np.zeros((0, 3)), np.eye(3)):
        with pytest.raises(MeshError, match="no triangles"):
            mesh_from_arrays(vertices, np.zeros((0, 3), dtype=np.int64))


# ---------------------------------------------------------------- OBJ read here, without trimesh

PARTS = Path(__file__).resolve().parents[2] / "shared" / "parts"


def _trimesh_arrays(path):
    """What the loader got from trimesh before OBJ was read here (trimesh.load, process=False)."""
    from deltaslice.mesh import _flatten_scene

    loaded = trimesh.load(str(path), process=False)
    if isinstance(loaded, trimesh.Scene):
        return _flatten_scene(loaded, str(path), [])[:2]
    return np.asarray(loaded.vertices, float), np.asarray(loaded.faces, np.int64)


def _triangles(v, f):
    """The triangles as a sorted list of corner triples, each rotated to start at its smallest
    corner (so a triangle is the same whichever corner a reader starts it at; orientation kept)."""
    out = []
    for tri in np.asarray(v)[np.asarray(f)].round(9).tolist():
        k = min(range(3), key=lambda i: tri[i])
        out.append(tuple(map(tuple, tri[k:] + tri[:k])))
    return sorted(out)


def _cube_quads(size: float):
    """A cube's corners (8, 3) (corner i at the bits of i as x, y, z) and its six faces as quads
    wound counter-clockwise seen from outside."""
    v = np.array([[(i >> 2) & 1, (i >> 1) & 1, i & 1] for i in range(8)], float) * size
    quads = []
    for axis in range(3):
        for side in (0, 1):
            ring = [i for i in range(8) if (v[i, axis] > 0) == side]
            c = v[ring].mean(axis=0)
            u, w = [k for k in range(3) if k != axis]
            ring.sort(key=lambda i: np.arctan2(v[i, w] - c[w], v[i, u] - c[u]))
            n = np.cross(v[ring[1]] - v[ring[0]], v[ring[2]] - v[ring[0]])
            if (n[axis] > 0) != side:
                ring.reverse()
            quads.append(ring)
    return v, quads


def test_obj_polygons_as_trimesh_reads_them(tmp_path):
    """Quads and pentagons fanned, v/vt/vn groups, negative indices, vertex colours, comments,
    groups, materials, CRLF line ends: the triangles trimesh reads, without importing it."""
    v, quads = _cube_quads(10.0)
    a, b = quads[2][:2]
    polys = []
    for ring in quads:  # the edge a-b split at vertex 8: both faces on it become pentagons, started there
        if a in ring and b in ring:
            k = [(ring[i], ring[(i + 1) % 4]) in ((a, b), (b, a)) for i in range(4)].index(True)
            ring = [8] + ring[k + 1 :] + ring[: k + 1]
        polys.append(ring)
    lines = ["# a cube of quads", "mtllib none.mtl", "o cube"]
    lines += [f"v {x} {y} {z} 0.5 0.5 0.5" for x, y, z in np.vstack([v, (v[a] + v[b]) / 2])]  # with a colour
    lines += ["vt 0 0", "vn 0 0 1", "g side", "usemtl red", "s off"]
    forms = ["{}/1/1", "{}//1", "{}", "{}/1"]
    for k, ring in enumerate(polys):
        if k == 1:  # counted back from the last vertex (-1 is vertex 8)
            lines.append("f " + " ".join(f"{i - 9}//1" for i in ring))
        else:
            lines.append("f " + " ".join(forms[k % 4].format(i + 1) for i in ring))
    path = tmp_path / "quads.obj"
    path.write_bytes("\r\n".join(lines).encode())
    code = ("import sys; from deltaslice.mesh import load_mesh; m = load_mesh(sys.argv[1]); "
            "print('trimesh' in sys.modules, round(m.volume, 6), m.closed)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "1000.0", "True"]
    from deltaslice.mesh import _read_obj

    mine = _read_obj(path, [])
    assert len(mine[1]) == 14  # 4 quads of 2 triangles and 2 pentagons of 3
    assert _triangles(*mine[:2]) == _triangles(*_trimesh_arrays(path))


TET = "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"  # a tetrahedron, outward


def test_obj_errors_name_the_line(tmp_path):
    """Every refusal names the line, quoted (cut short), and what was expected; order in the file
    does not matter; nothing but MeshError comes out (a bad-input campaign's cases)."""
    cases = [
        (TET + "f 1 2 x\n", r"line 9: 'f 1 2 x': expected vertex numbers"),
        (TET + "f 1 2 4 # c\nf 1 /2 3\n", r"line 10: 'f 1 /2 3': expected vertex numbers \(each v"),
        (TET + "f 0 1 2\n", r"line 9: .*vertex 0 \(OBJ vertices count from 1\)"),
        (TET + "f 1 3 2\nf 2 3 400\nf 2 3 9\n", r"line 10: 'f 2 3 400': vertex 400: the file has 4"),
        (TET + "f 1 2 99999999999999999999\n", r"line 9: .*expected vertex numbers"),
        ("v 0 0 0\nf -2 1 1\n" + TET, r"line 2: .*counted back before the first one \(1 read so far\)"),
        ("v 0 0 zero\n" + TET, r"line 1: 'v 0 0 zero': expected numbers"),
        ("v 0 0 1_0\n" + TET, r"line 1: 'v 0 0 1_0': expected numbers"),
        ("v 0 0 1e\n" + TET, r"line 1: 'v 0 0 1e': expected numbers"),
        ("v 0 0\n" + TET, r"line 1: 'v 0 0': expected 'v x y z'"),
        ("v 0 1\x0c.0 2\n" + TET, r"line 1: .*expected numbers"),  # a form feed is not a separator
        ("v 0 0 " + "1" * 5000 + "x\n" + TET, r"line 1: 'v 0 0 1{51}\.\.\.': expected numbers"),
        (TET.replace("v 0 0 10", "v 0 0 nan"), r"line 4: 'v 0 0 nan': NaN or infinite coordinates"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", r"no faces \('f' lines\)"),
        ("v 0 0 0\nv 1 0 0\nf 1 2\n", r"no face of three or more vertices"),
    ]
    for k, (text, message) in enumerate(cases):
        (tmp_path / f"bad{k}.obj").write_text(text)
        with pytest.raises(MeshError, match=message):
            load_mesh(tmp_path / f"bad{k}.obj")


def test_obj_edge_cases_that_load(tmp_path):
    """What a real exporter writes and still loads: a UTF-8 BOM, lone CR line ends, comments after
    the numbers, an unused vertex (no 'merged' note, and a NaN one is no error: trimesh kept only the
    vertices faces use), a face of two vertices (skipped, with a note), a comment hiding a line
    separator that str.splitlines would split at."""
    from deltaslice.mesh import _read_obj

    tet = TET.replace("\n", "\r").replace("f 1 3 2", "f 1 3 2 # first face")
    text = "# by X\u2028v 50 50 50\r" + tet + "v 5 5 5\rv nan 1 1\rf 1 2\r"
    (tmp_path / "a.obj").write_bytes(b"\xef\xbb\xbf" + text.encode())
    m = load_mesh(tmp_path / "a.obj")
    assert m.closed and m.volume == pytest.approx(1000 / 6)
    assert m.repairs == ("skipped 1 face of fewer than three vertices (first: line 12)",)
    vertices, faces, _ = _read_obj(tmp_path / "a.obj", [])
    assert len(vertices) == 4 and len(faces) == 4


def test_obj_with_other_statements_goes_to_trimesh(tmp_path):
    """A statement this reader does not know (a free-form curve) hands the file to trimesh."""
    from deltaslice.mesh import _read_obj

    tm = meshes.cube_trimesh(10)
    text = "".join(f"v {a} {b} {c}\n" for a, b, c in tm.vertices) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in tm.faces)
    (tmp_path / "curve.obj").write_text("cstype bspline\n" + text)
    assert _read_obj(tmp_path / "curve.obj", []) is None
    assert load_mesh(tmp_path / "curve.obj").volume == pytest.approx(1000)
    # what trimesh then reads wrong is refused, not a traceback
    (tmp_path / "short.obj").write_text(TET + "foo\nv 1 2\n")
    with pytest.raises(MeshError, match="vertices are not x y z triples"):
        load_mesh(tmp_path / "short.obj")
    (tmp_path / "scene.obj").write_text("usemtl a\n" + TET.replace("v 0 10 0", "v 0 10") + "v9n 0 0 1\nusemtl b\nf 1 2 3\n")
    with pytest.raises(MeshError, match="vertices are not x y z triples"):  # read by trimesh as a scene
        load_mesh(tmp_path / "scene.obj")


@pytest.mark.skipif(not PARTS.is_dir(), reason="../shared/parts is absent")
def test_obj_parts_read_as_trimesh_read_them():
    """Every OBJ of ../shared/parts: after the repair, the vertices and faces trimesh's reading gave,
    array for array; where the file has texture coordinates (trimesh splits a vertex per texture
    coordinate, which the merge joins again, in another order) the same triangles."""
    from deltaslice.mesh import _read_obj, _repair

    parts = sorted(PARTS.glob("*.obj"))
    assert parts
    for path in parts:
        mine = _read_obj(path, [])
        assert mine is not None, path.name
        a, b = _repair(mine[0], mine[1], path.name), _repair(*_trimesh_arrays(path), path.name)
        assert (a.closed, a.consistent) == (b.closed, b.consistent), path.name
        if "\nvt " in path.read_text(errors="replace"):
            assert _triangles(a.vertices, a.faces) == _triangles(b.vertices, b.faces), path.name
        else:
            np.testing.assert_array_equal(a.vertices, b.vertices, err_msg=path.name)
            np.testing.assert_array_equal(a.faces, b.faces, err_msg=path.name)


def test_obj_negative_indices_count_back_from_the_vertices_read_so_far(tmp_path):
    """-1 is the last vertex read before the face (the format's rule), not the file's last."""
    from deltaslice.mesh import _read_obj

    (tmp_path / "neg.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf -3 -2 -1\n")
    vertices, faces, _ = _read_obj(tmp_path / "neg.obj", [])
    np.testing.assert_array_equal(faces, [[0, 1, 2], [3, 4, 5]])
    assert vertices.shape == (6, 3)


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_vertex_merge_equals_trimesh(seed):
    """The merge the sound-surface path does without trimesh gives trimesh's merge_vertices arrays:
    repeated positions, positions equal once rounded to its 1e-8 (and some not), unreferenced
    vertices, faces repeating a vertex."""
    from deltaslice.mesh import _merge_vertices

    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 60))
    grid = rng.integers(-3, 4, size=(n, 3)) * 0.5
    v = grid[rng.integers(0, n, size=n)] + (rng.random((n, 1)) < 0.3) * rng.choice([0.0, 1e-10, 3e-9, 1e-7], size=(n, 1))
    f = rng.integers(0, n, size=(int(rng.integers(1, 40)), 3))
    tm = trimesh.Trimesh(v, f, process=False)
    tm.merge_vertices()
    mv, mf = _merge_vertices(v, f)
    np.testing.assert_array_equal(mv, tm.vertices)
    np.testing.assert_array_equal(mf, tm.faces)
