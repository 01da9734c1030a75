"""Meshes built by the tests themselves (trimesh.creation + manifold booleans)."""

from __future__ import annotations

import numpy as np
import trimesh

from deltaslice.mesh import Mesh, mesh_from_arrays


def _mesh(tm: trimesh.Trimesh, name: str) -> Mesh:
    return mesh_from_arrays(tm.vertices, tm.faces, name=name)


def box(x=20.0, y=20.0, z=20.0) -> Mesh:
    return _mesh(trimesh.creation.box((x, y, z)), f"box {x}x{y}x{z}")


def cylinder(radius=10.0, height=10.0, sections=64) -> Mesh:
    return _mesh(trimesh.creation.cylinder(radius=radius, height=height, sections=sections), "cylinder")


def cube_with_hole(size=20.0, hole_radius=4.0) -> Mesh:
    cube = trimesh.creation.box((size, size, size))
    hole = trimesh.creation.cylinder(radius=hole_radius, height=size * 2, sections=48)
    return _mesh(trimesh.boolean.difference([cube, hole], engine="manifold"), "cube with hole")


def step(size=20.0, low=8.0, high=16.0) -> Mesh:
    """An L (step) shape: a full square block up to ``low``, half of it up to ``high``:
    a top surface at mid-height."""
    a = trimesh.creation.box((size, size, low))
    a.apply_translation((0, 0, low / 2))
    b = trimesh.creation.box((size / 2, size, high))
    b.apply_translation((-size / 4, 0, high / 2))
    return _mesh(trimesh.boolean.union([a, b], engine="manifold"), "step")


def thin_wall(thickness=1.2, length=20.0, height=6.0) -> Mesh:
    return box(length, thickness, height)


def write(tm_or_mesh, path, file_type="stl"):
    if isinstance(tm_or_mesh, Mesh):
        tm = trimesh.Trimesh(tm_or_mesh.vertices, tm_or_mesh.faces, process=False)
    else:
        tm = tm_or_mesh
    tm.export(str(path), file_type=file_type)
    return path


def cube_trimesh(size=20.0) -> trimesh.Trimesh:
    return trimesh.creation.box((size, size, size))


def outward_volume(vertices, faces) -> float:
    t = np.asarray(vertices)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6)


def towers_with_deck(gap=20.0, tower=6.0, depth=6.0, height=4.0, deck=1.6) -> Mesh:
    """Two square towers ``gap`` mm apart (along x) joined at the top by a deck: the deck's
    first layer is a bridge across the gap, its outline over the gap an overhang."""
    parts = []
    for sx in (-1, 1):
        t = trimesh.creation.box((tower, depth, height))
        t.apply_translation((sx * (gap + tower) / 2, 0, height / 2))
        parts.append(t)
    d = trimesh.creation.box((gap + 2 * tower, depth, deck))
    d.apply_translation((0, 0, height + deck / 2))
    parts.append(d)
    return _mesh(trimesh.boolean.union(parts, engine="manifold"), "towers with deck")


def post_on_block(post=0.9, block=10.0, post_height=1.0, height=4.0) -> Mesh:
    """A block standing on a post ``post`` mm square: a bed contact of post**2 mm^2,
    thinner than the first-layer bead."""
    p = trimesh.creation.box((post, post, post_height))
    p.apply_translation((0, 0, post_height / 2))
    b = trimesh.creation.box((block, block, height - post_height))
    b.apply_translation((0, 0, post_height + (height - post_height) / 2))
    return _mesh(trimesh.boolean.union([p, b], engine="manifold"), "post on block")


def ring(outer=20.0, inner=16.0, height=4.0, sections=128) -> Mesh:
    """A flat annulus: a narrow band of infill all the way round."""
    a = trimesh.creation.cylinder(radius=outer, height=height, sections=sections)
    b = trimesh.creation.cylinder(radius=inner, height=height * 2, sections=sections)
    return _mesh(trimesh.boolean.difference([a, b], engine="manifold"), "ring")


def blind_hole(size=20.0, height=10.0, radius=4.0, depth=5.0) -> Mesh:
    """A block with a hole ``depth`` mm deep from its top: walls start mid-height."""
    a = trimesh.creation.box((size, size, height))
    a.apply_translation((0, 0, height / 2))
    b = trimesh.creation.cylinder(radius=radius, height=depth * 2, sections=64)
    b.apply_translation((0, 0, height))
    return _mesh(trimesh.boolean.difference([a, b], engine="manifold"), "blind hole")
