"""The small parts the golden trajectories pin, built in code (no slicer involved, so a slicer
change does not move them; the planner, kinematics and printer files do)."""

from __future__ import annotations

import numpy as np

from deltaslice.toolpath import Role, ToolpathBuilder

GOLDEN_RATE = 50.0  # Hz: the stored samples are decimated to keep the files a few kilobytes


def square_and_circle(z0: float, dz: float, size: float, laser: bool = False):
    """Two layers: a square perimeter and an inner circle, with retracts between."""
    b = ToolpathBuilder((0.0, 0.0, z0 + 1.0))
    th = np.linspace(0, 2 * np.pi, 37)
    for k in range(1 if laser else 2):
        z = z0 + k * dz
        b.new_layer(z)
        h = size / 2
        sq = np.array([[-h, -h], [h, -h], [h, h], [-h, h], [-h, -h]])
        seg = np.linalg.norm(np.diff(sq, axis=0), axis=1)
        b.add([[sq[0, 0], sq[0, 1], z]], 100.0, 0, 0, Role.TRAVEL)
        if not laser:
            b.add([[sq[0, 0], sq[0, 1], z]], 30.0, 0.5, 0, Role.RETRACT)
        b.add(np.c_[sq[1:], np.full(4, z)], 30.0, 0 if laser else seg * 0.02, 0.7 if laser else 1, Role.PERIMETER)
        if not laser:
            b.add([[sq[-1, 0], sq[-1, 1], z]], 30.0, -0.5, 0, Role.RETRACT)
        c = np.c_[h / 2 * np.cos(th), h / 2 * np.sin(th)]
        seg = np.linalg.norm(np.diff(c, axis=0), axis=1)
        b.add([[c[0, 0], c[0, 1], z]], 100.0, 0, 0, Role.TRAVEL)
        b.add(np.c_[c[1:], np.full(36, z)], 45.0, 0 if laser else seg * 0.02, 1.0, Role.INFILL)
    return b.build()


CASES = {
    "delta_etitc": lambda: square_and_circle(0.5, 0.4, 20.0),
    "delta_ucb": lambda: square_and_circle(0.25, 0.2, 20.0),
    "fivebar_atlas": lambda: square_and_circle(0.3, 0.3, 20.0),
    "delta_espe_laser": lambda: square_and_circle(0.0, 0.0, 20.0, laser=True),
}
