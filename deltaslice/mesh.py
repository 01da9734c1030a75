"""Mesh stage: load a part (STL here; OBJ, 3MF, PLY, OFF with trimesh), repair what is
safe to repair (with trimesh, only when the surface needs it), place it on the bed, and check
that it fits the printer.

The result is a frozen :class:`Mesh`: vertices (mm, bed frame) and faces, the
repairs made and whether the surface is a closed solid. Only repairs that cannot
open a surface are made; a mesh that stays open or non-manifold (or that
manifold3d refuses) is kept, marked ``closed=False``, and sliced layer by layer
(:mod:`deltaslice.slicing.sections`), as PrusaSlicer does. A file that cannot be
read raises :class:`~deltaslice.errors.MeshError` saying what is wrong and where.
"""

from __future__ import annotations

import math
import numbers
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import MeshError, UnreachableError

#: Largest part dimension accepted, mm (10 m: anything larger is a unit mistake).
MAX_EXTENT = 10_000.0
#: Smallest part dimension accepted, mm.
MIN_EXTENT = 1e-3
#: Largest hole (boundary loop, in edges) filled automatically.
MAX_HOLE_EDGES = 8


@dataclass(frozen=True)
class Mesh:
    """A triangle surface placed in the bed frame.

    vertices: (n, 3) float64, mm; faces: (m, 3) int64 indices, counter-clockwise
    seen from outside; repairs: what was repaired or found, one human-readable
    note each; path: the file it came from; closed: a watertight 2-manifold
    manifold3d accepts (else the slicer cuts it layer by layer);
    winding_consistent: the faces are oriented consistently (outward);
    placement: where the part was in its file and how it was moved.
    """

    vertices: np.ndarray
    faces: np.ndarray
    repairs: tuple[str, ...] = ()
    path: str = ""
    closed: bool = True
    winding_consistent: bool = True
    placement: str = ""
    _cache: dict = field(default_factory=dict, compare=False, repr=False, hash=False)

    def __post_init__(self):
        v = np.array(self.vertices, dtype=np.float64).reshape(-1, 3)
        f = np.array(self.faces, dtype=np.int64).reshape(-1, 3)
        v.setflags(write=False)
        f.setflags(write=False)
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        object.__setattr__(self, "repairs", tuple(self.repairs))

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3): min and max corner, mm."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @property
    def volume(self) -> float:
        """Enclosed volume, mm^3 (divergence theorem; only an estimate when the surface is not closed)."""
        t = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)

    def to_manifold(self):
        """The part as a ``manifold3d.Manifold`` (cached). Raises MeshError if refused or not closed."""
        if not self.closed:
            raise MeshError(f"{self.path}: not a closed solid: no manifold3d solid for it (it is sliced layer by layer)")
        if "manifold" not in self._cache:
            self._cache["manifold"] = _to_manifold(self.vertices, self.faces, self.path)
        return self._cache["manifold"]


def _manifold(vertices, faces):
    """manifold3d's solid for a surface and its status name ('NoError' when accepted)."""
    import manifold3d

    mesh = manifold3d.Mesh64(
        vert_properties=np.array(vertices, dtype=np.float64, order="C"),
        tri_verts=np.array(faces, dtype=np.uint64, order="C"),
    )
    man = manifold3d.Manifold(mesh)
    status = str(man.status()).split(".")[-1]
    if status == "NoError" and man.is_empty() and len(faces):
        status = "Empty"
    return man, status


def _to_manifold(vertices, faces, shown):
    man, status = _manifold(vertices, faces)
    if status != "NoError":
        raise MeshError(
            f"{shown}: the surface is not a closed 2-manifold ({status}): "
            "expected a watertight part without self-intersecting or non-manifold edges"
        )
    return man


# --------------------------------------------------------------------------- loading


def _where(points: np.ndarray) -> str:
    """A short 'near (x, y, z)' for a set of points, in the file's own coordinates and units."""
    c = np.asarray(points, float).reshape(-1, 3).mean(axis=0)
    return f"near ({c[0]:.4g}, {c[1]:.4g}, {c[2]:.4g}) in file coordinates"


def _read(path: Path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Vertices (n, 3) float in file units, faces (m, 3) int64 and reading notes."""
    shown = str(path)
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise MeshError(f"{shown}: no such file") from None
    except OSError as exc:
        raise MeshError(f"{shown}: cannot read: {exc}") from None
    if size == 0:
        raise MeshError(f"{shown}: empty file (0 bytes): expected a mesh")
    suffix = path.suffix.lower()
    notes: list[str] = []
    if suffix == ".stl":
        n = _binary_stl_count(path, size)
        if n is not None:
            return _read_binary_stl(path, n, size, notes)
        return _read_ascii_stl(path, notes)
    if suffix == ".obj":
        read = _read_obj(path, notes)
        if read is not None:
            return read
    if suffix == ".3mf":
        _check_unpacked_size(path, shown)
    import trimesh  # other formats only: STL and plain OBJ are read here, and importing trimesh takes 0.4-0.8 s

    try:
        loaded = trimesh.load(str(path), process=False)
    except MeshError:
        raise
    except Exception as exc:  # trimesh raises many types on bad input
        raise MeshError(f"{shown}: {_parse_failure(suffix, exc)}") from None
    try:
        if isinstance(loaded, trimesh.Scene):
            vertices, faces = _flatten_scene(loaded, shown, notes)
        elif hasattr(loaded, "faces") and loaded.vertices is not None:
            vertices = np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)
            faces = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
        else:
            raise MeshError(f"{shown}: no triangle mesh found in the file")
    except (TypeError, ValueError):  # what trimesh read is not triangles: a vertex of two numbers, a face left whole
        raise MeshError(f"{shown}: cannot read as {suffix or 'a mesh'}: its vertices are not x y z "
                        "triples or its faces not triangles") from None
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshError(f"{shown}: the mesh has no triangles")
    return vertices, faces, notes


# What a 3MF's parts may unpack to: about 5 million triangles of model XML. A 612 KB file of
# compressed spaces unpacked to 600 MB and its reading took 1.4 GB.
MAX_3MF_UNPACKED = 512 << 20


def _check_unpacked_size(path: Path, shown: str) -> None:
    """Refuse a 3MF (a zip archive) whose parts unpack to more than MAX_3MF_UNPACKED, from its
    directory, before anything is unpacked; a file that is no zip is left to the reader's words."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            unpacked = sum(max(0, info.file_size) for info in z.infolist())
    except (zipfile.BadZipFile, OSError, ValueError, EOFError):
        return
    if unpacked > MAX_3MF_UNPACKED:
        raise MeshError(f"{shown}: its parts unpack to {unpacked / 2**20:.0f} MiB, more than the "
                        f"{MAX_3MF_UNPACKED >> 20} MiB a 3MF of a printable part holds (a zip bomb?)")


_KINDS = {".3mf": "3MF", ".ply": "PLY", ".off": "OFF", ".obj": "OBJ", ".stl": "STL", ".glb": "glTF", ".gltf": "glTF"}


def _parse_failure(suffix: str, exc: Exception) -> str:
    """What trimesh's failure to read a file means, in a user's words (its exceptions are
    Python's own: StopIteration for a 3MF without a model, IndexError for a short PLY header)."""
    import zipfile

    kind = _KINDS.get(suffix, suffix.lstrip(".").upper() or "mesh")
    if suffix == ".3mf":
        if isinstance(exc, zipfile.BadZipFile):
            return "not a 3MF file: a 3MF is a zip archive, and this is not one (or a damaged one)"
        if isinstance(exc, (StopIteration, KeyError)):
            return "a 3MF without a 3D model in it (no 3D/3dmodel.model part with a mesh)"
        if isinstance(exc, SyntaxError) or type(exc).__name__ == "XMLSyntaxError":  # lxml's is a SyntaxError too
            return f"a 3MF whose model is not well-formed XML ({exc.msg if hasattr(exc, 'msg') else exc})"
    if suffix == ".ply" and "not a ply" in str(exc).lower():
        return "not a PLY file: a PLY starts with the line 'ply'"
    if isinstance(exc, (IndexError, KeyError, StopIteration, EOFError, ValueError, UnicodeDecodeError)):
        return f"not a readable {kind} file: its header or data is damaged, incomplete or of another format"
    return f"not a readable {kind} file ({exc or 'no detail'})"


#: OBJ statements that are not polygons (texture and normal vertices, names, groups, smoothing,
#: materials, polylines and points): read past.
_OBJ_PASSED = frozenset({"vt", "vn", "vp", "o", "g", "s", "usemtl", "mtllib", "l", "p", "mg"})
#: What follows the keyword of ``v`` and ``f`` lines may hold (ASCII only: Python's int and float
#: also take '1_0' and other scripts' digits; a form feed is no separator).
_OBJ_VERTEX_TEXT = re.compile(r"[0-9+\-.eEnaifNAIF \t\n]*", re.ASCII)
_OBJ_FACE_TEXT = re.compile(r"[0-9+\-/ \t\n]*", re.ASCII)


def _quote(line: str) -> str:
    """A file's line for a message: quoted, at most 60 characters of it."""
    line = line.strip()
    return repr(line if len(line) <= 60 else line[:57] + "...")


#: A line's first two characters -> 0: a vertex, 1: a face, 3: vt, vn or vp (if a separator follows),
#: 4: nothing; anything else (2) is told by its keyword.
_OBJ_HEADS = {"v ": 0, "v\t": 0, "v": 0, "f ": 1, "f\t": 1, "f": 1, "vt": 3, "vn": 3, "vp": 3, "": 4}


def _tokens_per_line(joined: str) -> np.ndarray:
    """How many space- or tab-separated tokens each line of ASCII ``joined`` has, (lines,) int."""
    b = np.frombuffer(joined.encode("ascii"), dtype=np.uint8)
    tok = (b != 32) & (b != 9) & (b != 10)
    start = tok.copy()
    start[1:] &= ~tok[:-1]
    newlines = np.flatnonzero(b == 10)
    return np.bincount(np.searchsorted(newlines, np.flatnonzero(start)), minlength=len(newlines) + 1)


def _read_obj(path: Path, notes: list[str]):
    """A Wavefront OBJ's polygons (``v`` and ``f``) fanned into triangles (0, i, i+1), as trimesh
    reads them, with the vertices its faces use (in file order); None for a file using what only
    trimesh reads (line continuations, free-form curves and surfaces, other statements): trimesh
    reads it then, or says why not.

    A face's vertex is the first number of each ``v/vt/vn`` group: a positive index counts from
    the file's first vertex (1), a negative one back from the last vertex read before the face
    (-1), as the format says. Faces are kept in file order; a face of fewer than three vertices is
    skipped (with a note); what is not a face (normals, texture coordinates, groups, materials,
    comments) is read past. Lines end at LF, CRLF or CR only. Errors name the line. The numbers
    are read all at once (the lines joined, then numpy's text parser): a line at a time took
    seconds for a few hundred thousand faces."""
    raw = path.read_bytes().decode("utf-8-sig", errors="replace").replace("\r\n", "\n").replace("\r", "\n")
    if "\\" in raw and re.search(r"\\[ \t]*(\n|$)", raw):  # a line continued on the next
        return None
    text = re.sub(r"#[^\n]*", "", raw) if "#" in raw else raw  # comments out, every line kept
    lines = text.split("\n")
    if text[:1] in (" ", "\t") or "\n " in text or "\n\t" in text:
        lines = [ln.lstrip(" \t") for ln in lines]
    kind = np.fromiter((_OBJ_HEADS.get(ln[:2], 2) for ln in lines), dtype=np.int8, count=len(lines))
    v_at, f_at = np.flatnonzero(kind == 0).tolist(), np.flatnonzero(kind == 1).tolist()
    # vt, vn and vp need a separator after them (vtx is no statement); any other line its keyword
    if not all(lines[i][2:3] in (" ", "\t", "") for i in np.flatnonzero(kind == 3).tolist()):
        return None
    if not {lines[i].split(None, 1)[0] for i in np.flatnonzero(kind == 2).tolist() if lines[i].strip()} <= _OBJ_PASSED:
        return None

    def fail(at, k: int | None, message: str):
        """MeshError at line at[k] (0-based), or without a line where none was found."""
        if k is None:
            raise MeshError(f"{path}: {message}")
        raise MeshError(f"{path}: line {at[k] + 1}: {_quote(raw.split(chr(10))[at[k]])}: {message}")

    def first(items, bad) -> int | None:
        return next((i for i, item in enumerate(items) if bad(item)), None)

    if not f_at:
        raise MeshError(f"{path}: no faces ('f' lines) in the OBJ file: expected a triangle mesh")
    v_rest = [lines[i][1:] for i in v_at]
    joined = "\n".join(v_rest)
    if not _OBJ_VERTEX_TEXT.fullmatch(joined):
        fail(v_at, first(v_rest, lambda r: not _OBJ_VERTEX_TEXT.fullmatch(r)), "expected numbers")
    counts = _tokens_per_line(joined) if v_rest else np.zeros(0, np.int64)
    if (counts < 3).any():
        fail(v_at, int(np.argmax(counts < 3)), "expected 'v x y z'")
    values = _numbers(joined, np.float64)
    if values is None or len(values) != counts.sum():
        fail(v_at, first(v_rest, lambda r: not _floats(r.split())), "expected numbers")
    vertices = values[(np.cumsum(counts) - counts)[:, None] + np.arange(3)].reshape(-1, 3)  # x y z of each

    f_rest = [lines[i][1:] for i in f_at]
    joined = "\n".join(f_rest)

    def malformed(r) -> bool:  # a character no vertex number has, or a group without its vertex
        return (not _OBJ_FACE_TEXT.fullmatch(r) or r.lstrip(" \t").startswith("/") or " /" in r or "\t/" in r
                or "\n/" in r)

    if malformed(joined):
        fail(f_at, first(f_rest, malformed), "expected vertex numbers (each v, v/vt, v//vn or v/vt/vn)")
    if "/" in joined:
        joined = re.sub(r"/[^ \t\n]*", "", joined)  # each group's vertex number
    counts = _tokens_per_line(joined)
    flat = _numbers(joined, np.int64)
    clamped = flat is not None and np.isin(flat, [_INT64.min, _INT64.max]).any()  # a number past int64
    if flat is None or len(flat) != counts.sum() or clamped:
        fail(f_at, first(f_rest, lambda r: not _vertex_numbers(r.split())),
             "expected vertex numbers (each v, v/vt, v//vn or v/vt/vn)")
    face = np.repeat(np.arange(len(counts)), counts)  # the face of each vertex number
    bad = flat == 0
    if bad.any():
        fail(f_at, int(face[np.argmax(bad)]), "vertex 0 (OBJ vertices count from 1)")
    before = np.searchsorted(np.asarray(v_at), np.asarray(f_at))  # the vertices read before each face
    flat = np.where(flat < 0, flat + before[face], flat - 1)
    bad = flat < 0
    if bad.any():
        k = int(face[np.argmax(bad)])
        fail(f_at, k, f"a vertex counted back before the first one ({int(before[k])} read so far)")
    bad = flat >= len(vertices)
    if bad.any():
        i = int(np.argmax(bad))
        fail(f_at, int(face[i]), f"vertex {int(flat[i]) + 1}: the file has {len(vertices)}")
    few = counts < 3
    if few.any():
        notes.append(f"skipped {int(few.sum())} face{'s' if few.sum() > 1 else ''} of fewer than three vertices "
                     f"(first: line {f_at[int(np.argmax(few))] + 1})")
        flat, counts = flat[~few[face]], counts[~few]
        if not len(counts):
            raise MeshError(f"{path}: no face of three or more vertices in the OBJ file: expected a triangle mesh")
    # the vertices the faces use, in file order (as trimesh keeps them)
    used = np.zeros(len(vertices), dtype=bool)
    used[flat] = True
    bad = used & ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        fail(v_at, int(np.argmax(bad)), "NaN or infinite coordinates")
    flat = (np.cumsum(used) - 1)[flat]
    # the fan of each face: its first vertex with each pair of consecutive others
    first_of = np.cumsum(counts) - counts
    tri = counts - 2
    of = np.repeat(np.arange(len(counts)), tri)
    step = np.arange(int(tri.sum())) - np.repeat(np.cumsum(tri) - tri, tri)
    faces = np.column_stack([flat[first_of[of]], flat[first_of[of] + step + 1], flat[first_of[of] + step + 2]])
    return vertices[used], faces, notes


_INT64 = np.iinfo(np.int64)


def _numbers(joined: str, dtype):
    """The whitespace-separated numbers of ``joined`` as one array, None where one is malformed
    (numpy's text parser: no list of strings, whose objects cost more memory than the file)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # "could not be read to its end"
        try:
            return np.fromstring(joined, dtype=dtype, sep=" ")
        except (ValueError, DeprecationWarning):
            return None


def _floats(tokens) -> bool:
    try:
        [float(t) for t in tokens]
    except ValueError:
        return False
    return True


def _vertex_numbers(tokens) -> bool:
    """Whether every v/vt/vn group starts with a vertex number that fits an int64."""
    try:
        return all(abs(int(t.split("/", 1)[0])) < 2**62 for t in tokens)
    except ValueError:
        return False


#: 3MF model units (the spec's list) in mm.
UNITS_MM = {"micron": 1e-3, "millimeter": 1.0, "centimeter": 10.0, "inch": 25.4, "foot": 304.8, "meter": 1000.0}


def _flatten_scene(scene, shown: str, notes: list[str]):
    """Every object instance of a scene (3MF build items) with its transform applied, in mm."""
    nodes = [n for n in scene.graph.nodes_geometry if len(getattr(scene.geometry[scene.graph[n][1]], "faces", ())) > 0]
    if not nodes:
        raise MeshError(f"{shown}: no triangle mesh found in the file")
    vs, fs, offset, names = [], [], 0, []
    for node in nodes:
        transform, name = scene.graph[node]
        geom = scene.geometry[name]
        v = np.asarray(geom.vertices, np.float64).reshape(-1, 3)
        v = v @ transform[:3, :3].T + transform[:3, 3]
        f = np.asarray(geom.faces, np.int64).reshape(-1, 3)
        if np.linalg.det(transform[:3, :3]) < 0:  # a mirroring transform turns the faces inside out
            f = f[:, ::-1]
        vs.append(v)
        fs.append(f + offset)
        offset += len(v)
        names.append(str(name))
    unit = str(scene.metadata.get("units") or "millimeter").lower().rstrip("s")
    factor = UNITS_MM.get(unit)
    if factor is None:
        raise MeshError(f"{shown}: model unit {unit!r}: expected one of {', '.join(UNITS_MM)}")
    moved = sum(not np.allclose(scene.graph[n][0], np.eye(4)) for n in nodes)
    if len(nodes) > 1 or moved:
        named = sorted({n for n in names if not n.isdigit()})  # 3MF object ids are numbers: not worth showing
        label = f" ({', '.join(named[:5])}{', ...' if len(named) > 5 else ''})" if named else ""
        notes.append(
            f"read {len(nodes)} object{'s' if len(nodes) > 1 else ''}{label}, {moved} placed by "
            f"{'their' if len(nodes) > 1 else 'its'} build transform{'s' if len(nodes) > 1 else ''}"
        )
    if factor != 1.0:
        notes.append(f"model unit {unit}: multiplied by {factor:g} to mm")
    return np.vstack(vs) * factor, np.vstack(fs)


def _binary_stl_count(path: Path, size: int) -> int | None:
    """The triangle count of a binary STL, None for ASCII; MeshError when truncated."""
    with open(path, "rb") as fh:
        head = fh.read(1024)
    if head[:5].lower() == b"solid":
        # A binary header may start with 'solid' too: an ASCII file says 'facet' early
        n = int.from_bytes(head[80:84], "little") if len(head) >= 84 else -1
        if b"facet" in head.lower() or b"endsolid" in head.lower() or n <= 0 or 84 + 50 * n > size:
            return None
        return n
    if size < 84:
        raise MeshError(f"{path}: truncated binary STL: {size} bytes, the 84-byte header alone is longer")
    n = int.from_bytes(head[80:84], "little")
    expected = 84 + 50 * n
    if n == 0:
        raise MeshError(f"{path}: binary STL with 0 triangles")
    if size < expected:
        got = (size - 84) // 50
        raise MeshError(
            f"{path}: truncated binary STL: header announces {n} triangles ({expected} bytes) "
            f"but the file has {size} bytes ({got} complete triangles)"
        )
    return n


_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def _read_binary_stl(path: Path, n: int, size: int, notes: list[str]):
    """The n triangles a binary STL header announces; bytes after them are ignored (as PrusaSlicer does)."""
    with open(path, "rb") as fh:
        fh.seek(84)
        data = np.frombuffer(fh.read(50 * n), dtype=_STL_RECORD, count=n)
    extra = size - 84 - 50 * n
    if extra:
        notes.append(f"ignored {extra} bytes after the {n} triangles the binary STL header announces")
    vertices = data["corners"].reshape(-1, 3).astype(np.float64)
    return vertices, np.arange(3 * n, dtype=np.int64).reshape(-1, 3), notes


_ASCII_VERTEX = re.compile(rb"\bvertex\s+(\S+)\s+(\S+)\s+(\S+)", re.IGNORECASE)
_ASCII_FACET = re.compile(rb"\bfacet\b", re.IGNORECASE)


def _read_ascii_stl(path: Path, notes: list[str]):
    """ASCII STL, any text encoding (only the numbers matter); every solid in the file."""
    data = path.read_bytes()
    found = _ASCII_VERTEX.findall(data)
    if not found:
        raise MeshError(f"{path}: ASCII STL without a single complete 'vertex x y z' line")
    try:
        vertices = np.array(found).astype(np.float64)
    except ValueError:
        for m in _ASCII_VERTEX.finditer(data):
            try:
                [float(x) for x in m.groups()]
            except ValueError:
                line = data.count(b"\n", 0, m.start()) + 1
                raise MeshError(f"{path}: line {line}: {m.group(0).decode('latin-1')!r}: expected three numbers") from None
        raise
    facets = len(_ASCII_FACET.findall(data))
    if len(vertices) % 3 or (facets and facets != len(vertices) // 3):
        raise MeshError(
            f"{path}: ASCII STL with {len(vertices)} vertices in {facets} facets: expected 3 vertices per facet"
        )
    return vertices, np.arange(len(vertices), dtype=np.int64).reshape(-1, 3), notes


def _edge_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges (k, 2) and how many faces use each (k,)."""
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    n = int(faces.max()) + 1 if len(faces) else 1
    keys, counts = np.unique(e[:, 0] * n + e[:, 1], return_counts=True)  # 1-D keys: far faster than axis=0
    return np.column_stack([keys // n, keys % n]), counts


def _first_of_each_face(faces: np.ndarray) -> np.ndarray:
    """Index of the first face of each distinct vertex set."""
    key = np.sort(faces, axis=1)
    n = int(faces.max()) + 1
    if n ** 3 < 2**62:
        return np.unique((key[:, 0] * n + key[:, 1]) * n + key[:, 2], return_index=True)[1]
    return np.unique(key, axis=0, return_index=True)[1]


@dataclass(frozen=True)
class _Repaired:
    vertices: np.ndarray
    faces: np.ndarray
    notes: list
    closed: bool
    consistent: bool


def _repair(vertices: np.ndarray, faces: np.ndarray, shown: str, stl: bool = False) -> _Repaired:
    """Repair what is safe, never opening a closed surface.

    Merges duplicate vertices, drops faces that repeat a vertex and duplicate
    faces (only when that leaves no more boundary edges than before), fills holes
    of at most MAX_HOLE_EDGES edges when that closes the surface, makes the
    winding consistent and outward. Faces of exactly zero area with three distinct
    vertices are kept: they are part of a watertight surface's topology.
    ``closed`` says whether the result is a watertight, 2-manifold, consistently
    wound surface (sliced by manifold3d); anything else is sliced layer by layer.
    """
    notes: list[str] = []
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshError(f"{shown}: the mesh has no triangles")
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if bad.any():
        raise MeshError(f"{shown}: {int(bad.sum())} vertices have NaN or infinite coordinates (first: vertex {int(np.flatnonzero(bad)[0])})")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"{shown}: faces refer to vertices that do not exist (index {int(faces.max())} of {len(vertices)})")
    referenced = np.zeros(len(vertices), dtype=bool)
    referenced[faces] = True
    used = vertices[referenced]
    extent = used.max(axis=0) - used.min(axis=0)
    if extent.max() > MAX_EXTENT or np.abs(used).max() > 100 * MAX_EXTENT:
        raise MeshError(
            f"{shown}: absurd size: {extent[0]:.4g} x {extent[1]:.4g} x {extent[2]:.4g} file units "
            f"(limit {MAX_EXTENT:g} mm): wrong units? use --scale"
        )
    if extent.max() < MIN_EXTENT:
        raise MeshError(f"{shown}: the part is degenerate: largest dimension {extent.max():.3g} file units")

    sound = _sound_surface(vertices, faces)
    if sound is not None:  # the usual part: nothing to repair, and no trimesh to import (0.4 s)
        v, f, merged = sound
        notes = [f"merged {merged} duplicate vertices"] if merged and not stl else []
        if _signed_volume(v, f) < 0:
            f = np.ascontiguousarray(np.fliplr(f))
            notes.append("turned the normals outward (the part was inside out)")
        return _Repaired(v, f, notes, True, True)

    import trimesh

    tm = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    nv = len(tm.vertices)
    tm.merge_vertices(merge_tex=True, merge_norm=True)
    if len(tm.vertices) < nv and not stl:  # STL stores every corner again: merging is routine there
        notes.append(f"merged {nv - len(tm.vertices)} duplicate vertices")
    f = np.asarray(tm.faces, np.int64)
    n_open_before = int((_edge_counts(f)[1] == 1).sum())
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    if repeated.all():
        raise MeshError(f"{shown}: every triangle is degenerate (repeats a vertex)")
    keep = ~repeated
    first = _first_of_each_face(f)
    unique = np.zeros(len(f), bool)
    unique[first] = True
    if not (unique | ~keep).all():
        # duplicates: dropping them must not open edges (two opposite copies form a closed membrane)
        trial = keep & unique
        if int((_edge_counts(f[trial])[1] == 1).sum()) <= n_open_before:
            keep = trial
    if not keep.all():
        notes.append(f"dropped {int((~keep).sum())} degenerate or duplicate faces")
        tm.update_faces(keep)
        tm.remove_unreferenced_vertices()

    edges, counts = _edge_counts(np.asarray(tm.faces, np.int64))
    nonman = edges[counts > 2]
    open_edges = edges[counts == 1]
    if len(open_edges) and not len(nonman):
        loops = _boundary_loops(open_edges)
        if max(len(lp) for lp in loops) <= MAX_HOLE_EDGES:
            trial = tm.copy()
            try:
                trimesh.repair.fill_holes(trial)
            except Exception:  # a failed repair leaves the part to the layer-by-layer slicer
                trial = None
            if trial is not None:
                f2 = np.asarray(trial.faces, np.int64)
                _, c2 = _edge_counts(f2)
                # a fill that backs a face with its own reverse makes a zero-volume membrane: not a repair
                membrane = len(_first_of_each_face(f2)) < len(f2)
                if not ((c2 == 1).any() or (c2 > 2).any() or membrane):
                    notes.append(f"filled {len(loops)} small hole{'s' if len(loops) > 1 else ''} with {len(trial.faces) - len(tm.faces)} triangles")
                    tm = trial
                    edges, counts = _edge_counts(np.asarray(tm.faces, np.int64))
                    open_edges = edges[counts == 1]

    wind_before = np.asarray(tm.faces).copy()
    try:
        trimesh.repair.fix_winding(tm)
    except Exception:  # non-manifold neighbourhoods can defeat it: the even-odd fill does not need it
        tm = trimesh.Trimesh(tm.vertices, wind_before, process=False, validate=False)
    if not np.array_equal(wind_before, tm.faces):
        notes.append(f"fixed the winding of {int(np.any(wind_before != tm.faces, axis=1).sum())} faces")
    consistent = bool(tm.is_winding_consistent)
    if consistent and _signed_volume(tm.vertices, tm.faces) < 0:
        tm.invert()
        notes.append("turned the normals outward (the part was inside out)")
    closed = consistent and not len(open_edges) and not len(nonman)
    if not closed:
        what = []
        if len(open_edges):
            loops = _boundary_loops(open_edges)
            big = max(loops, key=len)
            what.append(
                f"{len(loops)} hole{'s' if len(loops) > 1 else ''} ({len(open_edges)} boundary edges; the largest, "
                f"{len(big)} edges, {_where(tm.vertices[np.asarray(big).ravel()])})"
            )
        if len(nonman):
            what.append(f"{len(nonman)} non-manifold edges (first {_where(tm.vertices[nonman[0]])})")
        if not consistent:
            what.append("faces that cannot be oriented consistently")
        notes.append(f"not a closed solid: {'; '.join(what)}: sliced layer by layer, closing each layer's outlines")
    return _Repaired(np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64), notes, closed, consistent)


#: trimesh's vertex merge: positions equal to 10**-MERGE_DIGITS (its ``tol.merge``) are one vertex.
MERGE_DIGITS = 8


def _merge_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """trimesh's ``merge_vertices`` without trimesh: vertices (n, 3) float and faces (m, 3) int64
    -> the referenced vertices with distinct positions (rounded to MERGE_DIGITS), in the order of
    their first occurrence, and the faces re-indexed to them. The same arrays as trimesh's."""
    referenced = np.zeros(len(vertices), dtype=bool)
    referenced[faces] = True
    keys = np.round(vertices[referenced] * 10**MERGE_DIGITS).astype(np.int64)
    # equal rows grouped by a stable sort of the columns (np.unique(axis=0) sorts rows as bytes:
    # several times slower); each group's first row is its first occurrence
    by_key = np.lexsort(keys.T[::-1])
    k = keys[by_key]
    starts = np.ones(len(k), dtype=bool)
    starts[1:] = (k[1:] != k[:-1]).any(axis=1)
    group = np.empty(len(k), dtype=np.int64)
    group[by_key] = np.cumsum(starts) - 1
    first = by_key[starts]  # (groups,) in key order
    rank = np.empty(len(first), dtype=np.int64)  # each group's place by first occurrence
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    new_index = np.empty(len(vertices), dtype=np.int64)
    new_index[referenced] = rank[group]
    return vertices[np.flatnonzero(referenced)[np.sort(first)]], new_index[faces]


def _sound_surface(vertices: np.ndarray, faces: np.ndarray):
    """(vertices, faces, merged) when the merged surface needs no repair: every edge has exactly
    two faces and they run it in opposite directions (closed and consistently wound, so trimesh's
    fix_winding would change nothing); else None. Nothing else can need repair then: a face that
    repeats a vertex runs an edge both ways or shares a directed edge, and two faces on the same
    three vertices only meet each other, which the repair keeps too."""
    v, f = _merge_vertices(vertices, faces)
    directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    n = len(v)
    runs = np.sort(directed[:, 0] * n + directed[:, 1])  # a directed edge twice: sorted, side by side
    if not (_edge_counts(f)[1] == 2).all() or (runs[1:] == runs[:-1]).any():
        return None
    return v, f, len(vertices) - len(v)


def _signed_volume(vertices, faces) -> float:
    t = np.asarray(vertices)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)


def _boundary_loops(open_edges: np.ndarray) -> list[list[int]]:
    """Group boundary edges into connected loops (components of the edge graph)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    verts, inv = np.unique(open_edges.ravel(), return_inverse=True)
    inv = inv.reshape(-1, 2)
    n = len(verts)
    g = coo_matrix((np.ones(len(inv)), (inv[:, 0], inv[:, 1])), shape=(n, n))
    k, labels = connected_components(g, directed=False)
    edge_label = labels[inv[:, 0]]
    return [open_edges[edge_label == i].tolist() for i in range(k)]


def _finish(vertices, faces, notes, closed, consistent, shown, placement="") -> Mesh:
    """A Mesh, checked by manifold3d when closed; a surface it refuses goes to the layer-by-layer slicer."""
    mesh = Mesh(vertices, faces, tuple(notes), shown, closed=closed, winding_consistent=consistent, placement=placement)
    if closed:
        man, status = _manifold(mesh.vertices, mesh.faces)
        if status == "NoError":
            mesh._cache["manifold"] = man
        else:
            notes = list(notes) + [f"manifold3d refused the closed surface ({status}): sliced layer by layer"]
            mesh = Mesh(vertices, faces, tuple(notes), shown, closed=False, winding_consistent=consistent, placement=placement)
    return mesh


#: Below this size (mm, largest dimension) a part is probably drawn in other units.
TINY_EXTENT = 5.0


def _placement(lo_file, hi_file, scale, shift) -> str:
    """One line: the part's size in its own units, the scale, and the move onto the bed (mm)."""
    ext = hi_file - lo_file
    shift = np.asarray(shift, float) + 0.0  # no "-0" in the text
    size = " x ".join(f"{e:.4g}" for e in ext)
    mm = " x ".join(f"{e * scale:.4g}" for e in ext)
    text = (
        f"placed: {size} file units, x-y centre ({(lo_file[0] + hi_file[0]) / 2:.4g}, {(lo_file[1] + hi_file[1]) / 2:.4g}), "
        f"bottom z {lo_file[2]:.4g}"
    )
    text += f"; scaled {scale:g}x to {mm} mm" if scale != 1.0 else f" (read as {mm} mm)"
    text += f"; moved by ({shift[0]:.4g}, {shift[1]:.4g}, {shift[2]:.4g}) mm"
    return text


def _tiny_hint(extent_mm: float) -> str | None:
    """A units hint for a part whose largest dimension is ``extent_mm`` (None if plausible)."""
    if extent_mm >= TINY_EXTENT:
        return None
    hint = "drawn in inches? try --scale 25.4" if extent_mm * 25.4 >= TINY_EXTENT else "drawn in metres? try --scale 1000"
    return f"the part is only {extent_mm:.3g} mm across: {hint}"


def load_mesh(path, *, scale: float = 1.0, rotate_z: float = 0.0, keep_position: bool = False) -> Mesh:
    """Load, repair and place a part.

    path: .stl (ASCII or binary), .obj, .3mf (every object with its transform,
    the model's unit), .ply or .off, in mm unless the file says otherwise.
    scale: factor; rotate_z: degrees about z (counter-clockwise). The part is
    scaled, rotated, centred on the bed (x-y bounding-box centre at the origin)
    unless ``keep_position``, and always dropped onto the bed (min z = 0).
    ``Mesh.placement`` says where it was and what was done, in the file's units.
    Raises :class:`MeshError` on anything unreadable.
    """
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise MeshError(f"path: expected a mesh file path, got {path!r}")
    path = Path(path)
    shown = str(path)
    if not (isinstance(rotate_z, numbers.Real) and not isinstance(rotate_z, bool)):
        raise MeshError(f"{shown}: rotate = {rotate_z!r}: expected a finite angle in degrees")
    if not isinstance(keep_position, (bool, np.bool_)):
        raise MeshError(f"{shown}: keep_position = {keep_position!r}: expected True or False")
    if not (isinstance(scale, numbers.Real) and not isinstance(scale, bool) and math.isfinite(scale) and scale > 0):
        raise MeshError(f"{shown}: scale = {scale!r}: expected a finite number > 0")
    if not math.isfinite(rotate_z):
        raise MeshError(f"{shown}: rotate = {rotate_z!r}: expected a finite angle in degrees")
    vertices, faces, read_notes = _read(path)
    r = _repair(vertices, faces, shown, stl=path.suffix.lower() == ".stl")
    lo_file, hi_file = r.vertices.min(axis=0), r.vertices.max(axis=0)
    vertices = r.vertices * float(scale)
    if rotate_z:
        a = math.radians(rotate_z)
        c, s = math.cos(a), math.sin(a)
        vertices = vertices @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    if scale != 1.0 and (hi - lo).max() > MAX_EXTENT:
        raise MeshError(f"{shown}: absurd size after scaling by {scale:g}: {(hi - lo).max():.4g} mm")
    shift = np.array([0.0, 0.0, -lo[2]])
    if not keep_position:
        shift[:2] = -(lo[:2] + hi[:2]) / 2
    placement = _placement(lo_file, hi_file, float(scale), shift)
    hint = _tiny_hint(float((hi - lo).max()))
    notes = read_notes + r.notes + ([hint] if hint else [])
    return _finish(vertices + shift, r.faces, notes, r.closed, r.consistent, shown, placement)


def mesh_from_arrays(vertices, faces, *, name: str = "<mesh>", place: bool = True) -> Mesh:
    """A :class:`Mesh` from arrays (for libraries and tests): repaired like a file,
    and placed on the bed (centred, dropped to z = 0) when ``place``."""
    r = _repair(np.asarray(vertices, float).reshape(-1, 3), np.asarray(faces, np.int64).reshape(-1, 3), name)
    vertices = r.vertices
    if place:
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        vertices = vertices - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    return _finish(vertices, r.faces, r.notes, r.closed, r.consistent, name)


# --------------------------------------------------------------------------- fit


def check_fits(mesh: Mesh, printer) -> None:
    """Raise :class:`UnreachableError` unless the part's convex outline, extruded
    from z = 0 to its height, lies inside the printer's bed and reachable volume.

    The message says how many mm of radius (or height) are missing.
    """
    v = mesh.vertices
    height = float(v[:, 2].max())
    bed = printer.bed
    r_part = float(np.hypot(v[:, 0], v[:, 1]).max())
    if height > bed.max_height + 1e-9:
        raise UnreachableError(
            f"{mesh.path}: the part is {height:.2f} mm tall, {height - bed.max_height:.2f} mm more than "
            f"the printer's max height {bed.max_height:g} mm{_placed(mesh)}"
        )
    outline = _hull_xy(v[:, :2])
    kin = printer.kinematics()
    heights = np.unique(np.concatenate([np.linspace(0.0, height, 9), [height + printer.planning.travel_lift]]))
    heights = heights[heights <= max(bed.max_height, height)]

    def fits(s: float) -> bool:
        pts = outline * s
        ok_bed = bed.contains_xy(pts).all()
        p3 = np.column_stack([np.tile(pts, (len(heights), 1)), np.repeat(heights, len(pts))])
        return bool(ok_bed and kin.reachable(p3).all())

    if fits(1.0):
        return
    lo, hi = 0.0, 1.0
    if not fits(0.0):
        col = np.column_stack([np.zeros((len(heights), 2)), heights])
        bad = heights[~kin.reachable(col)]
        raise UnreachableError(
            f"{mesh.path}: the printer cannot reach the bed centre at z = {bad[0]:.2f} mm "
            f"(the part is {height:.2f} mm tall){_placed(mesh)}"
        )
    for _ in range(30):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    r_ok = lo * r_part
    raise UnreachableError(
        f"{mesh.path}: the part does not fit the printer's reachable volume: it reaches {r_part:.2f} mm from the bed "
        f"centre (up to z = {height:.2f} mm) but only {r_ok:.2f} mm are reachable in that shape: "
        f"{r_part - r_ok:.2f} mm of radius too large (scale it by {lo:.3f} or less, or move it){_placed(mesh)}"
    )


def _placed(mesh: Mesh) -> str:
    """'; placed: ...' for an error message, in the part's own units ('' if unknown)."""
    return f"; {mesh.placement}" if mesh.placement else ""


def _hull_xy(xy: np.ndarray) -> np.ndarray:
    """Convex hull of 2-D points, densified so no edge is longer than ~2 mm. GEOS's hull (shapely
    is loaded for slicing anyway; scipy.spatial would cost the compile's main process 0.15 s)."""
    import shapely

    outline = shapely.convex_hull(shapely.multipoints(xy))
    if isinstance(outline, shapely.Polygon) and not outline.is_empty:
        hull = shapely.get_coordinates(outline.exterior)[:-1]
    else:  # the points on one line (or one point): their extremes
        hull = xy[[np.argmin(xy[:, 0]), np.argmax(xy[:, 0]), np.argmin(xy[:, 1]), np.argmax(xy[:, 1])]]
    nxt = np.roll(hull, -1, axis=0)
    seg = np.linalg.norm(nxt - hull, axis=1)
    k = np.maximum(1, np.ceil(seg / 2.0)).astype(int)
    t = np.concatenate([np.arange(n) / n for n in k])
    i = np.repeat(np.arange(len(hull)), k)
    return hull[i] + (nxt[i] - hull[i]) * t[:, None]
