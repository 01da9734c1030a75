"""Linear (Rostock/Kossel) delta: three carriages on vertical towers.

Tower i stands at ``D u_i`` (``u_i`` at ``i * 120 deg`` counter-clockwise from +x,
D the delta radius). The joint is the height of the carriage's rod joint above
the bed; each diagonal rod of length L closes
``(q_i - z - t)^2 + |xy - D u_i|^2 = L^2`` with the carriage above the effector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import Section
from ..jit import njit
from .base import (GRAVITY, MM, Kinematics, check_out, closure_motion, lower_sphere_intersection, point_forces, rows3,
                   solve_rows)

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


@dataclass(frozen=True)
class LinearDeltaMasses:
    """The moving parts of a linear delta (the ``[dynamics]`` table), kg. ``carriage_mass``: one
    carriage with what rides on it; ``drive_mass``: the motor's rotor and pulley reflected to the
    carriage (rotor inertia / pulley radius^2) plus the belt; ``rod_mass``: both rods of one
    carriage, uniform between the ball-joint centres; ``effector_mass``: the effector with the tool
    (``tool_mass``) and the effector-side rod ends."""

    carriage_mass: float
    rod_mass: float
    effector_mass: float
    drive_mass: float = 0.0


def read_dynamics(sec: Section, geometry: LinearDeltaGeometry) -> LinearDeltaMasses:
    """The family's keys of the ``[dynamics]`` table, kg."""
    return LinearDeltaMasses(
        carriage_mass=sec.getfloat("carriage_mass", minval=0, maxval=100),
        rod_mass=sec.getfloat("rod_mass", minval=0, maxval=100),
        effector_mass=sec.getfloat("effector_mass", minval=0, maxval=1000) + sec.getfloat("tool_mass", 0.0, minval=0,
                                                                                           maxval=1000),
        drive_mass=sec.getfloat("drive_mass", 0.0, minval=0, maxval=100),
    )


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
        points = rows3(points, "points")
        q = np.empty((len(points), 3))
        _inverse_kernel(points, self.towers, self.L, self.t, q)
        return q

    def inverse_into(self, points, out):
        points = rows3(points, "points")
        check_out(out, len(points), 3)
        _inverse_kernel(points, self.towers, self.L, self.t, out)

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
        """Closed form (compiled): q_i = z + t + h_i with h_i^2 = L^2 - |w_i|^2, w_i = xy - T_i,
        so h h' = -w.t and h'^2 + h h'' = -(|t_xy|^2 + w.kappa_xy)."""
        q1 = np.empty((len(q), 3))
        q2 = np.empty((len(q), 3))
        _derivatives_kernel(*(np.ascontiguousarray(v, dtype=float) for v in (points, q, t, kappa)),
                            self.towers, self.t, q1, q2)
        return q1, q2

    def inverse_dynamics(self, masses: LinearDeltaMasses, q, qd, qdd):
        """Carriage forces (N, 3) N along the towers (up positive) that move the carriages along q
        (N,3) mm with velocities qd (mm/s) and accelerations qdd (mm/s^2) against gravity; NaN where
        the rods cannot close. Carriages and effector are point masses, each rod pair three (see
        :mod:`.base`); exact for that model, velocity terms included."""
        q, qd, qdd = (np.atleast_2d(np.asarray(v, dtype=float)) for v in (q, qd, qdd))
        m = masses
        p = self.forward(q)
        z = np.array([0.0, 0.0, 1.0])
        carriages = np.concatenate([np.broadcast_to(self.towers[None], (len(q), 3, 2)), q[..., None]], axis=2)
        d = (p + self.t * z)[:, None, :] - carriages  # rod vectors, effector joint minus carriage joint
        de = np.broadcast_to(z, d.shape)
        jac, acc = closure_motion(d, de, np.zeros_like(d), qd, qdd)
        acc_c = de * qdd[..., None]
        rod = m.rod_mass
        f_mid = point_forces(2 * rod / 3, 0.5 * (acc_c + acc[:, None, :]).reshape(-1, 3)).reshape(acc_c.shape)
        f_p = point_forces(m.effector_mass + 3 * rod / 6, acc) + 0.5 * f_mid.sum(axis=1)
        f_c = point_forces(m.carriage_mass + rod / 6, acc_c.reshape(-1, 3)).reshape(acc_c.shape) + 0.5 * f_mid
        # a carriage's Jacobian is z: only its vertical force loads its own joint
        return np.einsum("nkj,nk->nj", jac, f_p) + f_c[..., 2] + m.drive_mass * MM * qdd

    def torque_coefficients(self, masses: LinearDeltaMasses, points, q, dq, ddq):
        """``A sdd + B sd^2 + C`` of the carriage forces (N) along a path in one compiled pass, what
        :func:`.base.path_coefficients` gives from :meth:`inverse_dynamics` (its tested reference):
        points (N,3) mm, q = inverse(points) (N,3) mm, dq, ddq (N,3) per path unit -> (A, B, C)."""
        points, q, dq, ddq = (rows3(v, name) for v, name in ((points, "points"), (q, "q"), (dq, "dq"), (ddq, "ddq")))
        m = masses
        out = np.empty((3, len(q), 3))
        params = np.array([m.effector_mass, m.carriage_mass, m.rod_mass, m.drive_mass, GRAVITY])
        _torque_coefficients_kernel(points, q, dq, ddq, self.towers, self.t, params, out)
        return out[0], out[1], out[2]

    def jacobian(self, q):
        """q: (N,3) -> (N,3,3) d(point)/d(q), dimensionless."""
        inv = self.inverse_jacobian(q)
        return solve_rows(inv, np.broadcast_to(np.eye(3), inv.shape))


@njit
def _inverse_kernel(points, towers, L, t, q):
    """q (N,3) mm: q_i = z + t + sqrt(L^2 - |xy - T_i|^2); a row is NaN where any rod cannot
    reach (h^2 <= 0) or the point is not finite."""
    for k in range(points.shape[0]):
        ok = True
        for i in range(3):
            dx = points[k, 0] - towers[i, 0]
            dy = points[k, 1] - towers[i, 1]
            h2 = L * L - (dx * dx + dy * dy)
            v = points[k, 2] + t + math.sqrt(h2) if h2 > 0 else np.nan
            if not math.isfinite(v):
                ok = False
                break
            q[k, i] = v
        if not ok:
            q[k, 0] = np.nan
            q[k, 1] = np.nan
            q[k, 2] = np.nan


@njit
def _derivatives_kernel(points, q, t, kappa, towers, tool, q1, q2):
    """q' and q'' (N,3) along a curve with unit tangent t and curvature vector kappa (N,3):
    h = q - z - tool, h' = -w.t_xy / h, h'' = -(|t_xy|^2 + w.kappa_xy + h'^2) / h."""
    for k in range(points.shape[0]):
        txy2 = t[k, 0] * t[k, 0] + t[k, 1] * t[k, 1]
        for i in range(3):
            wx = points[k, 0] - towers[i, 0]
            wy = points[k, 1] - towers[i, 1]
            h = q[k, i] - points[k, 2] - tool
            h1 = -(wx * t[k, 0] + wy * t[k, 1]) / h
            h2 = -(txy2 + (wx * kappa[k, 0] + wy * kappa[k, 1]) + h1 * h1) / h
            q1[k, i] = t[k, 2] + h1
            q2[k, i] = kappa[k, 2] + h2


@njit(inline="always")  # inlined: a call no longer builds and counts views of its array arguments
def _carriage_forces(p, q, towers, tool, params, x, y, gravity, work, tau):
    """tau (3,) N of :meth:`LinearDelta.inverse_dynamics` at the tool point p (3,) mm and carriage
    heights q (3,) mm with velocities x (mm/s), accelerations y (mm/s^2); gravity 1.0 or 0.0. The
    rods d_i = effector joint - carriage i, the carriages' rate e' = z: D a = g y - |v - z x|^2 with
    g_i = d_i.z, v = D^-1 (g x). work: (7, 3) scratch."""
    d = work[0:3]
    inv = work[3:6]
    fz = work[6]
    for i in range(3):
        d[i, 0], d[i, 1], d[i, 2] = p[0] - towers[i, 0], p[1] - towers[i, 1], p[2] + tool - q[i]
    for k in range(3):
        a, b = (k + 1) % 3, (k + 2) % 3
        inv[0, k] = d[a, 1] * d[b, 2] - d[a, 2] * d[b, 1]
        inv[1, k] = d[a, 2] * d[b, 0] - d[a, 0] * d[b, 2]
        inv[2, k] = d[a, 0] * d[b, 1] - d[a, 1] * d[b, 0]
    det = d[0, 0] * inv[0, 0] + d[0, 1] * inv[1, 0] + d[0, 2] * inv[2, 0]
    v0 = (inv[0, 0] * d[0, 2] * x[0] + inv[0, 1] * d[1, 2] * x[1] + inv[0, 2] * d[2, 2] * x[2]) / det
    v1 = (inv[1, 0] * d[0, 2] * x[0] + inv[1, 1] * d[1, 2] * x[1] + inv[1, 2] * d[2, 2] * x[2]) / det
    v2 = (inv[2, 0] * d[0, 2] * x[0] + inv[2, 1] * d[1, 2] * x[1] + inv[2, 2] * d[2, 2] * x[2]) / det
    r0 = d[0, 2] * y[0] - (v0 * v0 + v1 * v1 + (v2 - x[0]) ** 2)
    r1 = d[1, 2] * y[1] - (v0 * v0 + v1 * v1 + (v2 - x[1]) ** 2)
    r2 = d[2, 2] * y[2] - (v0 * v0 + v1 * v1 + (v2 - x[2]) ** 2)
    a0 = (inv[0, 0] * r0 + inv[0, 1] * r1 + inv[0, 2] * r2) / det
    a1 = (inv[1, 0] * r0 + inv[1, 1] * r1 + inv[1, 2] * r2) / det
    a2 = (inv[2, 0] * r0 + inv[2, 1] * r1 + inv[2, 2] * r2) / det
    m_eff, m_c, rod, drive, grav = params[0], params[1], params[2], params[3], params[4]
    lift = grav * gravity
    # each rod's middle (2 rod / 3, at the mean of its ends' accelerations) loads the effector and its
    # carriage with half its force each; horizontally only the effector moves, so the effector's
    # horizontal load is its mass, the rods' ends (3 x rod / 6) and the middles' halves (3 x rod / 6)
    f0 = (m_eff + rod) * a0 * MM
    f1 = (m_eff + rod) * a1 * MM
    f2 = (m_eff + rod / 2) * (a2 * MM + lift)
    for i in range(3):
        fmid_z = (2 * rod / 3) * (0.5 * (y[i] + a2) * MM + lift)
        f2 += 0.5 * fmid_z
        fz[i] = (m_c + rod / 6) * (y[i] * MM + lift) + 0.5 * fmid_z
    for j in range(3):
        w = (inv[0, j] * f0 + inv[1, j] * f1 + inv[2, j] * f2) / det  # (D^-T f)_j
        tau[j] = d[j, 2] * w + fz[j] + drive * MM * y[j]


@njit
def _torque_coefficients_kernel(points, q, dq, ddq, towers, tool, params, out):
    """out[0], out[1], out[2] (N,3): A, B, C of :meth:`LinearDelta.torque_coefficients`."""
    zero = np.zeros(3)
    work = np.empty((7, 3))
    for n in range(q.shape[0]):
        _carriage_forces(points[n], q[n], towers, tool, params, zero, dq[n], 0.0, work, out[0, n])
        _carriage_forces(points[n], q[n], towers, tool, params, dq[n], ddq[n], 0.0, work, out[1, n])
        _carriage_forces(points[n], q[n], towers, tool, params, zero, zero, 1.0, work, out[2, n])


KINEMATICS = LinearDelta
