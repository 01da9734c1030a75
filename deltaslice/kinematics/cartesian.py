"""Cartesian machine: each joint moves one bed axis (plus a constant offset)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import Section
from .base import Kinematics


FAMILY = "cartesian"


@dataclass(frozen=True)
class CartesianGeometry:
    """Three orthogonal axes; the joint value is the bed-frame coordinate plus ``offset``. mm."""

    offset_x: float = 0.0
    offset_y: float = 0.0
    offset_z: float = 0.0


def read_geometry(sec: Section) -> CartesianGeometry:
    """The ``[kinematics]`` keys of a Cartesian machine, mm."""
    return CartesianGeometry(
        offset_x=sec.getfloat("offset_x", 0.0),
        offset_y=sec.getfloat("offset_y", 0.0),
        offset_z=sec.getfloat("offset_z", 0.0),
    )


class Cartesian(Kinematics):
    geometry_class = CartesianGeometry
    n_joints = 3
    joint_kinds = ("prismatic", "prismatic", "prismatic")

    def __init__(self, geometry, position_min, position_max, singularity_limit: float = 50.0):
        super().__init__(geometry, position_min, position_max, singularity_limit)
        self.offset = np.array([geometry.offset_x, geometry.offset_y, geometry.offset_z])

    def inverse(self, points):
        """points: (N,3) mm -> q: (N,3) mm."""
        q = np.atleast_2d(np.asarray(points, dtype=float)) + self.offset
        q[~np.all(np.isfinite(q), axis=1)] = np.nan
        return q

    def forward(self, q):
        """q: (N,3) mm -> points: (N,3) mm."""
        p = np.atleast_2d(np.asarray(q, dtype=float)) - self.offset
        p[~np.all(np.isfinite(p), axis=1)] = np.nan
        return p

    def jacobian(self, q):
        return np.broadcast_to(np.eye(3), (len(np.atleast_2d(q)), 3, 3)).copy()

    def inverse_jacobian(self, q):
        return self.jacobian(q)

    def path_derivatives(self, points, q, t, kappa):
        """The joints follow the point: q' = t, q'' = kappa."""
        return np.array(t, dtype=float), np.array(kappa, dtype=float)


KINEMATICS = Cartesian
