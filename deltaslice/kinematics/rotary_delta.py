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
from .base import Kinematics, lower_sphere_intersection, solve_rows

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
        points = np.ascontiguousarray(np.atleast_2d(np.asarray(points, dtype=float)))
        q = np.empty((len(points), 3))
        _inverse_kernel(points, self._offsets, self.L1, self.L2, q)
        return q

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
        no q array, and the scaling done as the rates are written."""
        points, t, kappa = (np.ascontiguousarray(v, dtype=float) for v in (points, t, kappa))
        for out in (out1, out2):  # the kernel writes unchecked: numpy's out= would have refused these
            if out.shape != (len(points), 3) or out.dtype != np.float64:
                raise ValueError(f"scaled_path_derivatives: an output is {out.dtype} {out.shape}, "
                                 f"expected float64 ({len(points)}, 3)")
        return int(_scaled_rates_kernel(points, t, kappa, self._offsets, self.L1, self.L2, float(scale), out1, out2))

    def ball_joint_tilt(self, points, q):
        """Sideways tilt of each forearm out of its arm's vertical plane: (N,3) rad."""
        d, _ = self._closure(q, points)
        return np.arcsin(np.clip(np.einsum("nij,ij->ni", d, V) / self.L2, -1, 1))

    def extra_ok(self, points, q):
        tilt_max = self.geometry.ball_joint_tilt_max
        if tilt_max is None:
            return np.ones(len(points), dtype=bool)
        return np.all(np.abs(self.ball_joint_tilt(points, q)) <= tilt_max + 1e-12, axis=1)


# The kernels below loop over points with the arms' unit vectors U_i = (cos, sin, 0): one pass,
# no (N, 3, 3) temporaries (the numpy forms took ~4 us a point; these ~0.1 us).


@njit
def _arm_root(points, k, i, offsets, L1, L2):
    """Arm i's knee-outward root at point k as (cos theta, sin theta) times rho^2, and rho^2
    (below); NaN when there is none.

    a cos(theta) + b sin(theta) = c with w = point + offsets[i], a = w.u_i, b = -w_z,
    c = (L1^2 + |w|^2 - L2^2) / (2 L1): theta = atan2(b, a) - acos(c / rho), rho = |(a, b)|,
    taken as one angle: with h = sqrt(rho^2 - c^2), cos theta = (a c + b h) / rho^2 and
    sin theta = (b c - a h) / rho^2. Also a + c and b, which place theta in its range."""
    wx = points[k, 0] + offsets[i, 0]
    wy = points[k, 1] + offsets[i, 1]
    wz = points[k, 2] + offsets[i, 2]
    a = wx * U[i, 0] + wy * U[i, 1]
    b = -wz
    c = (L1 * L1 + (wx * wx + wy * wy + wz * wz) - L2 * L2) / (2.0 * L1)
    rho2 = a * a + b * b
    disc = rho2 - c * c
    if not (disc >= 0.0 and rho2 > 0.0 and math.isfinite(rho2) and math.isfinite(c)):
        return np.nan, np.nan, np.nan, np.nan, np.nan
    h = math.sqrt(disc)
    return a * c + b * h, b * c - a * h, rho2, a + c, b


@njit
def _arm_angle(points, k, i, offsets, L1, L2):
    """Arm i's knee-outward root at point k: (theta, cos theta, sin theta), NaN when none
    (:func:`_arm_root`), theta in (-2 pi, pi]."""
    x, y, rho2, a_plus_c, b = _arm_root(points, k, i, offsets, L1, L2)
    if rho2 != rho2:
        return np.nan, np.nan, np.nan
    th = math.atan2(y, x)
    # atan2(b, a) - acos(c / rho) lies in (-2 pi, pi]: below -pi exactly when b < 0 and
    # a + c < 0 (atan2(b, a) + pi < acos(c / rho)), where one atan2 gives it plus 2 pi.
    if b < 0.0 and a_plus_c < 0.0 and th > 0.0:
        th -= 2.0 * math.pi
    return th, x / rho2, y / rho2


@njit
def _arm_rates(points, k, i, offsets, L1, cq, sq, t, kappa):
    """Arm i's q' (rad/mm) and q'' (rad/mm^2) at point k along a curve with unit tangent t and
    curvature vector kappa (rows k), from cos q and sin q: with the forearm
    d = w - L1 (cos q u - sin q z) and the elbow's rates e' = L1 (-sin q u - cos q z),
    e'' = L1 (-cos q u + sin q z), as closure_derivatives: q' = d.t / d.e',
    q'' = ((d'.t + d.kappa) - q' (d'.e' + d.e'' q')) / d.e', d' = t - e' q'."""
    ux, uy = U[i, 0], U[i, 1]
    tx, ty, tz = t[k, 0], t[k, 1], t[k, 2]
    dx = points[k, 0] + offsets[i, 0] - L1 * cq * ux
    dy = points[k, 1] + offsets[i, 1] - L1 * cq * uy
    dz = points[k, 2] + offsets[i, 2] + L1 * sq
    ex, ey, ez = -L1 * sq * ux, -L1 * sq * uy, -L1 * cq
    fx, fy, fz = -L1 * cq * ux, -L1 * cq * uy, L1 * sq
    g = dx * ex + dy * ey + dz * ez
    d1 = (dx * tx + dy * ty + dz * tz) / g
    ddx, ddy, ddz = tx - ex * d1, ty - ey * d1, tz - ez * d1
    num = (ddx * tx + ddy * ty + ddz * tz) + (dx * kappa[k, 0] + dy * kappa[k, 1] + dz * kappa[k, 2])
    g1 = (ddx * ex + ddy * ey + ddz * ez) + (dx * fx + dy * fy + dz * fz) * d1
    return d1, (num - d1 * g1) / g


@njit
def _inverse_kernel(points, offsets, L1, L2, q):
    """q (N,3) rad of points (N,3) mm; a row is NaN where any arm has no real root (or the
    point is not finite)."""
    for k in range(points.shape[0]):
        for i in range(3):
            q[k, i] = _arm_angle(points, k, i, offsets, L1, L2)[0]
            if q[k, i] != q[k, i]:
                q[k, 0] = q[k, 1] = q[k, 2] = np.nan
                break


@njit
def _derivatives_kernel(points, q, t, kappa, offsets, L1, q1, q2):
    """q' and q'' (N,3) at points whose joints q (N,3) are known."""
    for k in range(points.shape[0]):
        for i in range(3):
            q1[k, i], q2[k, i] = _arm_rates(points, k, i, offsets, L1, math.cos(q[k, i]), math.sin(q[k, i]), t, kappa)


@njit
def _scaled_rates_kernel(points, t, kappa, offsets, L1, L2, scale, q1, q2):
    """q' scale and q'' scale^2 (N,3) into q1, q2 in one pass, the rates taking cos q and sin q
    from the root itself; a row is NaN where any arm has no root. Returns the first such row, or
    -1."""
    first = -1
    scale2 = scale * scale
    for k in range(points.shape[0]):
        reach = True
        for i in range(3):
            x, y, rho2, _, _ = _arm_root(points, k, i, offsets, L1, L2)  # no atan2: the rates need cos and sin only
            reach = reach and rho2 == rho2
            d1, d2 = _arm_rates(points, k, i, offsets, L1, x / rho2, y / rho2, t, kappa)
            q1[k, i] = d1 * scale
            q2[k, i] = d2 * scale2
        if not reach:
            for i in range(3):
                q1[k, i] = q2[k, i] = np.nan
            if first < 0:
                first = k
    return first


KINEMATICS = RotaryDelta
