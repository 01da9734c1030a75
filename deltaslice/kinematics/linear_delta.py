"""Linear (Rostock/Kossel) delta: three carriages on vertical towers.

Tower i stands at ``D u_i`` (``u_i`` at ``i * 120 deg`` counter-clockwise from +x,
D the delta radius). The joint is the height of the carriage's rod joint above
the bed; each diagonal rod of length L closes
``(q_i - z - t)^2 + |xy - D u_i|^2 = L^2`` with the carriage above the effector.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import Section
from .base import Kinematics, lower_sphere_intersection, solve_rows

_ANGLES = np.radians([0.0, 120.0, 240.0])
TOWERS = np.stack([np.cos(_ANGLES), np.sin(_ANGLES)], axis=1)


FAMILY = "linear_delta"


@dataclass(frozen=True)
class LinearDeltaGeometry:
    """Rostock/Kossel delta: carriages on three vertical towers. mm.

    ``delta_radius`` is the horizontal distance from a carriage's rod joint to
    the effector's rod joint when the effector is centred (tower radius minus
    effector and carriage offsets). Tower i stands at ``i * 120 deg``
    counter-clockwise from +x. A joint value is the height of the carriage's rod
    joint above the bed; ``tool_offset`` is the tool tip below the effector joints.
    """

    delta_radius: float
    diagonal_rod: float
    tool_offset: float = 0.0


def read_geometry(sec: Section) -> LinearDeltaGeometry:
    """The ``[kinematics]`` keys of a linear delta, mm."""
    g = LinearDeltaGeometry(
        delta_radius=sec.getfloat("delta_radius", above=0),
        diagonal_rod=sec.getfloat("diagonal_rod", above=0),
        tool_offset=sec.getfloat("tool_offset", 0.0, minval=0),
    )
    if g.diagonal_rod <= g.delta_radius:
        sec.fail("diagonal_rod", g.diagonal_rod, f"a rod longer than delta_radius ({g.delta_radius:g} mm)")
    return g


class LinearDelta(Kinematics):
    geometry_class = LinearDeltaGeometry
    n_joints = 3
    joint_kinds = ("prismatic", "prismatic", "prismatic")

    def __init__(self, geometry, position_min, position_max, singularity_limit: float = 50.0):
        super().__init__(geometry, position_min, position_max, singularity_limit)
        self.towers = geometry.delta_radius * TOWERS  # (3, 2)
        self.L, self.t = geometry.diagonal_rod, geometry.tool_offset

    def inverse(self, points):
        """points: (N,3) mm -> q: (N,3) carriage heights, mm (NaN out of reach)."""
        points = np.atleast_2d(np.asarray(points, dtype=float))
        d2 = np.sum((points[:, None, :2] - self.towers[None]) ** 2, axis=2)
        h2 = self.L**2 - d2
        with np.errstate(invalid="ignore"):
            q = points[:, 2:3] + self.t + np.sqrt(h2)
        q[(h2 <= 0).any(axis=1) | ~np.all(np.isfinite(q), axis=1)] = np.nan
        return q

    def forward(self, q):
        """q: (N,3) mm -> points (N,3) mm: trilateration, effector below every carriage
        (NaN where the rods cannot meet or only meet with a carriage below the effector)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        c = np.concatenate([np.broadcast_to(self.towers[None], (len(q), 3, 2)), q[..., None]], axis=2)
        out, zz2 = lower_sphere_intersection(c, self.L)
        out[:, 2] -= self.t
        # The lower root can still leave a carriage below the effector joints when the carriage
        # heights differ much; no rod hangs upward in this machine (and inverse never returns it).
        with np.errstate(invalid="ignore"):
            below = np.all(q - out[:, 2:3] - self.t > 0, axis=1)
        out[~((zz2 > 0) & below)] = np.nan
        return out

    def inverse_jacobian(self, q):
        """q: (N,3) -> (N,3,3) d(q)/d(point): dq_i/dxy = -(xy - T_i)/h_i, dq_i/dz = 1."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        p = self.forward(q)
        h = q - p[:, 2:3] - self.t
        out = np.ones((len(q), 3, 3))
        with np.errstate(divide="ignore", invalid="ignore"):
            out[:, :, :2] = -(p[:, None, :2] - self.towers[None]) / h[..., None]
        return out

    def path_derivatives(self, points, q, t, kappa):
        """Closed form: q_i = z + t + h_i with h_i^2 = L^2 - |w_i|^2, w_i = xy - T_i, so
        h h' = -w.t and h'^2 + h h'' = -(|t_xy|^2 + w.kappa_xy)."""
        w = points[:, None, :2] - self.towers[None]  # (N, 3, 2)
        h = q - points[:, 2:3] - self.t
        with np.errstate(divide="ignore", invalid="ignore"):
            h1 = -np.einsum("njk,nk->nj", w, t[:, :2]) / h
            h2 = -(np.sum(t[:, :2] ** 2, axis=1)[:, None] + np.einsum("njk,nk->nj", w, kappa[:, :2]) + h1**2) / h
        return t[:, 2:3] + h1, kappa[:, 2:3] + h2

    def jacobian(self, q):
        """q: (N,3) -> (N,3,3) d(point)/d(q), dimensionless."""
        inv = self.inverse_jacobian(q)
        return solve_rows(inv, np.broadcast_to(np.eye(3), inv.shape))


KINEMATICS = LinearDelta
