"""Mesh stage: load a part (STL, OBJ, 3MF, PLY, OFF) with trimesh, repair what is
safe to repair, place it on the bed, and check that it fits the printer.

The result is a frozen :class:`Mesh`: vertices (mm, bed frame) and faces of a
closed, consistently oriented triangle surface, plus the list of repairs made.
Anything that cannot be repaired safely (an open surface, non-manifold edges, a
surface manifold3d refuses) raises :class:`~deltaslice.errors.MeshError` saying
what is wrong and where.
"""

from __future__ import annotations

import math
import os
import numbers
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
    """A closed triangle surface placed in the bed frame.

    vertices: (n, 3) float64, mm; faces: (m, 3) int64 indices, counter-clockwise
    seen from outside; repairs: what was repaired, one human-readable note each;
    path: the file it came from.
    """

    vertices: np.ndarray
    faces: np.ndarray
    repairs: tuple[str, ...] = ()
    path: str = ""
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
        """Enclosed volume, mm^3 (divergence theorem)."""
        t = self.vertices[self.faces]
        return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)

    def to_manifold(self):
        """The part as a ``manifold3d.Manifold`` (cached). Raises MeshError if refused."""
        if "manifold" not in self._cache:
            self._cache["manifold"] = _to_manifold(self.vertices, self.faces, self.path)
        return self._cache["manifold"]


def _to_manifold(vertices, faces, shown):
    import manifold3d

    mesh = manifold3d.Mesh64(
        vert_properties=np.array(vertices, dtype=np.float64, order="C"),
        tri_verts=np.array(faces, dtype=np.uint64, order="C"),
    )
    man = manifold3d.Manifold(mesh)
    status = man.status()
    if str(status) != "Error.NoError" or (man.is_empty() and len(faces)):
        raise MeshError(
            f"{shown}: the surface is not a closed 2-manifold ({str(status).split('.')[-1]}): "
            "expected a watertight part without self-intersecting or non-manifold edges"
        )
    return man


# --------------------------------------------------------------------------- loading


def _where(points: np.ndarray) -> str:
    """A short 'near (x, y, z)' for a set of points."""
    c = np.asarray(points, float).reshape(-1, 3).mean(axis=0)
    return f"near ({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}) mm"


def _read_trimesh(path: Path):
    import trimesh

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
    if suffix == ".stl":
        _check_stl(path, size)
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except MeshError:
        raise
    except Exception as exc:  # trimesh raises many types on bad input
        raise MeshError(f"{shown}: cannot parse as {suffix or 'a mesh'}: {type(exc).__name__}: {exc}") from None
    if not hasattr(loaded, "faces") or loaded.vertices is None:
        raise MeshError(f"{shown}: no triangle mesh found in the file")
    vertices = np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0 or len(vertices) == 0:
        raise MeshError(f"{shown}: the mesh has no triangles")
    return vertices, faces


def _check_stl(path: Path, size: int) -> None:
    """Catch truncated binary STL before trimesh, with a precise message."""
    with open(path, "rb") as fh:
        head = fh.read(84)
    if head[:5].lower() == b"solid":
        # Could still be binary with a header starting 'solid': check the count.
        if len(head) == 84:
            n = int.from_bytes(head[80:84], "little")
            if 84 + 50 * n == size and n > 0:
                return
        return  # ASCII: trimesh reports its own errors
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


def _repair(
    vertices: np.ndarray, faces: np.ndarray, shown: str, stl: bool = False
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    import trimesh

    notes: list[str] = []
    bad = ~np.all(np.isfinite(vertices), axis=1)
    if bad.any():
        raise MeshError(f"{shown}: {int(bad.sum())} vertices have NaN or infinite coordinates (first: vertex {int(np.flatnonzero(bad)[0])})")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"{shown}: faces refer to vertices that do not exist (index {int(faces.max())} of {len(vertices)})")
    used = vertices[np.unique(faces)]
    extent = used.max(axis=0) - used.min(axis=0)
    if extent.max() > MAX_EXTENT or np.abs(used).max() > 100 * MAX_EXTENT:
        raise MeshError(
            f"{shown}: absurd size: {extent[0]:.4g} x {extent[1]:.4g} x {extent[2]:.4g} mm "
            f"(limit {MAX_EXTENT:g} mm): wrong units? use --scale"
        )
    if extent.max() < MIN_EXTENT:
        raise MeshError(f"{shown}: the part is degenerate: largest dimension {extent.max():.3g} mm")

    tm = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    nv = len(tm.vertices)
    tm.merge_vertices(merge_tex=True, merge_norm=True)
    if len(tm.vertices) < nv and not stl:  # STL stores every corner again: merging is routine there
        notes.append(f"merged {nv - len(tm.vertices)} duplicate vertices")
    nf = len(tm.faces)
    f = tm.faces
    degenerate = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    area = tm.area_faces
    scale = max(float(extent.max()), 1e-9)
    degenerate |= area <= (1e-12 * scale * scale)
    if degenerate.any():
        tm.update_faces(~degenerate)
    key = np.sort(tm.faces, axis=1)
    _, first = np.unique(key, axis=0, return_index=True)
    if len(first) < len(tm.faces):
        keep = np.zeros(len(tm.faces), bool)
        keep[first] = True
        tm.update_faces(keep)
    if len(tm.faces) < nf:
        notes.append(f"dropped {nf - len(tm.faces)} degenerate or duplicate faces")
    tm.remove_unreferenced_vertices()
    if len(tm.faces) == 0:
        raise MeshError(f"{shown}: every triangle is degenerate (zero area)")

    # Edge topology: non-manifold edges are not safe to repair.
    edges = np.sort(tm.edges, axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    nonman = uniq[counts > 2]
    if len(nonman):
        raise MeshError(
            f"{shown}: {len(nonman)} non-manifold edges (shared by more than two triangles), first "
            f"{_where(tm.vertices[nonman[0]])}: expected each edge to join exactly two triangles"
        )
    open_edges = uniq[counts == 1]
    if len(open_edges):
        n_open = len(open_edges)
        loops = _boundary_loops(open_edges)
        if loops and max(len(lp) for lp in loops) <= MAX_HOLE_EDGES:
            before = len(tm.faces)
            trimesh.repair.fill_holes(tm)
            e2 = np.sort(tm.edges, axis=1)
            _, c2 = np.unique(e2, axis=0, return_counts=True)
            if (c2 == 1).any() or (c2 > 2).any():
                raise MeshError(
                    f"{shown}: open surface: {len(loops)} holes ({n_open} boundary edges), first "
                    f"{_where(tm.vertices[open_edges[0]])}, could not be closed safely"
                )
            notes.append(f"filled {len(loops)} small holes with {len(tm.faces) - before} triangles")
        else:
            big = max(loops, key=len) if loops else open_edges[0]
            raise MeshError(
                f"{shown}: open surface: {n_open} boundary edges in {len(loops)} holes; the largest, "
                f"{len(big)} edges, {_where(tm.vertices[np.asarray(big).ravel()])} (file coordinates): expected a closed (watertight) "
                "part; close it in the CAD program"
            )

    # Orientation: consistent winding, then outward normals.
    wind_before = tm.faces.copy()
    trimesh.repair.fix_winding(tm)
    if not np.array_equal(wind_before, tm.faces):
        notes.append(f"fixed the winding of {int(np.any(wind_before != tm.faces, axis=1).sum())} faces")
    if not tm.is_winding_consistent:
        raise MeshError(f"{shown}: the surface cannot be oriented consistently (a Moebius-like or self-touching surface)")
    if tm.volume < 0:
        tm.invert()
        notes.append("turned the normals outward (the part was inside out)")
    return np.asarray(tm.vertices, float), np.asarray(tm.faces, np.int64), notes


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


def load_mesh(path, *, scale: float = 1.0, rotate_z: float = 0.0, keep_position: bool = False) -> Mesh:
    """Load, repair and place a part.

    path: .stl (ASCII or binary), .obj, .3mf, .ply or .off, mm. scale: factor;
    rotate_z: degrees about z (counter-clockwise). The part is scaled, rotated,
    centred on the bed (x-y bounding-box centre at the origin) unless
    ``keep_position``, and always dropped onto the bed (min z = 0).
    Raises :class:`MeshError` on anything unreadable or unrepairable.
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
    vertices, faces = _read_trimesh(path)
    vertices, faces, notes = _repair(vertices, faces, shown, stl=path.suffix.lower() == ".stl")
    vertices = vertices * float(scale)
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
    vertices = vertices + shift
    mesh = Mesh(vertices, faces, tuple(notes), shown)
    mesh.to_manifold()  # refuse now, with the file name, what slicing could not use
    return mesh


def mesh_from_arrays(vertices, faces, *, name: str = "<mesh>", place: bool = True) -> Mesh:
    """A :class:`Mesh` from arrays (for libraries and tests): repaired like a file,
    and placed on the bed (centred, dropped to z = 0) when ``place``."""
    vertices, faces, notes = _repair(np.asarray(vertices, float).reshape(-1, 3), np.asarray(faces, np.int64).reshape(-1, 3), name)
    if place:
        lo, hi = vertices.min(axis=0), vertices.max(axis=0)
        vertices = vertices - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    mesh = Mesh(vertices, faces, tuple(notes), name)
    mesh.to_manifold()
    return mesh


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
            f"the printer's max height {bed.max_height:g} mm"
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
            f"(the part is {height:.2f} mm tall)"
        )
    for _ in range(30):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if fits(mid) else (lo, mid)
    r_ok = lo * r_part
    raise UnreachableError(
        f"{mesh.path}: the part does not fit the printer's reachable volume: it reaches {r_part:.2f} mm from the bed "
        f"centre (up to z = {height:.2f} mm) but only {r_ok:.2f} mm are reachable in that shape: "
        f"{r_part - r_ok:.2f} mm of radius too large (scale it by {lo:.3f} or less, or move it)"
    )


def _hull_xy(xy: np.ndarray) -> np.ndarray:
    """Convex hull of 2-D points, densified so no edge is longer than ~2 mm."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = xy[ConvexHull(xy).vertices]
    except (QhullError, ValueError):
        hull = xy[[np.argmin(xy[:, 0]), np.argmax(xy[:, 0]), np.argmin(xy[:, 1]), np.argmax(xy[:, 1])]]
    nxt = np.roll(hull, -1, axis=0)
    seg = np.linalg.norm(nxt - hull, axis=1)
    k = np.maximum(1, np.ceil(seg / 2.0)).astype(int)
    t = np.concatenate([np.arange(n) / n for n in k])
    i = np.repeat(np.arange(len(hull)), k)
    return hull[i] + (nxt[i] - hull[i]) * t[:, None]
