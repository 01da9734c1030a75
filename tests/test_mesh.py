import re

import numpy as np
import pytest
import trimesh

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
    import deltaslice.mesh as m

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
    import deltaslice.mesh as m

    for name, v, f in _sound_variants():
        assert m._sound_surface(v, f) is not None, name
        ours = m._repair(v, f, "part", stl=stl)
        theirs = _repaired_by_trimesh(monkeypatch, v, f, stl)
        assert np.array_equal(ours.vertices, theirs.vertices), name
        assert np.array_equal(ours.faces, theirs.faces), name
        assert (ours.notes, ours.closed, ours.consistent) == (theirs.notes, theirs.closed, theirs.consistent), name


def test_surfaces_needing_repair_are_not_taken_as_sound():
    import deltaslice.mesh as m

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
