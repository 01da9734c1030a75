"""Overhang perimeters (issue 53): every loop's segments over air, not only the external loop's."""

import numpy as np

from deltaslice.machine import load_printer
from deltaslice.slicing import slice_mesh
from deltaslice.toolpath import Role

from .test_slicing_support import cantilever

LOOPS = (Role.EXTERNAL_PERIMETER, Role.PERIMETER, Role.OVERHANG_PERIMETER)


def test_every_loop_over_air_is_an_overhang_perimeter():
    p = load_printer("linear_kossel")
    tp = slice_mesh(cantilever(), p.slicing, p.tool)
    w = p.slicing.perimeter_width
    first = int(np.flatnonzero(tp.layer_z > 10.0 + 1e-6)[0])  # the plate's first layer, over air beyond x = -6
    m = tp.working & (tp.layer == first) & np.isin(tp.role, [int(r) for r in LOOPS])
    mid = (tp.starts[m, :2] + tp.xyz[m, :2]) / 2
    role = tp.role[m]
    air = mid[:, 0] > -6.0 + w  # nothing under the bead's centre within half a width
    held = mid[:, 0] < -6.0 - w
    assert np.all(role[air] == Role.OVERHANG_PERIMETER)
    assert not np.any(role[held] == Role.OVERHANG_PERIMETER)
    # both loops of the two over air: about twice the external loop's length out there
    over = tp.lengths[m][role == Role.OVERHANG_PERIMETER].sum()
    assert over > 1.8 * (2 * 16.0 + 10.0 - 4 * w)
    # the layer above rests on the plate: no overhang
    assert not np.any(tp.working & (tp.layer == first + 1) & (tp.role == Role.OVERHANG_PERIMETER))
