"""Planar five-bar (5R) linkage for x-y plus a lead-screw z (the Atlas printer).

Motors at A (``origin``) and C (``origin + base_length x``), in the bed plane's
frame; links A-B, B-P (arm a) and C-D, D-P (arm c). Inverse (Atlas paper, sec.
IV): per arm, ``theta = atan2(P - M) + codo * acos((l1^2 + |MP|^2 - l2^2) / (2 l1 |MP|))``;
the two signs CODO1, CODO2 choose one of the four working modes. Forward: the
two circles around B and D of radii l2 and l4 meet in two points (the two
assembly modes); the one whose inverse returns the same joint angles under the
chosen working mode *and* whose assembly mode is the machine's is kept. The
assembly mode is the side of the distal links' elbow at P: the sign of
``(B - P) x (D - P)``; it only changes through a type-2 singularity (B, P, D in
line), so the machine keeps the one it has over the bed centre, and points of
the other mode are unreachable (without this, the same joint angles served two
points, and ``forward(inverse(p))`` could land some 390 mm away from p behind the
motors). Joint 3 is the tool height above the bed, mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import Section
from ..jit import njit
from .base import GRAVITY, MM, Kinematics, closure_derivatives, closure_motion, solve_rows


def _wrap(a, centre=0.0):
    """Angles into (centre - pi, centre + pi]."""
    return centre - ((centre - a + np.pi) % (2 * np.pi) - np.pi)


FAMILY = "five_bar"


@dataclass(frozen=True)
class FiveBarGeometry:
    """Planar 5R linkage for x-y plus a lead-screw z. mm.

    Motor A at ``(origin_x, origin_y)`` on the bed, motor C at ``base_length``
    further along +x; links A-B (``proximal_a``), B-P (``distal_a``), C-D
    (``proximal_c``), D-P (``distal_c``). ``codo1`` and ``codo2`` (+1 or -1) pick
    the working mode as in the Atlas paper: the sign of the elbow angle added to
    the direction from each motor to P.
    """

    base_length: float
    proximal_a: float
    distal_a: float
    proximal_c: float
    distal_c: float
    origin_x: float
    origin_y: float
    codo1: int = 1
    codo2: int = -1


def read_geometry(sec: Section) -> FiveBarGeometry:
    """The ``[kinematics]`` keys of a five-bar, mm; ``codo1``/``codo2`` are +1 or -1."""
    return FiveBarGeometry(
        base_length=sec.getfloat("base_length", minval=0),
        proximal_a=sec.getfloat("proximal_a", above=0),
        distal_a=sec.getfloat("distal_a", above=0),
        proximal_c=sec.getfloat("proximal_c", above=0),
        distal_c=sec.getfloat("distal_c", above=0),
        origin_x=sec.getfloat("origin_x", required=True),
        origin_y=sec.getfloat("origin_y", required=True),
        codo1=sec.getint("codo1", choices=(1, -1)),
        codo2=sec.getint("codo2", choices=(1, -1)),
    )


@dataclass(frozen=True)
class FiveBarMasses:
    """The moving parts of a five-bar printer (the ``[dynamics]`` table). kg, kg m^2.

    ``proximal_inertia``: links A-B and C-D each about its motor axis, (A side, C side);
    ``elbow_mass``: the joint hardware at B and at D each; ``distal_mass``: links B-P and D-P each,
    uniform between the joint centres; ``tool_mass``: what rides at P (the print head). The linkage
    moves in a horizontal plane (gravity does no work on it). ``z_mass``: what the lead screw lifts
    (with the rotor and screw reflected: J (2 pi / lead)^2), the bed (``z_carries = "bed"``, which
    goes down as the tool height z grows) or the head (``"head"``)."""

    proximal_inertia: tuple[float, float]
    elbow_mass: float
    distal_mass: float
    tool_mass: float
    z_mass: float
    z_carries: str = "bed"
    rotor_inertia: float = 0.0


def read_dynamics(sec: Section, geometry: FiveBarGeometry) -> FiveBarMasses:
    """The family's keys of the ``[dynamics]`` table. A proximal link of unknown shape defaults to a
    uniform bar from its motor axis to its elbow (m l^2 / 3 with its own length)."""
    prox = sec.getfloat("proximal_mass", minval=0, maxval=100)
    given = sec.getfloat("proximal_inertia", required=False, minval=0, maxval=100)
    inertia = tuple(prox * (length * MM) ** 2 / 3 if given is None else given
                    for length in (geometry.proximal_a, geometry.proximal_c))
    return FiveBarMasses(
        proximal_inertia=inertia,
        elbow_mass=sec.getfloat("elbow_mass", 0.0, minval=0, maxval=100),
        distal_mass=sec.getfloat("distal_mass", minval=0, maxval=100),
        tool_mass=sec.getfloat("tool_mass", minval=0, maxval=1000),
        z_mass=sec.getfloat("z_mass", minval=0, maxval=1000),
        z_carries=sec.getstr("z_carries", "bed", choices=("bed", "head"), required=False),
        rotor_inertia=sec.getfloat("rotor_inertia", 0.0, minval=0, maxval=100),
    )


class FiveBar(Kinematics):
    geometry_class = FiveBarGeometry
    n_joints = 3
    joint_kinds = ("revolute", "revolute", "prismatic")

    def __init__(self, geometry, position_min, position_max, singularity_limit: float = 50.0):
        super().__init__(geometry, position_min, position_max, singularity_limit)
        g = geometry
        self.A = np.array([g.origin_x, g.origin_y])
        self.C = self.A + np.array([g.base_length, 0.0])
        # Arm angles are reported in the turn centred on the middle of each joint's range, so a
        # range that crosses 180 deg stays continuous.
        self.centre = (self.position_min[:2] + self.position_max[:2]) / 2
        # Assembly mode: the one at the bed centre (+1 if the centre is out of reach).
        sign = self._assembly(np.zeros((1, 3)), self.inverse(np.zeros((1, 3))))[0]
        self.assembly = sign if sign != 0 else 1.0

    def _assembly(self, points, q):
        """Sign of (B - P) x (D - P) per row (N,): +1, -1, or 0 (singular or NaN)."""
        b, d = self._elbows(q)
        u, v = b - points[:, :2], d - points[:, :2]
        return np.nan_to_num(np.sign(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]))

    def _arm(self, rel, l1, l2, codo):
        d = np.hypot(rel[:, 0], rel[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            cos_e = (l1**2 + d**2 - l2**2) / (2 * l1 * d)
            th = np.arctan2(rel[:, 1], rel[:, 0]) + codo * np.arccos(cos_e)
        th[~(np.abs(cos_e) <= 1)] = np.nan
        return th

    def inverse(self, points):
        """points: (N,3) mm -> q: (N,3) = (theta_A rad, theta_C rad, z mm); each angle within
        half a turn of the middle of its joint range."""
        points = np.atleast_2d(np.asarray(points, dtype=float))
        g = self.geometry
        q = np.empty((len(points), 3))
        q[:, 0] = _wrap(self._arm(points[:, :2] - self.A, g.proximal_a, g.distal_a, g.codo1), self.centre[0])
        q[:, 1] = _wrap(self._arm(points[:, :2] - self.C, g.proximal_c, g.distal_c, g.codo2), self.centre[1])
        q[:, 2] = points[:, 2]
        q[~np.all(np.isfinite(q), axis=1)] = np.nan
        return q

    def _elbows(self, q):
        g = self.geometry
        b = self.A + g.proximal_a * np.stack([np.cos(q[:, 0]), np.sin(q[:, 0])], axis=1)
        d = self.C + g.proximal_c * np.stack([np.cos(q[:, 1]), np.sin(q[:, 1])], axis=1)
        return b, d

    def forward(self, q):
        """q: (N,3) -> points (N,3) mm (NaN where the distal links cannot meet)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        g = self.geometry
        b, d = self._elbows(q)
        bd = d - b
        dist = np.hypot(bd[:, 0], bd[:, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            a = (g.distal_a**2 - g.distal_c**2 + dist**2) / (2 * dist)
            h = np.sqrt(g.distal_a**2 - a**2)
            ex = bd / dist[:, None]
        mid = b + a[:, None] * ex
        perp = np.stack([-ex[:, 1], ex[:, 0]], axis=1)
        cands = np.stack([mid + h[:, None] * perp, mid - h[:, None] * perp], axis=1)  # (N, 2, 2)
        err = np.empty((len(q), 2))
        for k in range(2):
            pts = np.concatenate([cands[:, k], q[:, 2:3]], axis=1)
            qq = self.inverse(pts)
            err[:, k] = np.abs(_wrap(qq[:, 0] - q[:, 0])) + np.abs(_wrap(qq[:, 1] - q[:, 1]))
            err[self._assembly(pts, q) != self.assembly, k] = np.inf
        err = np.nan_to_num(err, nan=np.inf)
        pick = np.argmin(err, axis=1)
        out = np.concatenate([cands[np.arange(len(q)), pick], q[:, 2:3]], axis=1)
        out[~(np.min(err, axis=1) < 1e-6)] = np.nan
        return out

    def extra_ok(self, points, q):
        """Only the machine's assembly mode (see the module docstring)."""
        return self._assembly(points, q) == self.assembly

    def _closure(self, q, points):
        g = self.geometry
        b, d = self._elbows(q)
        p = points[:, :2]
        rows = np.stack([p - b, p - d], axis=1)  # (N, 2, 2)
        db = g.proximal_a * np.stack([-np.sin(q[:, 0]), np.cos(q[:, 0])], axis=1)
        dd = g.proximal_c * np.stack([-np.sin(q[:, 1]), np.cos(q[:, 1])], axis=1)
        diag = np.stack([-np.einsum("ni,ni->n", p - b, db), -np.einsum("ni,ni->n", p - d, dd)], axis=1)
        return rows, diag

    def path_derivatives(self, points, q, t, kappa):
        """Closed form (:func:`closure_derivatives`) for the two arms, whose distal links keep
        their length while each elbow turns on a circle about its motor; z is its own joint."""
        g = self.geometry
        b, d = self._elbows(q)
        links = np.stack([points[:, :2] - b, points[:, :2] - d], axis=1)  # (N, 2, 2)
        c, s = np.cos(q[:, :2])[..., None], np.sin(q[:, :2])[..., None]
        radius = np.array([g.proximal_a, g.proximal_c])[None, :, None]
        de = radius * np.concatenate([-s, c], axis=2)
        dde = radius * np.concatenate([-c, -s], axis=2)
        q1, q2 = closure_derivatives(links, de, dde, t[:, :2], kappa[:, :2])
        return np.column_stack([q1, t[:, 2]]), np.column_stack([q2, kappa[:, 2]])

    def inverse_dynamics(self, masses: FiveBarMasses, q, qd, qdd):
        """Joint torques and force (N, 3): N m at the two arms, N on the lead screw (up positive in
        the tool height z), for joints q (N,3) (rad, rad, mm), qd (per s), qdd (per s^2); NaN where
        the linkage cannot close. Proximal links turn about their motor axes; elbows, the tool and
        each distal link's three points (see :mod:`.base`) are point masses in the horizontal plane,
        so the arms feel no gravity; the z axis carries ``z_mass`` up or down."""
        q, qd, qdd = (np.atleast_2d(np.asarray(v, dtype=float)) for v in (q, qd, qdd))
        m = masses
        g = self.geometry
        b, d = self._elbows(q)
        elbows = np.stack([b, d], axis=1)  # (N, 2 arms, 2) mm
        p = self.forward(q)[:, :2]
        c, s = np.cos(q[:, :2])[..., None], np.sin(q[:, :2])[..., None]
        radius = np.array([g.proximal_a, g.proximal_c])[None, :, None]
        de = radius * np.concatenate([-s, c], axis=2)
        dde = radius * np.concatenate([-c, -s], axis=2)
        jac, acc = closure_motion(p[:, None, :] - elbows, de, dde, qd[:, :2], qdd[:, :2])
        acc_e = de * qdd[:, :2, None] + dde * (qd[:, :2] ** 2)[..., None]
        f_mid = (2 * m.distal_mass / 3) * MM * 0.5 * (acc_e + acc[:, None, :])
        f_p = (m.tool_mass + 2 * m.distal_mass / 6) * MM * acc + 0.5 * f_mid.sum(axis=1)
        f_e = (m.elbow_mass + m.distal_mass / 6) * MM * acc_e + 0.5 * f_mid
        tau = np.empty((len(q), 3))
        tau[:, :2] = MM * (np.einsum("nkj,nk->nj", jac, f_p) + np.einsum("njk,njk->nj", de, f_e))
        tau[:, :2] += (np.array(m.proximal_inertia) + m.rotor_inertia) * qdd[:, :2]
        # the lifted body is at +z (head) or -z (bed) plus a constant: tau = J m (J zdd + g), J = +-1
        sign = 1.0 if m.z_carries == "head" else -1.0
        tau[:, 2] = m.z_mass * (MM * qdd[:, 2] + sign * GRAVITY)
        return tau

    def torque_coefficients(self, masses: FiveBarMasses, points, q, dq, ddq):
        """``A sdd + B sd^2 + C`` of the joint torques and screw force along a path in one compiled
        pass, what :func:`.base.path_coefficients` gives from :meth:`inverse_dynamics` (its tested
        reference): points (N,3) mm, q = inverse(points) (N,3), dq, ddq (N,3) per path unit ->
        (A, B, C), each (N,3): N m, N m, N."""
        points, q, dq, ddq = (np.ascontiguousarray(np.atleast_2d(v), dtype=float) for v in (points, q, dq, ddq))
        m, g = masses, self.geometry
        out = np.empty((3, len(q), 3))
        params = np.array([m.tool_mass, m.elbow_mass, m.distal_mass, m.proximal_inertia[0] + m.rotor_inertia,
                           m.proximal_inertia[1] + m.rotor_inertia, m.z_mass,
                           GRAVITY if m.z_carries == "head" else -GRAVITY])
        motors = np.array([self.A, self.C])
        _torque_coefficients_kernel(points, q, dq, ddq, motors, np.array([g.proximal_a, g.proximal_c]), params, out)
        return out[0], out[1], out[2]

    def jacobian(self, q):
        """q: (N,3) -> (N,3,3) d(point)/d(q): mm/rad for the arms, 1 for z."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        rows, diag = self._closure(q, self.forward(q))
        out = np.zeros((len(q), 3, 3))
        out[:, :2, :2] = -solve_rows(rows, diag[:, :, None] * np.eye(2)[None])
        out[:, 2, 2] = 1.0
        return out

    def inverse_jacobian(self, q):
        """q: (N,3) -> (N,3,3) d(q)/d(point)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        rows, diag = self._closure(q, self.forward(q))
        out = np.zeros((len(q), 3, 3))
        with np.errstate(divide="ignore", invalid="ignore"):
            out[:, :2, :2] = -rows / diag[:, :, None]
        out[:, 2, 2] = 1.0
        return out

    def condition(self, q):
        """Condition number of the planar (x-y) block; z is decoupled and never singular."""
        q = np.atleast_2d(q)
        out = np.full(len(q), np.inf)
        good = np.all(np.isfinite(q), axis=1)
        if good.any():
            out[good] = self._condition_of(self.jacobian(q[good])[:, :2, :2])
        return out


@njit(inline="always")  # inlined: a call no longer builds and counts views of its array arguments
def _link_torques(p, q, motors, lengths, params, x, y, gravity, tau):
    """tau (3,) of :meth:`FiveBar.inverse_dynamics` (N m, N m, N) at the tool point p and joints q,
    velocities x and accelerations y (per s, per s^2); gravity 1.0 or 0.0. In the plane: the distal
    links d_i = p - elbow_i, the elbows' rates e'_i, e''_i; D a = g y + h x^2 - |v - e' x|^2,
    v = D^-1 (g x), D (2, 2) with rows d_i."""
    c0, s0, c1, s1 = math.cos(q[0]), math.sin(q[0]), math.cos(q[1]), math.sin(q[1])
    l0, l1 = lengths[0], lengths[1]
    d00, d01 = p[0] - motors[0, 0] - l0 * c0, p[1] - motors[0, 1] - l0 * s0
    d10, d11 = p[0] - motors[1, 0] - l1 * c1, p[1] - motors[1, 1] - l1 * s1
    e00, e01, e10, e11 = -l0 * s0, l0 * c0, -l1 * s1, l1 * c1  # e'
    f00, f01, f10, f11 = -l0 * c0, -l0 * s0, -l1 * c1, -l1 * s1  # e''
    g0, g1 = d00 * e00 + d01 * e01, d10 * e10 + d11 * e11
    h0, h1 = d00 * f00 + d01 * f01, d10 * f10 + d11 * f11
    det = d00 * d11 - d01 * d10
    i00, i01, i10, i11 = d11 / det, -d01 / det, -d10 / det, d00 / det  # D^-1
    v0 = i00 * g0 * x[0] + i01 * g1 * x[1]
    v1 = i10 * g0 * x[0] + i11 * g1 * x[1]
    r0 = g0 * y[0] + h0 * x[0] * x[0] - ((v0 - e00 * x[0]) ** 2 + (v1 - e01 * x[0]) ** 2)
    r1 = g1 * y[1] + h1 * x[1] * x[1] - ((v0 - e10 * x[1]) ** 2 + (v1 - e11 * x[1]) ** 2)
    a0, a1 = i00 * r0 + i01 * r1, i10 * r0 + i11 * r1
    m_tool, m_e, dist, inertia0, inertia1, m_z, z_gravity = (params[0], params[1], params[2], params[3], params[4],
                                                             params[5], params[6])
    # elbows' accelerations, the distal links' middles (half their force to either end)
    b00, b01 = e00 * y[0] + f00 * x[0] * x[0], e01 * y[0] + f01 * x[0] * x[0]
    b10, b11 = e10 * y[1] + f10 * x[1] * x[1], e11 * y[1] + f11 * x[1] * x[1]
    mid = 2 * dist / 3
    m0x, m0y = mid * 0.5 * (b00 + a0) * MM, mid * 0.5 * (b01 + a1) * MM
    m1x, m1y = mid * 0.5 * (b10 + a0) * MM, mid * 0.5 * (b11 + a1) * MM
    fpx = (m_tool + 2 * dist / 6) * a0 * MM + 0.5 * (m0x + m1x)
    fpy = (m_tool + 2 * dist / 6) * a1 * MM + 0.5 * (m0y + m1y)
    fe0x, fe0y = (m_e + dist / 6) * b00 * MM + 0.5 * m0x, (m_e + dist / 6) * b01 * MM + 0.5 * m0y
    fe1x, fe1y = (m_e + dist / 6) * b10 * MM + 0.5 * m1x, (m_e + dist / 6) * b11 * MM + 0.5 * m1y
    w0, w1 = i00 * fpx + i10 * fpy, i01 * fpx + i11 * fpy  # D^-T fp
    tau[0] = MM * (g0 * w0 + e00 * fe0x + e01 * fe0y) + inertia0 * y[0]
    tau[1] = MM * (g1 * w1 + e10 * fe1x + e11 * fe1y) + inertia1 * y[1]
    tau[2] = m_z * (MM * y[2] + gravity * z_gravity)


@njit
def _torque_coefficients_kernel(points, q, dq, ddq, motors, lengths, params, out):
    """out[0], out[1], out[2] (N,3): A, B, C of :meth:`FiveBar.torque_coefficients`."""
    zero = np.zeros(3)
    for n in range(q.shape[0]):
        _link_torques(points[n], q[n], motors, lengths, params, zero, dq[n], 0.0, out[0, n])
        _link_torques(points[n], q[n], motors, lengths, params, dq[n], ddq[n], 0.0, out[1, n])
        _link_torques(points[n], q[n], motors, lengths, params, zero, zero, 1.0, out[2, n])


KINEMATICS = FiveBar
