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
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import MeshError, UnreachableError
from ..tolerances import SAME_LENGTH
from .readers import UNITS_MM, _binary_stl_count, _flatten_scene, _read_ascii_stl, _read_binary_stl, _read_obj
from .repair import (MAX_EXTENT, MAX_HOLE_EDGES, MERGE_DIGITS, MIN_EXTENT, _manifold, _merge_vertices, _repair,
                     _to_manifold)

__all__ = ["MAX_EXTENT", "MAX_HOLE_EDGES", "MERGE_DIGITS", "MIN_EXTENT", "UNITS_MM", "Mesh", "check_fits", "load_mesh",
           "mesh_from_arrays", "_flatten_scene", "_merge_vertices", "_read_obj", "_repair"]


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


# --------------------------------------------------------------------------- loading



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
    import trimesh  # other formats only: STL and plain OBJ are read here, and trimesh's import is slow

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
    if height > bed.max_height + SAME_LENGTH:
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
    is loaded for slicing anyway; scipy.spatial would add its import to the compile's start)."""
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
