"""Bridge direction and anchoring (issue 53): lines start and end on what holds them up."""

import numpy as np
import trimesh

from deltaslice.machine import load_printer
from deltaslice.slicing import slice_mesh
from deltaslice.toolpath import Role

from . import meshes
from .test_slicing_support import cantilever


def deck():
    """Two 5 x 10 x 5 mm towers at x 10..15 and -15..-10 under a 30 x 10 x 3 mm deck at z 5..8."""
    parts = []
    for size, at in (((5, 10, 5), (12.5, 0, 2.5)), ((5, 10, 5), (-12.5, 0, 2.5)), ((30, 10, 3), (0, 0, 6.5))):
        b = trimesh.creation.box(size)
        b.apply_translation(at)
        parts.append(b)
    return meshes._mesh(trimesh.boolean.union(parts, engine="manifold"), "deck")


def _bridge_lines(tp, li, min_length=2.0):
    """(starts, ends) (k, 2) of the layer's bridge moves longer than ``min_length`` (the lines,
    not the links between them)."""
    m = tp.working & (tp.layer == li) & (tp.role == Role.BRIDGE_INFILL)
    a, b = tp.starts[m, :2], tp.xyz[m, :2]
    long = np.hypot(*(b - a).T) > min_length
    return a[long], b[long]


def _first_layer_above(tp, z):
    return int(np.flatnonzero(tp.layer_z > z + 1e-6)[0])


def test_cantilever_bridge_lines_run_out_of_the_block_that_holds_them():
    p = load_printer("linear_kossel")
    tp = slice_mesh(cantilever(), p.slicing, p.tool)
    a, b = _bridge_lines(tp, _first_layer_above(tp, 10.0))
    assert len(a) > 10
    d = b - a
    # across the supported edge (x = -6), not along it
    assert np.all(np.abs(d[:, 0]) > 5 * np.abs(d[:, 1]))
    # each line starts on the post, a few mm in, and reaches out over the air
    inner = np.minimum(a[:, 0], b[:, 0])
    assert np.all(inner < -6.0 - 1.0) and np.all(np.maximum(a[:, 0], b[:, 0]) > 6.0)


def test_deck_bridge_lines_reach_into_both_towers():
    p = load_printer("linear_kossel")
    tp = slice_mesh(deck(), p.slicing, p.tool)
    a, b = _bridge_lines(tp, _first_layer_above(tp, 5.0))
    assert len(a) > 10
    d = b - a
    assert np.all(np.abs(d[:, 0]) > 5 * np.abs(d[:, 1]))  # tower to tower
    lo, hi = np.minimum(a[:, 0], b[:, 0]), np.maximum(a[:, 0], b[:, 0])
    # on the towers by 2 mm at least at both ends (the towers' tops are sparse infill: the bridge
    # is anchored there all the same)
    assert np.all(lo < -10.0 - 2.0) and np.all(hi > 10.0 + 2.0)
