"""Rotary (Clavel, 3-RSS) delta.

Motor i's shoulder axis is at ``S_i = R u_i + H z`` with ``u_i`` at ``i * 120 deg``
counter-clockwise from +x; the upper arm swings in the vertical plane through
``u_i`` and ``theta = 0`` is horizontal, positive downward, so the elbow is
``E_i = S_i + L1 (cos(theta) u_i - sin(theta) z)``. The platform stays parallel
to the base; its ball joints are at ``B_i = p + r u_i + t z`` for a tool tip p
(t: tool offset). Each forearm closes ``|E_i - B_i| = L2``.

Inverse: per arm, ``a cos(theta) + b sin(theta) = c`` with ``a = w.u``,
``b = -w.z``, ``c = (L1^2 + |w|^2 - L2^2) / (2 L1)`` and ``w = B_i - S_i``; the
knee-outward root is ``theta = atan2(b, a) - acos(c / hypot(a, b))``.
Forward: intersection of the three spheres of radius L2 around ``E_i - r u_i``,
the lower root. Jacobian: from differentiating the closure equations,
``A dp + diag(b) dtheta = 0``.
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
U = np.stack([np.cos(_ANGLES), np.sin(_ANGLES), np.zeros(3)], axis=1)  # (3 arms, 3) radial unit vectors
V = np.stack([-np.sin(_ANGLES), np.cos(_ANGLES), np.zeros(3)], axis=1)  # tangential unit vectors
Z = np.array([0.0, 0.0, 1.0])


FAMILY = "rotary_delta"


@dataclass(frozen=True)
class RotaryDeltaGeometry:
    """Clavel (3-RSS) delta. Lengths in mm, angles in rad.

    Motor i's shoulder axis sits at ``base_radius`` from the base centre at
    ``i * 120 deg`` counter-clockwise from +x, ``shoulder_height`` above the bed.
    ``tool_offset`` is the distance from the platform's ball-joint plane down to
    the tool tip; ``ball_joint_tilt_max`` limits the forearms' sideways tilt
    (None: no limit).
    """

    base_radius: float
    platform_radius: float
    upper_arm: float
    forearm: float
    shoulder_height: float
    tool_offset: float = 0.0
    ball_joint_tilt_max: float | None = None


def read_geometry(sec: Section) -> RotaryDeltaGeometry:
    """The ``[kinematics]`` keys of a rotary delta (lengths mm, tilt degrees in the file)."""
    tilt = sec.getfloat("ball_joint_tilt_max", required=False, above=0, maxval=90)
    g = RotaryDeltaGeometry(
        base_radius=sec.getfloat("base_radius", minval=0),
        platform_radius=sec.getfloat("platform_radius", minval=0),
        upper_arm=sec.getfloat("upper_arm", above=0),
        forearm=sec.getfloat("forearm", above=0),
        shoulder_height=sec.getfloat("shoulder_height", above=0),
        tool_offset=sec.getfloat("tool_offset", 0.0, minval=0),
        ball_joint_tilt_max=None if tilt is None else math.radians(tilt),
    )
    if g.forearm <= g.upper_arm * 0.5:
        sec.fail("forearm", g.forearm, f"a forearm longer than half the upper arm ({g.upper_arm / 2:g} mm)")
    return g


@dataclass(frozen=True)
class RotaryDeltaMasses:
    """The moving parts of a rotary delta, per arm (the ``[dynamics]`` table). kg, kg m^2, mm.

    ``upper_arm_inertia`` is about the shoulder axis, ``upper_arm_com`` the distance from that axis
    to the arm's centre of mass along the arm (shoulder to elbow). ``elbow_mass``: what moves with
    the elbow point (rod ends, nuts, axle). ``forearm_mass``: both rods of one parallelogram,
    taken as uniform rods between the ball-joint centres. ``platform_mass``: the platform with
    everything rigidly on it, the tool (``tool_mass``) and the platform-side rod ends included.
    ``rotor_inertia``: the motor and gear train reflected to the joint."""

    upper_arm_mass: float
    upper_arm_inertia: float
    upper_arm_com: float
    elbow_mass: float
    forearm_mass: float
    platform_mass: float
    rotor_inertia: float = 0.0


def read_dynamics(sec: Section, geometry: RotaryDeltaGeometry) -> RotaryDeltaMasses:
    """The family's keys of the ``[dynamics]`` table (masses kg, inertias kg m^2, lengths mm).
    An upper arm of unknown shape defaults to a uniform bar from the shoulder axis to the elbow."""
    L1 = geometry.upper_arm
    arm = sec.getfloat("upper_arm_mass", minval=0, maxval=100)
    return RotaryDeltaMasses(
        upper_arm_mass=arm,
        upper_arm_inertia=sec.getfloat("upper_arm_inertia", arm * (L1 * MM) ** 2 / 3, minval=0, maxval=100),
        upper_arm_com=sec.getfloat("upper_arm_com", L1 / 2, minval=0),
        elbow_mass=sec.getfloat("elbow_mass", 0.0, minval=0, maxval=100),
        forearm_mass=sec.getfloat("forearm_mass", minval=0, maxval=100),
        platform_mass=sec.getfloat("platform_mass", minval=0, maxval=1000) + sec.getfloat("tool_mass", 0.0, minval=0,
                                                                                             maxval=1000),
        rotor_inertia=sec.getfloat("rotor_inertia", 0.0, minval=0, maxval=100),
    )


class RotaryDelta(Kinematics):
    geometry_class = RotaryDeltaGeometry
    n_joints = 3
    joint_kinds = ("revolute", "revolute", "revolute")

    def __init__(self, geometry, position_min, position_max, singularity_limit: float = 50.0):
        super().__init__(geometry, position_min, position_max, singularity_limit)
        g = geometry
        self.R, self.r, self.L1, self.L2 = g.base_radius, g.platform_radius, g.upper_arm, g.forearm
        self.H, self.t = g.shoulder_height, g.tool_offset
        self.shoulders = self.R * U + self.H * Z  # (3, 3)
        # ball joint minus shoulder, less the tool point: w_i = point + _offsets[i], (3 arms, 3) mm
        self._offsets = np.ascontiguousarray(self.r * U + self.t * Z - self.shoulders)

    def _ball_minus_shoulder(self, points):
        """points (N,3) -> w (N, 3 arms, 3): ball joint relative to its shoulder."""
        return points[:, None, :] + (self.r * U + self.t * Z)[None] - self.shoulders[None]

    def elbows(self, q: np.ndarray) -> np.ndarray:
        """q (N,3) rad -> elbow centres (N, 3 arms, 3) mm."""
        q = np.atleast_2d(q)
        c, s = np.cos(q)[..., None], np.sin(q)[..., None]
        return self.shoulders[None] + self.L1 * (c * U[None] - s * Z)

    def inverse(self, points):
        """points: (N,3) float, mm, bed frame -> q: (N,3) float, rad (NaN where out of reach)."""
        points = rows3(points, "points")
        q = np.empty((len(points), 3))
        _inverse_kernel(points, self._offsets, self.L1, self.L2, q)
        return q

    def inverse_into(self, points, out):
        points = rows3(points, "points")
        check_out(out, len(points), 3)
        _inverse_kernel(points, self._offsets, self.L1, self.L2, out)

    def forward(self, q):
        """q: (N,3) float, rad -> points: (N,3) float, mm (NaN where the spheres do not meet)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        # Sphere centres: where the platform centre (plus tool offset) would be if arm i alone held it.
        c = self.elbows(q) - (self.r * U + self.t * Z)[None]
        out, h2 = lower_sphere_intersection(c, self.L2)
        out[~(h2 >= 0)] = np.nan
        return out

    def _closure(self, q, points):
        """Rows of A (N,3,3) and diagonal b (N,3) of A dp + diag(b) dq = 0."""
        e = self.elbows(q)
        ball = points[:, None, :] + (self.r * U + self.t * Z)[None]
        d = ball - e  # forearm vectors (N, arm, 3)
        return d, -np.einsum("nij,nij->ni", d, self._elbow_rates(q))

    def _elbow_rates(self, q):
        """d(elbow)/dq: (N, 3 arms, 3) mm/rad."""
        return self.L1 * (-np.sin(q)[..., None] * U[None] - np.cos(q)[..., None] * Z)

    def jacobian(self, q):
        """q: (N,3) rad -> (N,3,3) d(point)/d(q), mm/rad."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        a, b = self._closure(q, self.forward(q))
        return -solve_rows(a, b[:, :, None] * np.eye(3)[None])

    def inverse_jacobian(self, q):
        """q: (N,3) rad -> (N,3,3) d(q)/d(point), rad/mm; analytic, no matrix inverse."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        a, b = self._closure(q, self.forward(q))
        with np.errstate(divide="ignore", invalid="ignore"):
            return -a / b[:, :, None]

    def inverse_jacobian_at(self, points, q):
        """As :meth:`inverse_jacobian` when the points are already known (saves a forward solve)."""
        a, b = self._closure(np.atleast_2d(q), np.atleast_2d(points))
        with np.errstate(divide="ignore", invalid="ignore"):
            return -a / b[:, :, None]

    def path_derivatives(self, points, q, t, kappa):
        """Closed form (as :func:`.base.closure_derivatives`, compiled: the planner's hottest
        call): each forearm d_i = ball_i - elbow_i(q_i) keeps its length; the elbow turns on a
        circle of radius L1 about its shoulder."""
        q1 = np.empty((len(q), 3))
        q2 = np.empty((len(q), 3))
        _derivatives_kernel(*(np.ascontiguousarray(v, dtype=float) for v in (points, q, t, kappa)),
                            self._offsets, self.L1, q1, q2)
        return q1, q2

    def scaled_path_derivatives(self, points, t, kappa, scale, out1, out2) -> int:
        """The base contract in one compiled pass with the inverse (the planner's hottest call):
        no q array, and the scaling done as the rates are written (columns 0-2 of out1, out2)."""
        points, t, kappa = (np.ascontiguousarray(v, dtype=float) for v in (points, t, kappa))
        for out in (out1, out2):  # the kernel writes unchecked: numpy's out= would have refused these
            if out.ndim != 2 or out.shape[0] != len(points) or out.shape[1] < 3 or out.dtype != np.float64:
                raise ValueError(f"scaled_path_derivatives: an output is {out.dtype} {out.shape}, "
                                 f"expected float64 ({len(points)}, 3 or more)")
        return int(_scaled_rates_kernel(points, t, kappa, self._offsets, self.L1, self.L2, float(scale), out1, out2))

    def inverse_dynamics(self, masses: RotaryDeltaMasses, q, qd, qdd):
        """Joint torques (N, 3) N m that move the arms along q (N,3) rad with velocities qd
        (rad/s) and accelerations qdd (rad/s^2) against gravity; NaN where the mechanism cannot
        close or is singular. Exact for the rigid-body model of :class:`RotaryDeltaMasses`
        (:mod:`.base`'s notes): each upper arm turns about its shoulder axis (inertia and gravity
        of its centre of mass), the elbow and the platform are point masses, each forearm pair is
        three point masses (elbow end, middle, platform end); Coriolis and centripetal terms come
        in through the platform's and the elbows' accelerations."""
        q, qd, qdd = (np.atleast_2d(np.asarray(v, dtype=float)) for v in (q, qd, qdd))
        m = masses
        c, s = np.cos(q)[..., None], np.sin(q)[..., None]
        de = self.L1 * (-s * U[None] - c * Z)  # elbow rate d e_i / d q_i, (N, 3 arms, 3) mm/rad
        dde = self.L1 * (-c * U[None] + s * Z)
        d = self.forward(q)[:, None, :] + (self.r * U + self.t * Z)[None] - self.elbows(q)
        jac, acc = closure_motion(d, de, dde, qd, qdd)  # of the platform (the ball joints move with it)
        acc_e = de * qdd[..., None] + dde * (qd**2)[..., None]
        rod = m.forearm_mass
        # the middle of rod pair i is (e_i + p) / 2: half its force goes to each end's Jacobian
        f_mid = point_forces(2 * rod / 3, 0.5 * (acc_e + acc[:, None, :]).reshape(-1, 3)).reshape(acc_e.shape)
        f_p = point_forces(m.platform_mass + 3 * rod / 6, acc) + 0.5 * f_mid.sum(axis=1)
        f_e = point_forces(m.elbow_mass + rod / 6, acc_e.reshape(-1, 3)).reshape(acc_e.shape) + 0.5 * f_mid
        tau = MM * (np.einsum("nkj,nk->nj", jac, f_p) + np.einsum("njk,njk->nj", de, f_e))
        # upper arm about its fixed axis: its centre of mass is upper_arm_com (cos q u - sin q z) from it
        tau += (m.upper_arm_inertia + m.rotor_inertia) * qdd - m.upper_arm_mass * GRAVITY * m.upper_arm_com * MM * np.cos(q)
        return tau

    def torque_coefficients(self, masses: RotaryDeltaMasses, points, q, dq, ddq):
        """The joint torques along a path as ``A sdd + B sd^2 + C`` (N m) in one compiled pass, what
        :func:`.base.path_coefficients` gives from :meth:`inverse_dynamics` (the reference it is
        tested against) in about 1 % of its time (a planner's grid): points (N,3) mm on the path,
        q = inverse(points) (N,3) rad, dq = dq/ds, ddq = d2q/ds2 (N,3). Returns (A, B, C), each
        (N,3); NaN where the forearms' matrix is singular."""
        points, q, dq, ddq = (rows3(v, name) for v, name in ((points, "points"), (q, "q"), (dq, "dq"), (ddq, "ddq")))
        m = masses
        out = np.empty((3, len(q), 3))
        params = np.array([m.platform_mass, m.elbow_mass, m.forearm_mass, m.upper_arm_inertia + m.rotor_inertia,
                           m.upper_arm_mass * m.upper_arm_com * MM, GRAVITY])
        _torque_coefficients_kernel(points, q, dq, ddq, self._offsets, self.L1, params, out)
        return out[0], out[1], out[2]

    def ball_joint_tilt(self, points, q):
        """Sideways tilt of each forearm out of its arm's vertical plane: (N,3) rad."""
        d, _ = self._closure(q, points)
        return np.arcsin(np.clip(np.einsum("nij,ij->ni", d, V) / self.L2, -1, 1))

    def extra_ok(self, points, q):
        """points (N,3) mm, q (N,3) rad -> (N,) bool: every forearm's tilt within
        ``ball_joint_tilt_max``, :meth:`ball_joint_tilt`'s test (to rounding) in one compiled pass
        (in numpy, a reach check's second largest cost)."""
        tilt_max = self.geometry.ball_joint_tilt_max
        if tilt_max is None:
            return np.ones(len(points), dtype=bool)
        points, q = rows3(points, "points"), rows3(q, "q")
        if len(points) != len(q):
            raise ValueError(f"extra_ok: {len(points)} points for {len(q)} joint rows")
        out = np.empty(len(q), dtype=bool)
        _tilt_ok_kernel(points, q, self._offsets, self.L1, self.L2, float(tilt_max) + 1e-12, out)
        return out

    def condition_bound(self, q):
        """q (N,3) rad -> (N,): the base's bound, its inverse Jacobian (:meth:`inverse_jacobian`:
        the closure at q's forward solution) and cofactors in one compiled pass, the forward
        solution too (the same to rounding: the bound only decides with a margin; :meth:`forward`,
        whose points feed planned moves, stays numpy's)."""
        q = rows3(q, "q")
        out = np.empty(len(q))
        _condition_bound_kernel(q, self._offsets, self.L1, self.L2, out)
        return out


#: The centres' plane is vertical where its unit normal's z is below this (the two roots nearly level).
PLANE_VERTICAL_Z = 1e-9


@njit(inline="always")  # one caller: typed in it, no module of its own on a first run
def _lower_meeting(c, L2):
    """Where three spheres of radius L2 centred at the rows of c (3, 3) meet, the root below
    their plane, as :func:`.base.lower_sphere_intersection` (NaN where they do not meet). NaN too
    where the centres' plane is within PLANE_VERTICAL_Z of vertical: the two roots are then nearly level, and
    which one numpy's form takes is a matter of rounding (the caller's exact test decides)."""
    exx, exy, exz = c[1, 0] - c[0, 0], c[1, 1] - c[0, 1], c[1, 2] - c[0, 2]
    d = math.sqrt(exx * exx + exy * exy + exz * exz)
    exx, exy, exz = exx / d, exy / d, exz / d
    wx, wy, wz = c[2, 0] - c[0, 0], c[2, 1] - c[0, 1], c[2, 2] - c[0, 2]
    i = exx * wx + exy * wy + exz * wz
    eyx, eyy, eyz = wx - i * exx, wy - i * exy, wz - i * exz
    j = math.sqrt(eyx * eyx + eyy * eyy + eyz * eyz)
    eyx, eyy, eyz = eyx / j, eyy / j, eyz / j
    ezx, ezy, ezz = exy * eyz - exz * eyy, exz * eyx - exx * eyz, exx * eyy - exy * eyx
    if not abs(ezz) > PLANE_VERTICAL_Z:
        return np.nan, np.nan, np.nan
    if ezz > 0:
        ezx, ezy, ezz = -ezx, -ezy, -ezz
    x = d / 2
    y = (i * i + j * j) / (2 * j) - i * x / j
    h2 = L2 * L2 - x * x - y * y
    if not h2 >= 0:
        return np.nan, np.nan, np.nan
    h = math.sqrt(h2)
    return (c[0, 0] + x * exx + y * eyx + h * ezx, c[0, 1] + x * exy + y * eyy + h * ezy,
            c[0, 2] + x * exz + y * eyz + h * ezz)


@njit
def _condition_bound_kernel(q, offsets, L1, L2, out):
    """Kinematics.condition_bound at joints q (N,3): the forward solution p (the spheres of radius
    L2 about each elbow less the platform offset, :func:`_lower_meeting`; NaN, so the SVD decides,
    where its root is ambiguous), rows
    J^-1_i = -d_i / (-d_i . e'_i) (forearm d_i and elbow rate e'_i from :func:`_arm`), their
    cofactors, and |J^-1|_F |adj|_F / |det| (NaN where p is)."""
    ji = np.empty((3, 3))
    c = np.empty((3, 3))
    cs = np.empty((3, 2))
    for n in range(q.shape[0]):
        # elbow_i - (r U_i + t Z) = L1 (cos q U_i - sin q Z) - offsets_i
        for i in range(3):
            cs[i, 0], cs[i, 1] = math.cos(q[n, i]), math.sin(q[n, i])
            c[i, 0] = L1 * cs[i, 0] * U[i, 0] - offsets[i, 0]
            c[i, 1] = L1 * cs[i, 0] * U[i, 1] - offsets[i, 1]
            c[i, 2] = -L1 * cs[i, 1] - offsets[i, 2]
        px, py, pz = _lower_meeting(c, L2)
        for i in range(3):
            dx, dy, dz, ex, ey, ez = _arm(px + offsets[i, 0], py + offsets[i, 1], pz + offsets[i, 2],
                                          U[i, 0], U[i, 1], L1, cs[i, 0], cs[i, 1])
            b = -(dx * ex + dy * ey + dz * ez)
            ji[i, 0], ji[i, 1], ji[i, 2] = -dx / b, -dy / b, -dz / b
        f2 = 0.0
        a2 = 0.0
        det = 0.0
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3
            cx = ji[j, 1] * ji[k, 2] - ji[j, 2] * ji[k, 1]
            cy = ji[j, 2] * ji[k, 0] - ji[j, 0] * ji[k, 2]
            cz = ji[j, 0] * ji[k, 1] - ji[j, 1] * ji[k, 0]
            if i == 0:
                det = ji[0, 0] * cx + ji[0, 1] * cy + ji[0, 2] * cz
            f2 += ji[i, 0] * ji[i, 0] + ji[i, 1] * ji[i, 1] + ji[i, 2] * ji[i, 2]
            a2 += cx * cx + cy * cy + cz * cz
        out[n] = math.sqrt(f2 * a2) / abs(det)


# inlined into their callers (numba's own inlining): a call no longer makes and counts references to
# the scratch array's views (a large part of the torque coefficients' time); the same bits
@njit(inline="always")
def _arm_geometry(p, cq, sq, offsets, L1, work):
    """Into work (7, 3, 3) scratch: the forearms d_i (rows of D), the elbows' rates e'_i and e''_i,
    g_i = d_i.e'_i, h_i = d_i.e''_i and D^-1, at the tool point p (3,) mm with cos q, sin q (3,)."""
    d, e1, e2, inv = work[0], work[1], work[2], work[3]
    g, h = work[5, 0], work[5, 1]
    for i in range(3):
        dx, dy, dz, ex, ey, ez = _arm(p[0] + offsets[i, 0], p[1] + offsets[i, 1], p[2] + offsets[i, 2], U[i, 0], U[i, 1],
                                      L1, cq[i], sq[i])
        d[i, 0], d[i, 1], d[i, 2] = dx, dy, dz
        e1[i, 0], e1[i, 1], e1[i, 2] = ex, ey, ez
        e2[i, 0], e2[i, 1], e2[i, 2] = -L1 * cq[i] * U[i, 0], -L1 * cq[i] * U[i, 1], L1 * sq[i]
        g[i] = dx * ex + dy * ey + dz * ez
        h[i] = dx * e2[i, 0] + dy * e2[i, 1] + dz * e2[i, 2]
    # D^-1 = adj(D) / det(D): column k of inv is (row k+1 x row k+2) / det
    for k in range(3):
        a, b = (k + 1) % 3, (k + 2) % 3
        inv[0, k] = d[a, 1] * d[b, 2] - d[a, 2] * d[b, 1]
        inv[1, k] = d[a, 2] * d[b, 0] - d[a, 0] * d[b, 2]
        inv[2, k] = d[a, 0] * d[b, 1] - d[a, 1] * d[b, 0]
    det = d[0, 0] * inv[0, 0] + d[0, 1] * inv[1, 0] + d[0, 2] * inv[2, 0]
    for r in range(3):
        for c in range(3):
            inv[r, c] /= det


@njit(inline="always")
def _arm_torques(cq, params, x, y, gravity, moving, work, tau):
    """tau (3,) N m of :meth:`RotaryDelta.inverse_dynamics` with joint velocities x (rad/s) and
    accelerations y (rad/s^2) where :func:`_arm_geometry` filled work; gravity 1.0 or 0.0 (0: the
    torques' velocity and acceleration part alone). The platform's acceleration solves
    D a = g y + h x^2 - |v - e' x|^2, v = D^-1 (g x); its force goes to the joints through
    J^T = diag(g) D^-T. moving False: x is taken as zero and its terms, exact zeros where the
    geometry is finite (:func:`_finite_geometry`), are left out (the same bits, to a zero's sign)."""
    e1, e2, inv, fe = work[1], work[2], work[3], work[4]
    g, h, v, rhs, ap, fp = work[5, 0], work[5, 1], work[5, 2], work[6, 0], work[6, 1], work[6, 2]
    if moving:
        for r in range(3):
            v[r] = inv[r, 0] * g[0] * x[0] + inv[r, 1] * g[1] * x[1] + inv[r, 2] * g[2] * x[2]
        for i in range(3):
            rx, ry, rz = v[0] - e1[i, 0] * x[i], v[1] - e1[i, 1] * x[i], v[2] - e1[i, 2] * x[i]
            rhs[i] = g[i] * y[i] + h[i] * x[i] * x[i] - (rx * rx + ry * ry + rz * rz)
    else:
        for i in range(3):
            rhs[i] = g[i] * y[i]
    for r in range(3):
        ap[r] = inv[r, 0] * rhs[0] + inv[r, 1] * rhs[1] + inv[r, 2] * rhs[2]
    m_p, m_e, rod, inertia, arm_moment, grav = params[0], params[1], params[2], params[3], params[4], params[5]
    lift = grav * gravity
    for c in range(3):
        fp[c] = (m_p + rod / 2) * (ap[c] * MM + (lift if c == 2 else 0.0))
    for i in range(3):
        for c in range(3):
            ae = e1[i, c] * y[i] + e2[i, c] * x[i] * x[i] if moving else e1[i, c] * y[i]
            up = lift if c == 2 else 0.0
            fmid = (2 * rod / 3) * (0.5 * (ae + ap[c]) * MM + up)
            fp[c] += 0.5 * fmid
            fe[i, c] = (m_e + rod / 6) * (ae * MM + up) + 0.5 * fmid
    for j in range(3):
        w = inv[0, j] * fp[0] + inv[1, j] * fp[1] + inv[2, j] * fp[2]  # (D^-T fp)_j
        tau[j] = MM * (g[j] * w + e1[j, 0] * fe[j, 0] + e1[j, 1] * fe[j, 1] + e1[j, 2] * fe[j, 2]) + inertia * y[j] \
            - gravity * arm_moment * grav * cq[j]


@njit
def _torque_coefficients_kernel(points, q, dq, ddq, offsets, L1, params, out):
    """out[0], out[1], out[2] (N,3): A, B, C of :meth:`RotaryDelta.torque_coefficients`: C the
    static torques, A the torques of accelerations dq, B of velocities dq with accelerations ddq
    (no gravity in A and B: the torques are affine in the accelerations and quadratic in the
    velocities). The geometry once per point for the three."""
    cq, sq = np.empty(3), np.empty(3)
    xs, ys = np.zeros((3, 3)), np.zeros((3, 3))  # the velocities and accelerations of A, B, C: row 2 stays 0
    work = np.empty((7, 3, 3))
    for n in range(q.shape[0]):
        for i in range(3):
            cq[i], sq[i] = math.cos(q[n, i]), math.sin(q[n, i])
            ys[0, i], xs[1, i], ys[1, i] = dq[n, i], dq[n, i], ddq[n, i]
        _arm_geometry(points[n], cq, sq, offsets, L1, work)
        # one call site: numba inlines (and types) _arm_torques once, not three times. A and C at
        # rest: their velocity terms are exact zeros where the geometry is finite and are left out;
        # elsewhere the full form's 0 x inf makes all six NaN, as here
        for k in range(3):
            _arm_torques(cq, params, xs[k], ys[k], 1.0 if k == 2 else 0.0, k == 1, work, out[k, n])
        if not _finite_geometry(cq, work):
            for j in range(3):
                out[0, n, j] = np.nan
                out[2, n, j] = np.nan


@njit(inline="always")
def _finite_geometry(cq, work):
    """Whether cos q (3,) and what :func:`_arm_geometry` put in work (D^-1, g, h) are all finite
    (a value times zero is zero then, NaN otherwise). sin q enters D, so D^-1, alone."""
    z = 0.0
    for i in range(3):
        z += cq[i] * 0.0 + work[5, 0, i] * 0.0 + work[5, 1, i] * 0.0
        for k in range(3):
            z += work[3, i, k] * 0.0
    return z == 0.0


@njit
def _tilt_ok_kernel(points, q, offsets, L1, L2, limit, out):
    """Whether every forearm's sideways tilt asin(d_i . V_i / L2) (d_i from :func:`_arm` at the
    tool points ``points`` (N,3) and joints q (N,3)) is within ``limit`` rad (False where NaN)."""
    for n in range(q.shape[0]):
        ok = True
        for i in range(3):
            dx, dy, dz, _ex, _ey, _ez = _arm(points[n, 0] + offsets[i, 0], points[n, 1] + offsets[i, 1],
                                             points[n, 2] + offsets[i, 2], U[i, 0], U[i, 1], L1, math.cos(q[n, i]),
                                             math.sin(q[n, i]))
            x = (dx * V[i, 0] + dy * V[i, 1] + dz * V[i, 2]) / L2
            # a NaN x stays NaN through max(x, -1) and min(x, 1) (numba keeps the first argument
            # when a comparison fails) and fails the test
            ok = ok and abs(math.asin(min(max(x, -1.0), 1.0))) <= limit
        out[n] = ok


# The kernels below loop over points with the arms' unit vectors U_i = (cos, sin, 0): one pass,
# no (N, 3, 3) temporaries (the numpy forms took ~4 us a point; these ~0.1 us). The planner's
# (_scaled_rates_kernel) and the sampler's (_inverse_kernel) go a block of BLOCK points at a time,
# copied into rows of one coordinate each: the loop over a block's points for one arm then has no
# branch and only unit strides, and compiles to vector instructions (the same bits; on the shared
# AVX-512 machine the rates went from ~68 to ~36 ns a point; the inverse, its atan2 then numpy's
# over the whole array, from ~110 to ~46; with the atan2 in the loop too, 85 -> 31 ns on an AVX2
# machine, where numpy's atan2 is scalar).
BLOCK = 256


# atan2 as a rational function of one octant's tangent (Cephes' atan: degree 4 over 5 on
# |r| <= 0.66, (r - 1) / (r + 1) above) with selects for the octant, so the loops calling it
# vectorise: libm's atan2 is scalar (numpy's vector loop for it needs AVX-512), ~25 ns a value,
# the sampler's largest cost; this takes ~3 ns and is within 2 ulp of it (about one value in ten
# differs, by 1 ulp).
_AP = (-8.750608600031904122785e-1, -1.615753718733365076637e1, -7.500855792314704667340e1,
       -1.228866684490136173410e2, -6.485021904942025371773e1)
_AQ = (2.485846490142306297962e1, 1.650270098316988542046e2, 4.328810604912902668951e2,
       4.853903996359136964868e2, 1.945506571482613964425e2)
_PI_4, _PI_2 = 0.78539816339744830962, 1.57079632679489661923
_PI_2_LO = 6.123233995736765886130e-17  # pi / 2 - _PI_2


@njit(inline="always")
def atan2(y, x):
    """atan2(y, x) in [-pi, pi], rad, for scalar floats, as math.atan2 (signed zeros, infinities
    and NaN included) within 2 ulp, branch-free."""
    ax, ay = abs(x), abs(y)
    lo, hi = min(ax, ay), max(ax, ay)
    big = (lo >= 0.66 * hi) & (lo > 0.0)  # reduce by pi / 4: r = tan(angle - pi / 4)
    num = (lo - hi if lo != hi else 0.0) if big else lo  # inf - inf would be NaN: equal is pi / 4
    den = lo + hi if big else hi
    r = num / den if num != 0.0 else 0.0  # 0 / 0 (both zero): angle 0
    z = r * r
    p = (((_AP[0] * z + _AP[1]) * z + _AP[2]) * z + _AP[3]) * z + _AP[4]
    d = ((((z + _AQ[0]) * z + _AQ[1]) * z + _AQ[2]) * z + _AQ[3]) * z + _AQ[4]
    a = r + r * (z * p / d)
    a = _PI_4 + (a + 0.5 * _PI_2_LO) if big else a
    a = (_PI_2 - a) + _PI_2_LO if ay > ax else a
    a = math.pi - a if math.copysign(1.0, x) < 0.0 else a
    a = a if (ax == ax) & (ay == ay) else math.nan
    return math.copysign(a, y)


@njit
def _root(wx, wy, wz, ux, uy, L1, L2):
    """The knee-outward root of an arm whose ball joint is at w = (wx, wy, wz) from its shoulder,
    U_i = (ux, uy, 0): (cos theta, sin theta) times rho^2, rho^2, and whether it exists (below
    that, the values are NaN or meaningless). Also a + c and b, which place theta in its range.

    a cos(theta) + b sin(theta) = c with a = w.u_i, b = -w_z, c = (L1^2 + |w|^2 - L2^2) / (2 L1):
    theta = atan2(b, a) - acos(c / rho), rho = |(a, b)|, taken as one angle: with
    h = sqrt(rho^2 - c^2), cos theta = (a c + b h) / rho^2 and sin theta = (b c - a h) / rho^2.
    No branch, so a loop over points of one arm vectorises."""
    a = wx * ux + wy * uy
    b = -wz
    c = (L1 * L1 + (wx * wx + wy * wy + wz * wz) - L2 * L2) / (2.0 * L1)
    rho2 = a * a + b * b
    disc = rho2 - c * c
    exists = disc >= 0.0 and rho2 > 0.0 and math.isfinite(rho2) and math.isfinite(c)
    h = math.sqrt(disc if disc >= 0.0 else 0.0)  # where disc < 0 the root does not exist: any value
    return a * c + b * h, b * c - a * h, rho2, a + c, b, exists


@njit(inline="always")  # one caller: typed in it, no module of its own on a first run
def _shift(x, y, a_plus_c, b):
    """What an arm's theta, taken as atan2(y, x) of :func:`_root`'s values in (-pi, pi], needs added
    to lie in (-2 pi, pi]: atan2(b, a) - acos(c / rho) lies there, below -pi exactly when b < 0 and
    a + c < 0 (atan2(b, a) + pi < acos(c / rho)), where one atan2 gives it plus 2 pi: -2 pi where
    that is so and atan2(y, x) > 0 (y > 0, or y = +0 with x < 0), else 0."""
    positive = y > 0.0 or (y == 0.0 and math.copysign(1.0, y) > 0.0 and x < 0.0)
    return -2.0 * math.pi if b < 0.0 and a_plus_c < 0.0 and positive else 0.0


@njit
def _arm(wx, wy, wz, ux, uy, L1, cq, sq):
    """An arm at cos q, sin q with its ball joint at w from its shoulder (U_i = (ux, uy, 0)):
    the forearm d = w - L1 (cos q u - sin q z) and the elbow's rate e' = L1 (-sin q u - cos q z),
    mm and mm/rad, as (dx, dy, dz, ex, ey, ez)."""
    return (wx - L1 * cq * ux, wy - L1 * cq * uy, wz + L1 * sq, -L1 * sq * ux, -L1 * sq * uy, -L1 * cq)


@njit
def _rates(wx, wy, wz, ux, uy, L1, cq, sq, tx, ty, tz, kx, ky, kz):
    """An arm's q' (rad/mm) and q'' (rad/mm^2) along a curve with unit tangent t and curvature
    vector kappa, its ball joint at w from its shoulder, from cos q and sin q: with the forearm
    d = w - L1 (cos q u - sin q z) and the elbow's rates e' = L1 (-sin q u - cos q z),
    e'' = L1 (-cos q u + sin q z), as closure_derivatives: q' = d.t / d.e',
    q'' = ((d'.t + d.kappa) - q' (d'.e' + d.e'' q')) / d.e', d' = t - e' q'."""
    dx, dy, dz, ex, ey, ez = _arm(wx, wy, wz, ux, uy, L1, cq, sq)
    fx, fy, fz = -L1 * cq * ux, -L1 * cq * uy, L1 * sq
    g = dx * ex + dy * ey + dz * ez
    d1 = (dx * tx + dy * ty + dz * tz) / g
    ddx, ddy, ddz = tx - ex * d1, ty - ey * d1, tz - ez * d1
    num = (ddx * tx + ddy * ty + ddz * tz) + (dx * kx + dy * ky + dz * kz)
    g1 = (ddx * ex + ddy * ey + ddz * ez) + (dx * fx + dy * fy + dz * fz) * d1
    return d1, (num - d1 * g1) / g


@njit
def _to_rows(src, k0, m, rows, r0):
    """rows[r0 + j, :m] = src[k0:k0 + m, j] for each column j of src (n, 3)."""
    for k in range(m):
        for j in range(3):
            rows[r0 + j, k] = src[k0 + k, j]


@njit
def _inverse_kernel(points, offsets, L1, L2, q):
    """Each arm's knee-outward root at points (N,3) mm into q (N,3) rad: atan2 of :func:`_root`'s
    cos and sin plus :func:`_shift`; a row is NaN where any arm has no real root (or the point is
    not finite). Where every arm has one, its x and y are finite or infinite, never NaN (|a c|,
    |b h| <= rho^2, which is finite), so the angles of a row are all finite or all NaN."""
    n = points.shape[0]
    p = np.empty((3, BLOCK))
    th = np.empty((3, BLOCK))
    ok = np.empty((3, BLOCK), dtype=np.bool_)
    for k0 in range(0, n, BLOCK):
        m = min(BLOCK, n - k0)
        _to_rows(points, k0, m, p, np.int64(0))  # a literal row would compile _to_rows for that value
        px, py, pz = p[0], p[1], p[2]
        for i in range(3):
            ux, uy = U[i, 0], U[i, 1]
            ox, oy, oz = offsets[i, 0], offsets[i, 1], offsets[i, 2]
            thi, oki = th[i], ok[i]
            for k in range(m):
                x, y, _, apc, b, oki[k] = _root(px[k] + ox, py[k] + oy, pz[k] + oz, ux, uy, L1, L2)
                thi[k] = atan2(y, x) + _shift(x, y, apc, b)
        for k in range(m):
            good = ok[0, k] and ok[1, k] and ok[2, k]
            for i in range(3):
                q[k0 + k, i] = th[i, k] if good else np.nan


@njit
def _derivatives_kernel(points, q, t, kappa, offsets, L1, q1, q2):
    """q' and q'' (N,3) at points whose joints q (N,3) are known."""
    for k in range(points.shape[0]):
        for i in range(3):
            q1[k, i], q2[k, i] = _rates(points[k, 0] + offsets[i, 0], points[k, 1] + offsets[i, 1],
                                        points[k, 2] + offsets[i, 2], U[i, 0], U[i, 1], L1, math.cos(q[k, i]),
                                        math.sin(q[k, i]), t[k, 0], t[k, 1], t[k, 2], kappa[k, 0], kappa[k, 1],
                                        kappa[k, 2])


@njit
def _scaled_rates_kernel(points, t, kappa, offsets, L1, L2, scale, q1, q2):
    """q' scale and q'' scale^2 (N,3) into q1, q2, the rates taking cos q and sin q from the root
    itself (no atan2); a row is NaN where any arm has no root. Returns the first such row, or -1."""
    first = -1
    scale2 = scale * scale
    n = points.shape[0]
    s = np.empty((9, BLOCK))  # a block's points, tangents and curvatures, one coordinate a row
    o1, o2, ok = np.empty((3, BLOCK)), np.empty((3, BLOCK)), np.empty((3, BLOCK), dtype=np.bool_)
    for k0 in range(0, n, BLOCK):
        m = min(BLOCK, n - k0)
        _to_rows(points, k0, m, s, np.int64(0))
        _to_rows(t, k0, m, s, np.int64(3))
        _to_rows(kappa, k0, m, s, np.int64(6))
        px, py, pz, tx, ty, tz, kx, ky, kz = s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7], s[8]
        for i in range(3):
            ux, uy = U[i, 0], U[i, 1]
            ox, oy, oz = offsets[i, 0], offsets[i, 1], offsets[i, 2]
            o1i, o2i, oki = o1[i], o2[i], ok[i]
            for k in range(m):
                wx, wy, wz = px[k] + ox, py[k] + oy, pz[k] + oz
                x, y, rho2, _, _, oki[k] = _root(wx, wy, wz, ux, uy, L1, L2)
                d1, d2 = _rates(wx, wy, wz, ux, uy, L1, x / rho2, y / rho2, tx[k], ty[k], tz[k], kx[k], ky[k], kz[k])
                o1i[k] = d1 * scale
                o2i[k] = d2 * scale2
        for k in range(m):
            if ok[0, k] and ok[1, k] and ok[2, k]:
                for i in range(3):
                    q1[k0 + k, i] = o1[i, k]
                    q2[k0 + k, i] = o2[i, k]
            else:
                for i in range(3):
                    q1[k0 + k, i] = q2[k0 + k, i] = np.nan
                if first < 0:
                    first = k0 + k
    return first


KINEMATICS = RotaryDelta
