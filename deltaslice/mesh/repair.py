"""Repairing a surface where it is safe (merging vertices, fixing winding, filling small holes),
and manifold3d's solid of a surface."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import MeshError

#: Largest part dimension accepted, mm (10 m: anything larger is a unit mistake).
MAX_EXTENT = 10_000.0
#: Smallest part dimension accepted, mm.
MIN_EXTENT = 1e-3
#: Largest hole (boundary loop, in edges) filled automatically.
MAX_HOLE_EDGES = 8


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


def _check_surface(vertices: np.ndarray, faces: np.ndarray, shown: str) -> None:
    """Refuse what no repair mends: no triangles, non-finite vertices, faces naming no vertex, an
    absurd or degenerate size (MeshError naming the file)."""
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
    _check_surface(vertices, faces, shown)
    sound = _sound_surface(vertices, faces)
    if sound is not None:  # the usual part: nothing to repair, and no trimesh to import
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
