"""Reading mesh files that need no trimesh: STL (binary and ASCII) and plain OBJ, and flattening
a scene trimesh read (3MF and the rest) into one triangle list in mm."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import MeshError



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
    found = _obj_statements(raw)
    if found is None:
        return None
    lines, v_at, f_at = found
    if not f_at:
        raise MeshError(f"{path}: no faces ('f' lines) in the OBJ file: expected a triangle mesh")

    def fail(at, k: int | None, message: str):
        """MeshError at line at[k] (0-based), or without a line where none was found."""
        if k is None:
            raise MeshError(f"{path}: {message}")
        raise MeshError(f"{path}: line {at[k] + 1}: {_quote(raw.split(chr(10))[at[k]])}: {message}")

    vertices = _obj_vertices([lines[i][1:] for i in v_at], v_at, fail)
    flat, counts = _obj_faces([lines[i][1:] for i in f_at], f_at, v_at, len(vertices), fail)
    few = counts < 3
    if few.any():
        notes.append(f"skipped {int(few.sum())} face{'s' if few.sum() > 1 else ''} of fewer than three vertices "
                     f"(first: line {f_at[int(np.argmax(few))] + 1})")
        flat, counts = flat[~few[np.repeat(np.arange(len(counts)), counts)]], counts[~few]
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


def _obj_statements(raw: str):
    """(lines without comments or leading blanks, the indices of ``v`` lines, of ``f`` lines) of an
    OBJ's text, or None when it holds what only trimesh reads (a continued line, another statement)."""
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
    return lines, v_at, f_at


def _first(items, bad) -> int | None:
    """The index of the first item that is ``bad``, or None."""
    return next((i for i, item in enumerate(items) if bad(item)), None)


def _obj_vertices(v_rest: list[str], v_at: list[int], fail) -> np.ndarray:
    """(n, 3) the x y z of the ``v`` lines (their text after the keyword); fail(at, k, message) raises."""
    joined = "\n".join(v_rest)
    if not _OBJ_VERTEX_TEXT.fullmatch(joined):
        fail(v_at, _first(v_rest, lambda r: not _OBJ_VERTEX_TEXT.fullmatch(r)), "expected numbers")
    counts = _tokens_per_line(joined) if v_rest else np.zeros(0, np.int64)
    if (counts < 3).any():
        fail(v_at, int(np.argmax(counts < 3)), "expected 'v x y z'")
    values = _numbers(joined, np.float64)
    if values is None or len(values) != counts.sum():
        fail(v_at, _first(v_rest, lambda r: not _floats(r.split())), "expected numbers")
    return values[(np.cumsum(counts) - counts)[:, None] + np.arange(3)].reshape(-1, 3)  # x y z of each


def _obj_malformed(r: str) -> bool:
    """A character no vertex number has, or a group without its vertex."""
    return (not _OBJ_FACE_TEXT.fullmatch(r) or r.lstrip(" \t").startswith("/") or " /" in r or "\t/" in r
            or "\n/" in r)


def _obj_faces(f_rest: list[str], f_at: list[int], v_at: list[int], n_vertices: int, fail):
    """(the 0-based vertex of every face's corners, flat; each face's corner count) of the ``f``
    lines (their text after the keyword), negative numbers counted back from the vertices before
    the face; fail(at, k, message) raises."""
    joined = "\n".join(f_rest)
    if _obj_malformed(joined):
        fail(f_at, _first(f_rest, _obj_malformed), "expected vertex numbers (each v, v/vt, v//vn or v/vt/vn)")
    if "/" in joined:
        joined = re.sub(r"/[^ \t\n]*", "", joined)  # each group's vertex number
    counts = _tokens_per_line(joined)
    flat = _numbers(joined, np.int64)
    clamped = flat is not None and np.isin(flat, [_INT64.min, _INT64.max]).any()  # a number past int64
    if flat is None or len(flat) != counts.sum() or clamped:
        fail(f_at, _first(f_rest, lambda r: not _vertex_numbers(r.split())),
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
    bad = flat >= n_vertices
    if bad.any():
        i = int(np.argmax(bad))
        fail(f_at, int(face[i]), f"vertex {int(flat[i]) + 1}: the file has {n_vertices}")
    return flat, counts


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
