"""The kinematics contract every machine family implements.

A family is one class built from a geometry dataclass and the joint position
limits. Everything is vectorised over N points:

* ``inverse(points (N,3) float, mm) -> q (N,J) float`` (rad or mm; NaN rows where
  the geometry cannot reach the point),
* ``forward(q (N,J)) -> points (N,3)`` (NaN rows where the joints cannot close
  the mechanism),
* ``jacobian(q (N,J)) -> (N,3,J)``: d(point)/d(q),
* ``inverse_jacobian(q (N,J)) -> (N,J,3)``: d(q)/d(point),
* ``path_derivatives(points, q, t, kappa) -> (q' (N,J), q'' (N,J))``: the joints' first and
  second derivatives along a curve, what the planner uses (closed form per family, a finite
  difference of the inverse Jacobian by default); ``scaled_path_derivatives(points, t, kappa,
  scale, out1, out2)`` writes them in path units into the planner's arrays (a family may fuse it
  with the inverse),
* ``reachable(points (N,3)) -> (N,) bool``: real inverse, joint limits and any
  family-specific limit (ball-joint tilt), and not near a singularity.

A family with a dynamics model also has ``read_dynamics(section, geometry)`` (its masses from the
printer file's ``[dynamics]`` table, a frozen dataclass) and ``inverse_dynamics(masses, q, qd, qdd)
-> (N,J)`` joint torques (N m) or forces (N) from joint positions, velocities and accelerations
(N,J) in joint units; :func:`path_coefficients` splits them along a path (see the notes below).

Points are in the bed frame: x, y on the bed with the origin at its centre, z up
from the bed surface, tool tip. Hot loops get masks, never exceptions.
"""

from __future__ import annotations

import numpy as np

from ..tolerances import JOINT_ROUNDOFF

REACH_BLOCK = 65536  # points per evaluation in Kinematics.reachable
FD_STEP = 1e-3  # mm: step of the default path_derivatives' difference of the inverse Jacobian


def rows3(v, name: str) -> np.ndarray:
    """v as contiguous float64 rows of three (a single row becomes (1, 3)); ValueError otherwise:
    the families' compiled kernels read three columns unchecked (a (N, 2) array would be read
    past its rows)."""
    v = np.ascontiguousarray(np.atleast_2d(np.asarray(v, dtype=float)))
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"{name}: expected rows of 3 values, got shape {v.shape}")
    return v


def check_out(out, n: int, j: int) -> None:
    """ValueError unless out is a float64 array (n, j), what a compiled kernel writes unchecked."""
    if not isinstance(out, np.ndarray) or out.shape != (n, j) or out.dtype != np.float64:
        got = f"{out.dtype} {out.shape}" if isinstance(out, np.ndarray) else type(out).__name__
        raise ValueError(f"out: expected a float64 array of shape ({n}, {j}), got {got}")


def solve_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched ``np.linalg.solve(a, b)`` that never raises: rows whose matrix is
    singular or holds NaN give NaN (a: (N,k,k), b: (N,k,m) -> (N,k,m))."""
    out = np.full(np.broadcast_shapes(a.shape[:1], b.shape[:1]) + b.shape[1:], np.nan)
    with np.errstate(invalid="ignore", over="ignore"):
        det = np.linalg.det(a) if len(a) else np.zeros(0)
    ok = np.isfinite(det) & (det != 0) & np.all(np.isfinite(b), axis=(1, 2))
    if ok.any():
        out[ok] = np.linalg.solve(a[ok], b[ok])
    return out


def lower_sphere_intersection(centres: np.ndarray, radius: float):
    """Where three equal spheres meet, the root with the lower z (deltas hang below their arms).

    centres: (N, 3 spheres, 3) float, mm; radius: mm. Returns (points (N,3), h2 (N,)): h2 is the
    squared height of the root above the centres' plane; where it is negative the spheres do
    not meet and the points are NaN."""
    p0, p1, p2 = centres[:, 0], centres[:, 1], centres[:, 2]
    ex = p1 - p0
    d = np.linalg.norm(ex, axis=1)
    ex = ex / d[:, None]
    i = np.einsum("ni,ni->n", ex, p2 - p0)
    ey = p2 - p0 - i[:, None] * ex
    j = np.linalg.norm(ey, axis=1)
    ey = ey / j[:, None]
    ez = np.cross(ex, ey)
    ez[ez[:, 2] > 0] *= -1  # the root below the centres
    x = d / 2  # equal radii: (r^2 - r^2 + d^2) / 2d
    y = (i**2 + j**2) / (2 * j) - i * x / j
    h2 = radius**2 - x**2 - y**2
    with np.errstate(invalid="ignore"):
        out = p0 + x[:, None] * ex + y[:, None] * ey + np.sqrt(h2)[:, None] * ez
    return out, h2


def closure_derivatives(d, de, dde, t, kappa):
    """Joint derivatives along a curve for arms each closed by a rigid link: joint i moves
    its elbow e_i(q_i) and the link keeps |d_i| constant, d_i = (point + const) - e_i(q_i).

    d: (N, J, k) link vectors, mm; de, dde: (N, J, k) the elbows' first and second
    derivatives in their joint (mm/rad, mm/rad^2); t: (N, k) unit tangent, kappa: (N, k)
    curvature vector (1/mm) of the curve in the same k coordinates. Returns (q' (N, J) rad/mm,
    q'' (N, J) rad/mm^2); inf or NaN where d_i is perpendicular to its elbow's motion (singular).

    From d.(p' - e' q') = 0: q' = (d.t) / (d.e'); differentiating the quotient along the curve
    with d' = t - e' q' gives q'' = ((d'.t + d.kappa) - q' (d'.e' + d.e'' q')) / (d.e')."""
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.einsum("njk,njk->nj", d, de)
        q1 = np.einsum("njk,nk->nj", d, t) / g
        dd = t[:, None, :] - de * q1[..., None]
        num1 = np.einsum("njk,nk->nj", dd, t) + np.einsum("njk,nk->nj", d, kappa)
        g1 = np.einsum("njk,njk->nj", dd, de) + np.einsum("njk,njk->nj", d, dde) * q1
        q2 = (num1 - q1 * g1) / g
    return q1, q2


class Kinematics:
    """Shared behaviour; subclasses provide ``inverse``, ``forward``, ``jacobian``."""

    n_joints: int = 3
    joint_kinds: tuple[str, ...] = ()

    def __init__(self, geometry, position_min, position_max, singularity_limit: float = 50.0):
        self.geometry = geometry
        self.position_min = np.asarray(position_min, dtype=float)
        self.position_max = np.asarray(position_max, dtype=float)
        self.singularity_limit = float(singularity_limit)

    # -- to implement -------------------------------------------------------------
    def inverse(self, points: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def forward(self, q: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def jacobian(self, q: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    # -- shared -------------------------------------------------------------------
    def inverse_into(self, points: np.ndarray, out: np.ndarray) -> None:
        """:meth:`inverse` of points (N,3) mm written into out (N,J) float (the sampler's rows of a
        block); a family with a compiled inverse writes there without a temporary."""
        q = self.inverse(points)
        check_out(out, len(q), q.shape[1])
        out[...] = q

    def inverse_jacobian(self, q: np.ndarray) -> np.ndarray:
        """q: (N,J) -> (N,J,3), d(q)/d(point); NaN where the Jacobian is singular."""
        jac = self.jacobian(q)
        return solve_rows(jac, np.broadcast_to(np.eye(jac.shape[1]), jac.shape[:1] + (jac.shape[1], jac.shape[1])))

    def inverse_jacobian_at(self, points: np.ndarray, q: np.ndarray) -> np.ndarray:
        """:meth:`inverse_jacobian` where the points of q are known too (a family may save its forward solve)."""
        return self.inverse_jacobian(q)

    def path_derivatives(self, points, q, t, kappa):
        """The joints' derivatives along a curve through ``points`` (N,3) mm, q = inverse(points)
        (N,J), with unit tangent t (N,3) and curvature vector kappa (N,3) 1/mm, by arc length:
        (q' (N,J) joint units/mm, q'' (N,J) joint units/mm^2).

        q' = Jinv t; q'' = (d Jinv/ds along t) t + Jinv kappa, the directional derivative by a
        central difference of FD_STEP mm (one-sided where a neighbour is out of reach). The
        families with a closed form override this; it stays the reference they are tested against."""
        jinv = self.inverse_jacobian_at(points, q)
        pp, pm = points + FD_STEP * t, points - FD_STEP * t
        jp = self.inverse_jacobian_at(pp, self.inverse(pp))
        jm = self.inverse_jacobian_at(pm, self.inverse(pm))
        djp, djm = (jp - jinv) / FD_STEP, (jinv - jm) / FD_STEP
        dj = np.where(np.isfinite(jp) & np.isfinite(jm), 0.5 * (djp + djm), np.where(np.isfinite(jp), djp, djm))
        dq = np.einsum("nij,nj->ni", jinv, t)
        ddq = np.einsum("nij,nj->ni", dj, t) + np.einsum("nij,nj->ni", jinv, kappa)
        return dq, ddq

    def scaled_path_derivatives(self, points, t, kappa, scale, out1, out2) -> int:
        """:meth:`path_derivatives` at points (N,3) mm along unit tangents t and curvature vectors
        kappa (N,3), in path units of ``scale`` mm: q' scale and q'' scale^2 written into out1 and
        out2 (N,J), or into the first J columns of (N, dof) arrays (the planner's, the filament's
        column after the joints' left alone: whole arrays keep a compiled family's kernel to one
        layout), with no (N,J) temporaries where a family fuses it (the rotary delta). Returns the
        index of the first point out of reach (its rows are NaN), -1 when all are reachable."""
        q = self.inverse(points)
        d1, d2 = self.path_derivatives(points, q, t, kappa)
        J = d1.shape[1]
        np.multiply(d1, scale, out=out1[:, :J])
        np.multiply(d2, scale * scale, out=out2[:, :J])
        with np.errstate(over="ignore"):
            if np.isfinite(q.sum()):  # one reduction: a NaN row makes the sum NaN
                return -1
        bad = ~np.all(np.isfinite(q), axis=1)
        out1[bad] = out2[bad] = np.nan
        return int(np.flatnonzero(bad)[0]) if bad.any() else -1

    def torque_coefficients(self, masses, points, q, dq, ddq):
        """The joint torques along a path as ``A sdd + B sd^2 + C`` (N m or N), (A, B, C) each
        (N,J), at points (N,3) mm with q = inverse(points), dq = dq/ds, ddq = d2q/ds2 (N,J): by
        default :func:`path_coefficients` of the family's ``inverse_dynamics`` (the reference a family's
        compiled form is tested against)."""
        return path_coefficients(lambda *x: self.inverse_dynamics(masses, *x), q, dq, ddq)

    def extra_ok(self, points: np.ndarray, q: np.ndarray) -> np.ndarray:
        """Family-specific limits beyond joint positions (default: none). (N,) bool."""
        return np.ones(len(points), dtype=bool)

    def within_joint_limits(self, q: np.ndarray, tol: float = JOINT_ROUNDOFF) -> np.ndarray:
        """q: (N,J) -> (N,) bool; NaN rows are outside."""
        q = np.atleast_2d(q)
        with np.errstate(invalid="ignore"):
            return np.all((q >= self.position_min - tol) & (q <= self.position_max + tol), axis=1)

    def _condition_of(self, jac: np.ndarray) -> np.ndarray:
        """(N,a,b) -> (N,) ratio of extreme singular values; inf where singular or NaN."""
        out = np.full(len(jac), np.inf)
        good = np.all(np.isfinite(jac), axis=(1, 2))
        if good.any():
            s = np.linalg.svd(jac[good], compute_uv=False)
            with np.errstate(divide="ignore"):
                out[good] = np.where(s[:, -1] > 0, s[:, 0] / s[:, -1], np.inf)
        return out

    def condition(self, q: np.ndarray) -> np.ndarray:
        """Condition number of the Jacobian (N,); inf at singular or unreachable poses.

        Columns are the joints, so for a revolute joint the scale is mm per rad; a
        large condition number means some direction needs much larger joint motion
        than another: the robot is near a singularity."""
        q = np.atleast_2d(q)
        out = np.full(len(q), np.inf)
        good = np.all(np.isfinite(q), axis=1)
        if good.any():
            out[good] = self._condition_of(self.jacobian(q[good]))
        return out

    def reachable(self, points: np.ndarray) -> np.ndarray:
        """points: (N,3) float, mm -> (N,) bool: the tool can stand there within every limit.
        Evaluated REACH_BLOCK points at a time (the Jacobians of a 1.5 M-move print would take
        most of a gigabyte at once)."""
        points = np.atleast_2d(np.asarray(points, dtype=float))
        if len(points) > REACH_BLOCK:
            return np.concatenate([self.reachable(points[i : i + REACH_BLOCK]) for i in range(0, len(points), REACH_BLOCK)])
        q = self.inverse(points)
        ok = np.all(np.isfinite(q), axis=1) & self.within_joint_limits(q)
        if ok.any():
            sub = np.flatnonzero(ok)
            ok[sub] &= self.extra_ok(points[sub], q[sub])
        if ok.any():
            sub = np.flatnonzero(ok)
            ok[sub] &= self.well_conditioned(points[sub], q[sub])
        return ok

    def well_conditioned(self, points: np.ndarray, q: np.ndarray) -> np.ndarray:
        """points (N,3) mm, q = inverse(points) (N,3) -> (N,) bool: ``condition(q) < singularity_limit``,
        the same decisions at a fraction of the SVD's cost. A bound decides most points:
        cond(J) = cond(J^-1) <= |J^-1|_F |J|_F, with J = adj(J^-1) / det(J^-1) in closed form from
        the inverse Jacobian (analytic for most families); only points whose bound is not below
        the limit (less than a millionth of margin) get the exact SVD. The inverse Jacobian is
        taken at q's own pose, as ``condition(q)`` takes the Jacobian (a rotary delta's forward
        solution; ``points`` may be the other root where the joints pass about -90 degrees)."""
        with np.errstate(over="ignore"):
            ok = self.condition_bound(q) * (1 + 1e-6) < self.singularity_limit
        rest = np.flatnonzero(~ok)
        if rest.size:
            ok[rest] = self.condition(q[rest]) < self.singularity_limit
        return ok

    def condition_bound(self, q: np.ndarray) -> np.ndarray:
        """q (N,3) -> (N,) an upper bound on ``condition(q)``: |J^-1|_F |J|_F with J = adj(J^-1) /
        det(J^-1) from the inverse Jacobian at q's own pose (inf or NaN where that is singular or
        out of reach: never below the limit, so :meth:`well_conditioned` asks the SVD there)."""
        ji = self.inverse_jacobian(q)
        adj = np.cross(ji[:, [1, 2, 0]], ji[:, [2, 0, 1]])  # row i: the cofactors of row i
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            det = np.einsum("ni,ni->n", ji[:, 0], adj[:, 0])
            return np.sqrt(np.einsum("nij,nij->n", ji, ji) * np.einsum("nij,nij->n", adj, adj)) / np.abs(det)


# -- dynamics ------------------------------------------------------------------------------------
# Every family models its moving parts as rigid bodies turning about a joint's fixed axis (an
# upper arm, a rotor) plus point masses whose positions follow from the joints (elbows, platforms,
# carriages, and each uniform rod as three points: m/6 at either end and 2m/3 at its middle, which
# gives a thin rod's kinetic energy m/6 (|v_a|^2 + v_a.v_b + |v_b|^2) and its centre of mass
# exactly, where the usual half-and-half split overstates its kinetic energy by m/12 |v_a - v_b|^2).
# d'Alembert over the point masses, tau = sum_k J_k^T m_k (a_k - g), with a_k = J_k qdd + Jdot_k qd
# from the closure equations, is then the exact rigid-body inverse dynamics of that model, velocity
# terms included.

GRAVITY = 9.80665  # m/s^2, standard gravity; the bed frame's z is up
MM = 1e-3  # m per mm: positions and Jacobians are in mm, the dynamics in SI (a revolute joint's
# Jacobian column times MM is m/rad, its torque N m; a prismatic one's is mm/mm, its force N)


def closure_motion(d, de, dde, qd, qdd):
    """Velocity Jacobian and acceleration of a point held by one rigid link per joint.

    Joint i moves its link's near end e_i(q_i) (a function of q_i alone); the link's far end is the
    point p (plus a constant) and keeps |d_i| constant, d_i = p + c_i - e_i. d: (N, J, k) links, mm;
    de, dde: (N, J, k) e_i's first and second derivatives in q_i (mm per joint unit, per unit^2);
    qd, qdd: (N, J) joint velocities and accelerations (units/s, units/s^2). Returns (jac (N, k, J)
    dp/dq in mm per unit, acc (N, k) mm/s^2); NaN where the links' matrix is singular.

    From d_i.(v - e_i' qd_i) = 0 and, differentiated, |v - e_i' qd_i|^2 + d_i.(a - e_i' qdd_i -
    e_i'' qd_i^2) = 0: D jac = diag(d_i.e_i') and D a = (d_i.e_i') qdd_i + (d_i.e_i'') qd_i^2 -
    |v - e_i' qd_i|^2, D with rows d_i."""
    g = np.einsum("njk,njk->nj", d, de)
    jac = solve_rows(d, g[:, :, None] * np.eye(d.shape[1])[None])
    v = np.einsum("nkj,nj->nk", jac, qd)
    rel = v[:, None, :] - de * qd[..., None]
    rhs = g * qdd + np.einsum("njk,njk->nj", d, dde) * qd**2 - np.einsum("njk,njk->nj", rel, rel)
    return jac, solve_rows(d, rhs[:, :, None])[..., 0]


def point_forces(mass, acc):
    """mass kg, acc (N, 3) mm/s^2 -> (N, 3) N: m (a - g), what d'Alembert loads a point mass with."""
    f = acc * MM
    f[:, 2] += GRAVITY
    return mass * f


def path_coefficients(dynamics, q, dq, ddq):
    """The torque along a path q(s) as ``tau = A sdd + B sd^2 + C``, the form of the planner's
    joint-acceleration constraint, from any inverse dynamics ``dynamics(q, qd, qdd)`` that is
    linear in qdd and quadratic in qd (a rigid-body model is: tau = M(q) qdd + c(q, qd) + g(q)).

    q, dq = dq/ds, ddq = d2q/ds2: (N, J). With qd = dq sd and qdd = dq sdd + ddq sd^2:
    A = M dq, B = M ddq + c(q, dq), C = g(q), evaluated as C = tau(q, 0, 0), A = tau(q, 0, dq) - C,
    B = tau(q, dq, ddq) - C. Returns (A, B, C), each (N, J) in the dynamics' units (N m or N)."""
    zero = np.zeros_like(np.asarray(q, dtype=float))
    c = dynamics(q, zero, zero)
    return dynamics(q, zero, dq) - c, dynamics(q, dq, ddq) - c, c
