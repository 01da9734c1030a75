"""Torque (force) limits along a run: the planner's rows and the stage-wise check (issue 56).

Along a path the joint torques are ``tau = A(s) u + B(s) x + C(s)`` (u the path acceleration, x the
squared path speed; ``Printer.torque_path_coefficients``), the form of the acceleration rows, so a
torque limit is two more rows per joint and evaluation fraction of every stage:

* **plain**: ``-T - C <= A u + B x <= T - C``, T the planned stall torque (the stall torque less
  its ``limit_margin``: ``Printer.planned_actuators``). Braking, a motor gives its stall torque at most.
* **driving**: while the motor drives (torque and joint speed of one sign, sigma = sign q'), the
  speed-torque curve caps the torque: ``sigma tau <= T (1 - |q'| sd / w)`` with w the speed where
  the curve's safe line reaches zero (``ActuatorCurves.line_speed``: the no-load speed for a
  linear curve, less for a stepper's pull-out curve). sd = sqrt(x) is not linear in x; sqrt is
  concave, so its tangent at any x0 > 0 lies above it, ``sqrt(x) <= (x + x0) / (2 sqrt(x0))``, and
  the row with the tangent in place of sd is stricter than the curve everywhere (safe) and exact at
  x0. x0 is one per stage (so the linearised use is nearly linear along it, and holding it at the
  fractions holds it between them), first the speed at its middle at which the motors hold the
  path at u = 0 (:func:`cruise_x`, capped by the velocity limits and the feed), then the previous
  solve's x there: each pass keeps the last one's profile feasible (the tangent is exact there) and
  moves closer to the curve (``TORQUE_PASSES``).

The driving row's lower bound ``-T - sigma C`` is implied by the plain row (the tangent term is
never negative), and the plain row's upper bound by the driving one, so the rows carry one side
each (the other infinite: the solver pairs half as many lines) and the pair is exactly the
two-sided limit with the linearised curve. After solving, :func:`stage_check` bounds every joint's
use of its curve over each whole stage with the exact torque (five points per stage, both sides of
a join from each stage's own piece, plus a second-difference bound between them), against the
real stall torque and line: a stage beyond it is refined, as for the acceleration limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..jit import njit

# Solves per grid with the driving rows' tangent moved to the last solution: on the ETITC's
# calibration cube a second solve gains 0.6 % (machine mode), a third nothing (to 1e-4).
TORQUE_PASSES = 2
X0_FLOOR = 1e-6  # of the line's own x at a stage: a tangent point at rest would make its row vertical


@dataclass(frozen=True)
class TorqueLimits:
    """The actuators' limits a plan keeps to. planned: (J,) stall torque or force less the
    margin (N m or N); stall: (J,) the real one (the check's); line_speed: (J,) joint units/s where
    the safe line under the speed-torque curve reaches zero (rad/s or mm/s)."""

    planned: np.ndarray
    stall: np.ndarray
    line_speed: np.ndarray


def torque_limits(printer) -> TorqueLimits | None:
    """The printer's torque limits, or None where it has no ``[dynamics]`` or its ``[planning]
    torque_limit`` is off (the joints' constant acceleration limits alone then)."""
    if printer.dynamics is None or printer.planning.torque_limit != "on":
        return None
    act, planned = printer.dynamics.actuators, printer.planned_actuators()
    return TorqueLimits(np.array(planned.stall, dtype=float), np.array(act.stall, dtype=float),
                        np.array(act.line_speed(), dtype=float))


@dataclass(frozen=True)
class StageTorque:
    """The torque coefficients at fractions ``frac`` (f,) of every stage of a grid (each with the
    piece the stage lies in): A, B, C (n, f, J) in the path's units (N m or N per path unit/s^2,
    per (path unit/s)^2, and N m or N); dq (n, f, J) the joints' q' (joint units per path unit),
    contiguous, so the kernels reading it see one layout (and compile once) with or without a filament."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    dq: np.ndarray


def stage_torque(printer, rp, x_grid: np.ndarray, frac: np.ndarray, dq: np.ndarray, ddq: np.ndarray,
                 block: int = 32768) -> StageTorque:
    """:class:`StageTorque` of a RunPath ``rp`` on grid x_grid (n+1,) at fractions frac (f,), from
    the stage derivatives dq, ddq (n, f, dof) it gave (``rp.stage_derivatives(x_grid, frac)``);
    the tool tips and joints at the same points by the path's frames and the inverse kinematics,
    ``block`` points at a time (bounded memory on a long window). Where frac runs from 0 to 1, a
    stage's end is the next stage's start when both lie in one piece (the same point, q' and q''):
    its coefficients are computed once, for the next stage, and copied; the fractions before the
    end are computed for every stage (contiguous slices, no masks), the ends only where not shared."""
    path, J = rp.path, rp.kin.n_joints
    s = np.asarray(x_grid, float) * rp.S
    ds = np.diff(s)
    owner = path.locate(0.5 * (s[:-1] + s[1:]))
    n, f = len(ds), len(frac)
    out = np.empty((3, n, f, J))
    inner = f - 1 if f > 1 and frac[0] == 0.0 and frac[-1] == 1.0 else f
    per = max(1, block // max(inner, 1))
    for a in range(0, n, per):
        b = min(a + per, n)
        coef = _coefficients(printer, rp, s[a:b], ds[a:b], frac[:inner], owner[a:b], dq[a:b, :inner, :J],
                             ddq[a:b, :inner, :J])
        for k in range(3):
            out[k, a:b, :inner] = coef[k].reshape(b - a, inner, J)
    if inner < f and n:
        _share_ends(out, owner)
        alone = np.flatnonzero(np.append(owner[:-1] != owner[1:], True))
        for a in range(0, len(alone), block):
            idx = alone[a: a + block]
            coef = _coefficients(printer, rp, s[idx], ds[idx], frac[-1:], owner[idx], dq[idx, -1:, :J],
                                 ddq[idx, -1:, :J])
            for k in range(3):
                out[k, idx, -1] = coef[k]
    # q' contiguous like the others: the kernels reading the model compile for one layout
    return StageTorque(out[0], out[1], out[2], np.ascontiguousarray(dq[..., :J]))


@njit
def _share_ends(out, owner):
    """out (3, n, f, J): each stage's last fraction from the next stage's first where both lie in
    one piece (owner (n,)), in one pass (numpy's fancy indexing copied through temporaries)."""
    _k, n, f, J = out.shape
    for i in range(n - 1):
        if owner[i] == owner[i + 1]:
            for k in range(3):
                for j in range(J):
                    out[k, i, f - 1, j] = out[k, i + 1, 0, j]


def _coefficients(printer, rp, s, ds, frac, owner, dq, ddq):
    """The torque coefficients (A, B, C), each (m f, J), at fractions frac (f,) of the m stages
    starting at s (m,) mm, of lengths ds (m,), in pieces owner (m,); dq, ddq (m, f, J)."""
    J = dq.shape[-1]
    p = rp.path.stage_frame(s, ds, frac, owner)[0]
    return printer.torque_path_coefficients(rp.kin.inverse(p), dq.reshape(-1, J), ddq.reshape(-1, J), p)


def cruise_x(model: StageTorque, limits: TorqueLimits, vmax: np.ndarray, feed2: np.ndarray, mid: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """(first tangent points, their floors), (n,) each, one per stage, at its middle (the model's
    fraction ``mid``): the squared path speed at which every motor holds the path at u = 0 on its
    safe line, ``sigma (B x + C) + T |q'| sqrt(x) / w = T``, capped by the joints' velocity limits
    vmax (J,) and the stage's feed cap feed2 (n,) (squared path speed); the floor, X0_FLOOR of the
    line's own speed there ((T - sigma C) / (T |q'| / w)), keeps a tangent point off zero. From the
    stage's own values only: a batch of runs gets the tangents each run gets alone."""
    n, J = model.B.shape[0], model.B.shape[2]
    x, floor = np.empty(n), np.empty(n)
    _cruise_kernel(model.B, model.C, model.dq, mid, np.asarray(limits.planned, float),
                   np.asarray(limits.line_speed, float), np.asarray(vmax, float)[:J],
                   np.ascontiguousarray(feed2, dtype=float), x, floor)
    return x, floor


@njit
def _cruise_kernel(B, C, dq, mid, T, w, vmax, feed2, x, floor):
    """:func:`cruise_x` in one pass (numpy's NaN rules: a NaN q' makes the velocity cap NaN and the
    tangent point 1). Per joint at the stage's middle, sigma = sign q', kk = T |q'| / w:
    qa y^2 + kk y + qc <= 0 with qa = sigma B, qc = sigma C - T; y its positive root (the linear
    one, -qc / kk, where qa is about 0), infinite where none."""
    n, _f, J = B.shape
    for i in range(n):
        ymin = np.inf
        line = np.inf
        vcap = np.inf
        for j in range(J):
            qp = dq[i, mid, j]
            sg = 1.0 if qp >= 0 else -1.0
            k = T[j] * abs(qp) / w[j]
            qa, qc = sg * B[i, mid, j], sg * C[i, mid, j] - T[j]
            r = k * k - 4 * qa * qc
            disc = math.sqrt(r if r != r or r > 0.0 else 0.0)
            lin = -qc / k  # numpy's error model: inf or NaN where kk = 0
            if qa > 1e-12 * (k + 1.0):
                y = (-k + disc) / (2 * qa)
            else:
                y = lin
            if math.isfinite(y) and y > 0:
                ymin = min(ymin, y)
            if math.isfinite(lin) and lin > 0:
                line = min(line, lin)
            c = vmax[j] / abs(qp)
            if vcap == vcap:
                vcap = c if c != c else min(vcap, c)
        line = line * line
        # no joint moves along the stage (kk = 0 for all): no tangent term, any positive point serves
        fl = X0_FLOOR * (line if math.isfinite(line) else 1.0)
        v = ymin * ymin
        vc = vcap * vcap
        v = vc if vc != vc else min(v, vc)
        v = feed2[i] if feed2[i] != feed2[i] else (v if v != v else min(v, feed2[i]))
        v = v if math.isfinite(v) else 1.0
        x[i] = max(v, fl)
        floor[i] = fl


def torque_rows(model: StageTorque, limits: TorqueLimits, x_grid: np.ndarray, x0: np.ndarray, eval_at,
                frac: np.ndarray, unit: np.ndarray | None = None, out=None, driving_only: bool = False):
    """The torque rows of every grid point, in the compiled solver's collocation form (stage i's rows
    in its start's (u, x_i)): (a, b, lo, hi), each (n+1, 2 f J), at the fractions frac (f,) (the
    model's fractions eval_at: a slice or indices), plain then driving rows, fraction-major.
    x0: (n,) each stage's tangent point (> 0); the last grid point's rows take the last stage's. unit: as StageAccelerationConstraint.rows (a / c, b / c^2; bounds unchanged). The last
    grid point has no stage ahead: its rows are the last stage's end's with no u term of its own
    (the solver never uses them). out: (a, b, lo, hi) arrays (n+1, 2 f J) to write them into
    (views of wider ones: a solve's full rows), returned. driving_only: only the driving rows are
    written (the plain ones do not depend on x0: a later pass leaves out's as they are)."""
    n, nf, J = model.A.shape
    ev = np.ascontiguousarray(np.arange(nf)[eval_at])
    c = np.ones(n + 1) if unit is None else np.asarray(unit, dtype=float)
    m = 2 * len(ev) * J
    a, b, lo, hi = (np.empty((n + 1, m)) for _ in range(4)) if out is None else out
    _torque_rows_kernel(model.A, model.B, model.C, model.dq, ev, np.asarray(frac, float), np.diff(x_grid),
                        np.ascontiguousarray(x0, dtype=float), limits.planned, limits.line_speed, c, bool(driving_only),
                        a, b, lo, hi)
    return a, b, lo, hi


@njit
def _torque_rows_kernel(A, B, C, dq, ev, frac, d, x0, T, w, unit, driving_only, a, b, lo, hi):
    """:func:`torque_rows` in one pass, reading the model's coefficients at its fractions ev (f,)
    in place. Row i < n at fraction f_k: x(f) = x_i + 2 f d_i u, so the plain row is
    (A + 2 f d B) u + B x_i in [-T - C, T - C] and the driving one (sigma = sign q', kk = T |q'| / w,
    the tangent's slope kp = kk / (2 sqrt(x0_f)), x0_f the stage's tangent point: one for the
    stage, so the linearised torque use is nearly linear in f and holding it at the fractions holds
    it between them, which sqrt(x) itself, concave, would not)
    (sigma A + 2 f d (sigma B + kp)) u + (sigma B + kp) x_i <= T - sigma C - kk sqrt(x0_f) / 2. Each
    row is one-sided (the other bound infinite): the plain row keeps the braking side, sigma tau >= -T."""
    n = A.shape[0]
    J = A.shape[2]
    f = len(ev)
    for i in range(n + 1):
        st = i if i < n else n - 1
        cc = unit[i]
        for k in range(f):
            fr = frac[k] if i < n else 1.0
            w2 = 2.0 * fr * d[st] if i < n else 0.0
            x0f = x0[st]
            sq = np.sqrt(x0f)
            e = ev[k] if i < n else ev[f - 1]
            for j in range(J):
                Aj, Bj, Cj, qp = A[st, e, j], B[st, e, j], C[st, e, j], dq[st, e, j]
                sg = 1.0 if qp >= 0.0 else -1.0
                kk = T[j] * abs(qp) / w[j]
                kp = kk / (2.0 * sq)
                col = k * J + j
                if not driving_only:
                    a[i, col] = (Aj + w2 * Bj) / cc
                    b[i, col] = Bj / (cc * cc)
                    # one-sided (the solver pairs half as many lines): the plain row's driving side and
                    # the driving row's braking side are implied by the other row wherever x >= 0
                    lo[i, col] = -T[j] - Cj if sg > 0.0 else -np.inf
                    hi[i, col] = np.inf if sg > 0.0 else T[j] - Cj
                col += f * J
                bd = sg * Bj + kp
                a[i, col] = (sg * Aj + w2 * bd) / cc
                b[i, col] = bd / (cc * cc)
                lo[i, col] = -np.inf
                hi[i, col] = T[j] - sg * Cj - 0.5 * kk * sq


@dataclass(frozen=True)
class TorqueCheck:
    """Stage-wise torque use of a solution: use (J,) the largest over the stages of each joint's
    (|tau| + [driving] stall |qd| / w) / stall (1: on its stall torque or its safe line), stage
    (J,) where; per_stage (n,) the largest of any joint in each stage."""

    use: np.ndarray
    stage: np.ndarray
    per_stage: np.ndarray


def stage_check(model: StageTorque, limits: TorqueLimits, frac: np.ndarray, sd: np.ndarray, xdd: np.ndarray,
                x0: np.ndarray | None = None) -> TorqueCheck:
    """Bound every joint's torque use over every stage of a solution sd (n+1,) path speeds, xdd (n,)
    path accelerations (the model's path units) at the model's fractions frac (f,) with the exact
    torque and joint speed: the largest sample plus 0.3125 of the largest second difference of the
    samples, as :func:`.topp.stage_maxima` bounds the accelerations, against the real stall torque
    and line (not the margined ones); or, where smaller, the same bound with sqrt(x) replaced by its
    tangent at x0 (n,) (the rows' tangent points; default: the solution's x at each stage's middle)."""
    x0 = 0.5 * (sd[:-1] ** 2 + sd[1:] ** 2) if x0 is None else np.asarray(x0, dtype=float)
    n, f, J = model.A.shape
    use = np.empty(J)
    at = np.empty(J, dtype=np.int64)
    per_stage = np.empty(n)
    _check_kernel(model.A, model.B, model.C, model.dq, np.asarray(frac, float), np.ascontiguousarray(sd, dtype=float),
                  np.ascontiguousarray(xdd, dtype=float), np.ascontiguousarray(x0), limits.stall, limits.line_speed,
                  use, at, per_stage)
    return TorqueCheck(use, at, per_stage)


@njit
def _check_kernel(A, B, C, dq, frac, sd, xdd, x0s, T, w, use, at, per_stage):
    """:func:`stage_check`: at fraction f of stage i, x = max(0, x_i + (x_{i+1} - x_i) f), tau =
    A u + B x + C, qd = q' sqrt(x), g = (|tau| + [tau qd > 0] T |qd| / w) / T; per stage and joint
    the largest g plus 0.3125 of the largest second difference (a NaN anywhere wins). sqrt(x) is
    steep near rest, which makes that allowance large on a stage that starts or ends there; the
    same bound of g with sqrt(x) replaced by its tangent at xm = x0s[i] (above it, and linear in f:
    what the rows held), is then the tighter one: the smaller of the two is taken."""
    n, f, J = A.shape
    g = np.empty(f)
    h = np.empty(f)
    xs = np.empty(f)
    rs = np.empty(f)
    for j in range(J):
        use[j] = -np.inf
        at[j] = 0
    for i in range(n):
        x0 = sd[i] * sd[i]
        x1 = sd[i + 1] * sd[i + 1]
        u = xdd[i]
        xm = max(x0s[i], 0.0)
        sm = np.sqrt(xm)
        worst = -np.inf
        for m in range(f):  # the path speed at each fraction, once for every joint
            xs[m] = max(x0 + (x1 - x0) * frac[m], 0.0)
            rs[m] = np.sqrt(xs[m])
        for j in range(J):
            nan = False
            for m in range(f):
                x = xs[m]
                tau = A[i, m, j] * u + B[i, m, j] * x + C[i, m, j]
                qd = dq[i, m, j] * rs[m]
                v = abs(tau)
                t = abs(tau)
                if tau * qd > 0.0:
                    v += T[j] * abs(qd) / w[j]
                # the tangent's term wherever the torque has q''s sign, as in the rows: at rest too,
                # where it is not zero (the tangent lies above sqrt(0))
                if tau * dq[i, m, j] > 0.0 and sm > 0.0:
                    t += T[j] * abs(dq[i, m, j]) * (x + xm) / (2.0 * sm) / w[j]
                g[m] = v / T[j]
                h[m] = t / T[j]
                nan |= g[m] != g[m]
            top = _bound(g, f)
            if sm > 0.0:
                top = min(top, _bound(h, f))
            top = np.nan if nan else top
            if worst == worst and (top != top or top > worst):
                worst = top
            if use[j] == use[j] and (top != top or top > use[j]):
                use[j] = top
                at[j] = i
        per_stage[i] = worst


@njit
def _bound(g, f):
    """The largest of g[:f] plus 0.3125 of its largest second difference."""
    top = g[0]
    for m in range(1, f):
        top = g[m] if g[m] > top else top
    dd = 0.0
    for m in range(f - 2):
        v = abs(g[m + 2] - 2.0 * g[m + 1] + g[m])
        dd = v if v > dd else dd
    return top + 0.3125 * dd


def torque_columns(frac, n_joints: int) -> int:
    """How many rows (columns of the solver's arrays) :func:`torque_rows` gives a grid point at
    the fractions frac: a plain and a driving row per joint and fraction."""
    return 2 * len(frac) * n_joints


def solve_with_torque(model: StageTorque, limits: TorqueLimits, x_grid: np.ndarray, rows, eval_at, frac: np.ndarray,
                      x0: np.ndarray, floor: np.ndarray, speeds, unit: np.ndarray | None = None):
    """The compiled solver's profile under the acceleration rows and the torque rows together.

    rows: (a, b, bound, cap2), the acceleration rows (``solver._fast_rows``) in the first
    len(bound) columns of a, b, which have :func:`torque_columns` more for the torque rows
    (written here: the others are not copied); eval_at, frac: the model's fractions the rows are
    taken at (a slice of them) and their values; x0 (n+1,) the first tangent points, one per
    stage, floor (n,) the least ones (:func:`cruise_x`); speeds: rows -> (sd (n+1,) or None, top),
    the solve (``topp._speeds`` with the caller's grid, start and units). TORQUE_PASSES solves,
    each with the driving rows' tangent at the last solution (always as many, and every choice from
    a point's own values: a batch of runs is planned as each alone would be); a later pass
    rewrites only the driving rows. Returns (sd, top, x0) of the fastest, x0 its driving rows'
    tangent points (sd None where the first finds no profile)."""
    a, b, bound, cap2 = rows
    n1, m = a.shape
    m0 = len(bound)
    if m != m0 + torque_columns(frac, model.A.shape[2]):
        raise ValueError(f"rows: {m} columns, expected {m0} and {torque_columns(frac, model.A.shape[2])} for torque")
    lo, hi = np.empty((n1, m)), np.empty((n1, m))  # the acceleration rows' bounds, then the torque rows'
    lo[:, :m0], hi[:, :m0] = -np.asarray(bound, float), bound
    tail = tuple(v[:, m0:] for v in (a, b, lo, hi))
    best = (None, None, x0)
    for k in range(TORQUE_PASSES):
        torque_rows(model, limits, x_grid, x0, eval_at, frac, unit, tail, driving_only=k > 0)
        sd, top = speeds((a, b, (lo, hi), cap2))
        if sd is None:
            break
        best = (sd, top, x0)
        x0 = np.maximum(0.5 * (sd[:-1] ** 2 + sd[1:] ** 2), floor)  # x at each stage's middle
    return best


# Joint-space travels (ruckig) have no torque model: each keeps to a joint velocity and acceleration
# that none of its poses can turn into more torque than the actuators give.
TRAVEL_SPEED_FRACTIONS = np.linspace(0.05, 0.8, 16)  # of the line speed: the velocity bounds tried
TRAVEL_LINE = np.linspace(0.0, 1.0, 9)  # fractions of the straight joint line between the ends


def travel_limits(ctx, q0, q1):
    """Joint velocity and acceleration bounds for ruckig's rest-to-rest moves q0 -> q1 (k, J) joint
    units, under the plan context ctx's torque and planned limits (its ``dynamics`` the model): (velocity (k, J), acceleration (k, J)) per s and s^2, NaN rows where no bound works;
    None without torque limits. At the move's poses P (its straight joint line at TRAVEL_LINE: the
    travel planner has ruckig synchronise the joints' phases, which keeps a rest-to-rest move on
    that line) and for any joint state with |qd_k| <= v_k, |qdd_k| <= a_k:

        |g_j| + sum_kl |G_jkl| v_k v_l + sum_k |M_jk| a_k + T_j v_j / w_j <= T_j

    (M the mass matrix, G the velocity terms' quadratic form, g gravity, from the family's inverse
    dynamics; T the planned stall, w the line speed): the torque plus the line's speed term, so the
    motor stays within its stall torque and its speed-torque line whatever ruckig does inside the
    bounds (at the sampled poses: between them the model is smooth and the margin covers it).
    v = fraction x w with the fraction (TRAVEL_SPEED_FRACTIONS) that gives the move's shortest
    trapezoid; a the joints' planned accelerations times the one scale the bound allows; neither
    above the joints' own planned limits."""
    tq = ctx.torque
    if tq is None:
        return None
    q0, q1 = np.atleast_2d(np.asarray(q0, float)), np.atleast_2d(np.asarray(q1, float))
    k, J = q0.shape
    lim = ctx.planned_limits
    vj, aj = lim.velocity[:J], lim.acceleration[:J]
    poses = q0[:, None] + TRAVEL_LINE[None, :, None] * (q1 - q0)[:, None]  # (k, P, J)
    P = poses.shape[1]
    M, G, g = _pose_dynamics(ctx.dynamics, poses.reshape(-1, J))
    M, G, g = M.reshape(k, P, J, J), G.reshape(k, P, J, J, J), g.reshape(k, P, J)
    v = np.minimum(TRAVEL_SPEED_FRACTIONS[:, None] * tq.line_speed[None], vj[None])  # (F, J)
    Gv = np.einsum("kpjab,fa,fb->fkpj", np.abs(G), v, v)
    room = tq.planned - np.abs(g)[None] - Gv - (tq.planned * v / tq.line_speed)[:, None, None]
    need = np.einsum("kpjm,m->kpj", np.abs(M), aj)[None]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(need > 0, room / need, np.where(room >= 0, np.inf, -np.inf))
        ratio = np.where(np.isnan(ratio), -np.inf, ratio)  # a pose the model has no torque at: no bound
        scale = np.minimum(np.min(ratio.reshape(len(v), k, -1), axis=2, initial=np.inf), 1.0)  # (F, k)
        a = aj[None, None] * scale[..., None]  # (F, k, J)
        dist = np.abs(q1 - q0)[None]
        vv = v[:, None]
        t = np.where(dist * a > vv * vv, dist / vv + vv / a, 2 * np.sqrt(dist / a))
        t = np.where(dist > 0, t, 0.0).max(axis=2)
    t = np.where(scale > 0, t, np.inf)
    best = np.argmin(t, axis=0)
    ok = np.isfinite(t[best, np.arange(k)])
    vel = np.where(ok[:, None], v[best], np.nan)
    acc = np.where(ok[:, None], a[best, np.arange(k)], np.nan)
    return vel, acc


def _pose_dynamics(printer, q):
    """At poses q (P, J): M (P, J, J) the mass matrix, G (P, J, J, J) the velocity terms' symmetric
    quadratic form (tau_j = sum_kl G_jkl qd_k qd_l), g (P, J) gravity (N m or N; NaN rows where the
    model has none), by the family's inverse dynamics at unit and paired joint rates."""
    P, J = q.shape
    eye = np.eye(J)
    zero = np.zeros_like(q)
    tau = printer.joint_torques
    g = tau(q, zero, zero)
    M = np.stack([tau(q, zero, np.broadcast_to(eye[m], q.shape)) - g for m in range(J)], axis=2)
    single = [tau(q, np.broadcast_to(eye[m], q.shape), zero) - g for m in range(J)]
    G = np.empty((P, J, J, J))
    for a in range(J):
        G[:, :, a, a] = single[a]
        for b in range(a + 1, J):
            both = tau(q, np.broadcast_to(eye[a] + eye[b], q.shape), zero) - g
            G[:, :, a, b] = G[:, :, b, a] = 0.5 * (both - single[a] - single[b])
    return M, G, g
