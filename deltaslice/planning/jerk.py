"""Jerk limits on runs and straight travels (``[planning] jerk_limit = "on"``): a re-timing of a
planned RunPiece under its time-optimal (TOPP-RA) speed profile, the path kept.

The TOPP-RA profile keeps the path acceleration u constant per stage and switches it bang-bang,
so each joint's acceleration ``a = q' u + q'' x_dot^2`` steps between stages (and where the path's
curvature steps, at the joins of blend arcs and lines). Here the run is re-timed on a grid of
stages at most ``STAGE`` long on that profile (:func:`fine_grid`), by linear programs over
x = x_dot^2 at the grid points (:func:`solve_grid`, scipy's HiGHS):

* x <= x*, the TOPP-RA profile's (so every speed cap holds: x is linear in the path parameter in
  a stage, and the grid refines TOPP-RA's);
* each channel's acceleration within its planned limit at both ends of every stage;
* each channel's acceleration step at every grid point within SPLIT of the jerk budget of the time
  around it (half of each stage beside it; from rest outside the run) and within J SLACK / 2, and
  its change inside every stage within the rest (:func:`_jerk_rows`): the budget is J dt, J the
  planned jerk times :func:`window_factor`, dt the tangent plane of the stage's duration
  (:func:`stage_time_tangent`) at x* for the first pass, then at the last solution, x within a
  trust region of GROW around it (a convex-concave procedure): the duration is convex in x, so the
  tangent is below it everywhere and every solution keeps its budgets at its true durations;
* maximise the sum of x weighted by dT/dx at the tangent's point; a pass is kept if it shortens the
  run (else the trust region shrinks), none after one that gains less than CONVERGED; HiGHS's
  feasibility tolerance at 1e-10 (at 1e-7 the rows near rest read up to 10x their budget).

The unknowns are x over its upper bound (near rest x is 1e-7 of its largest, within HiGHS's
tolerances). Stages the solution makes longer than LONG * STAGE are cut again into stages of at
most CUT * STAGE (:func:`split_long`) and the programs run again from it (REGRIDS).

Guarantee (checked on the result, :func:`jerk_check`, between the ``CHECK`` points of every
stage): where each channel's acceleration has a total variation of at most ``R (|I| + E)`` over
every interval I, a third difference of the positions over a spacing h reads at most ``R (1 +
0.75 E / h)`` (the quadratic B-spline it weights the jerk with peaks at 0.75 / h); the check
measures E, the largest excess over ``R |I|``, for each of the RATES R and keeps the least bound,
which must be within the jerk limit for every channel over JERK_SPACING (or longer). The planned
rate J_p allows for an excess of PLAN_SLACK, far less than the steps' caps allow and about what the
programs' solutions show. Where the check fails (a larger excess, the velocity or acceleration
between fractions, or the actuators' torque where the solver plans it), the run is slowed
uniformly in time (velocity x s, acceleration x s^2, jerk about s^3) until it holds.

Long runs planned window by window (their pieces join at speed) are left as planned.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..errors import PlanningError
from ..machine.limits import JERK_SPACING
from .pieces import RunPiece
from .constraints import CHECK
from .context import PlanContext
from .runpath import RunPath
from .stages import CHECK_TOLERANCE, stage_maxima
from .torque import stage_check, stage_torque

STAGE = 1e-3  # s: longest stage of the re-timing grid on the TOPP-RA profile
PASSES = 6  # linear programs at most (2 planned the star 2-10 % slower), each around the last solution
GROW = 2.0  # trust region of the passes after the first: x within this factor of the last solution's
CONVERGED = 0.005  # and none after one that shortens the run by less than this fraction
LIFT = 0.01  # plus this fraction of x* (so a point at rest can start again)
LONG_STAGE = 1.0  # s: the budget of a stage at rest at both ends (none is, in a solution)
REGRIDS = 1  # times the stages a solution makes longer than LONG * STAGE are cut and the programs run again
REGRID_PASSES = 6  # linear programs after each cut
LONG = 1.5  # of STAGE: a stage this long is cut (REGRIDS)
CUT = 1.25  # of STAGE: into stages at most this long (1: a 2x larger grid, no faster run)
SPLIT = 0.9  # of a stage's jerk budget, for the steps at its ends; the rest for the change inside it
# the planned slack: the programs hold a grid-aligned interval's variation within J (|I| + SLACK),
# every step within J SLACK / 2 (a stage's step budget, at most LONG STAGE long)
SLACK = SPLIT * LONG * STAGE
# the slack the planned rate allows for (window_factor): the steps' excess the check measures is
# far less than SLACK (0.3-0.6 ms planned the star 1-2 % faster than SLACK; the check holds it)
PLAN_SLACK = 0.3e-3
RATES = np.geomspace(0.5, 1.0, 16)  # of jerk_max: the rates J_r the check tries (the least bound kept)
SLOW_PASSES = 20  # uniform slow-downs tried before a run's check holds (the first usually does)
TORQUE_AIM = 1e-4  # below the torque limit: where a secant slow-down aims (_torque_step)
REST_POINTS = 40  # grid points added on each side of a point at rest (fine_grid)
MIN_STAGE = 1e-6  # mm: grid points closer than this are one
FLOOR = 1e-3  # of the largest x*: the least x_dot^2 a point's weight is taken at
ACTIVE = 0.95  # a row counts as active within 5 % of its bound (the piece's active_time)


def window_factor(stage: float | None = None, spacing: float = JERK_SPACING) -> float:
    """The fraction of the jerk limit planned to: a third difference over ``spacing`` of a motion
    whose acceleration varies by at most J (|I| + stage) over every interval I is at most J (1 +
    0.75 stage / spacing) (0.75 h^2: the peak of the quadratic B-spline the third difference
    weights the jerk with). Default: PLAN_SLACK."""
    return 1.0 / (1.0 + 0.75 * (PLAN_SLACK if stage is None else stage) / spacing)


def jerk_limited(ctx: PlanContext, pieces: list) -> list:
    """The pieces with every RunPiece from rest to rest re-timed within the jerk limits (as they
    are with ``[planning] jerk_limit = "off"``, or where no channel has a jerk limit)."""
    if not ctx.jerk_limit:
        return pieces
    return [limit_run(ctx, p) if isinstance(p, RunPiece) else p for p in pieces]


def _channels(ctx: PlanContext, piece: RunPiece):
    """(e_ratio or None, planned limits, true limits) of the channels a run moves."""
    e_ratio = piece.e_ratio if len(piece.e_ratio) and np.any(piece.e_ratio != 0) else None
    planned, true = ctx.planned_limits, ctx.machine_limits
    c = true.n_channels if e_ratio is not None else true.n_joints
    return e_ratio, planned, true, c


def limit_run(ctx: PlanContext, piece: RunPiece) -> RunPiece:
    """One RunPiece re-timed within the jerk limits (module docstring); unchanged where it does
    not start and end at rest or no channel it moves has a jerk limit."""
    if len(piece.xdd) == 0 or piece.xd[0] != 0 or piece.xd[-1] != 0:
        return piece
    e_ratio, planned, true, c = _channels(ctx, piece)
    jerk = planned.jerk[:c] * window_factor()
    if not np.any(np.isfinite(jerk)):
        return piece
    rp = RunPath(ctx.kin, piece.path, e_ratio, piece.layer)
    with np.errstate(divide="ignore"):
        path_jerk = float(np.min(jerk / np.abs(rp.stage_derivatives(piece.x, np.array([0.5]))[0][:, 0]).max(axis=0)))
    x, env = fine_grid(piece, path_jerk)
    y, best = None, None
    for regrid in range(REGRIDS + 1):
        dq, ddq = rp.stage_derivatives(x, np.array([0.0, 1.0]))
        y = solve_grid(x, env, dq, ddq, planned.acceleration[:c], jerk, y, PASSES if regrid == 0 else REGRID_PASSES)
        found = _checked(ctx, rp, x, y, true.velocity[:c], true.acceleration[:c], true.jerk[:c], np.isfinite(jerk))
        if found is not None and (best is None or found[3][-1] < best[3][-1]):
            best = found
        xd, xdd, t = profile(x, y)
        dt = np.diff(t)
        # where the solution is much slower than TOPP-RA its stages are long: the window factor
        # falls with them (the check slows the run), so they are cut again (kept if faster)
        if regrid == REGRIDS or not np.any(dt > LONG * STAGE):
            break
        x, y = split_long(x, xd, xdd, dt, MIN_STAGE / piece.S)
        env = envelope(piece, x)
    if best is None:  # never seen: solve_grid keeps a profile whose stages end, and slowing holds
        start = piece.path.evaluate(np.array([0.0]))[0]
        raise PlanningError(
            f"layer {piece.layer}: the jerk limits could not be held on the run from x = {start[0]:.2f}, "
            f"y = {start[1]:.2f}, z = {start[2]:.2f} mm (re-timed and slowed {SLOW_PASSES} times); "
            "[planning] jerk_limit = \"off\" plans it without them")
    x, xd, xdd, t, use = best
    env = envelope(piece, x)
    active = use.max(axis=1) >= ACTIVE
    active |= (xd[:-1] ** 2 >= ACTIVE * env[:-1]) & (env[:-1] > 0)
    return replace(piece, x=x, xd=xd, xdd=xdd, t=t, active_time=float(np.diff(t)[active].sum()))


def _checked(ctx: PlanContext, rp, x, y, vmax, amax, jmax, limited):
    """The profile x_dot^2 = y on the grid x checked against the true limits vmax, amax, jmax (dof,)
    (``limited``: the channels with a jerk limit) and, where the solver plans torque, the actuators'
    torque (:func:`.torque.stage_check`), and slowed uniformly until every check holds: (x, x_dot,
    path acceleration, t, jerk use (N, dof)), or None where a stage never ends or SLOW_PASSES
    slow-downs leave a check failing."""
    xd, xdd, t = profile(x, y)
    dq_c, ddq_c = rp.stage_derivatives(x, CHECK)
    vel = stage_maxima(rp, x, xd, xdd, vmax, amax, stage=(dq_c, ddq_c))
    worst_v, worst_a = float(np.max(vel.velocity)), float(np.max(vel.acceleration))
    slow = min(1.0, 1.0 / max(worst_v, 1e-12), 1.0 / math.sqrt(max(worst_a, 1e-12)))
    model = stage_torque(ctx.dynamics, rp, x, CHECK, dq_c, ddq_c) if ctx.plans_torque else None
    last = None  # (slow^2, worst torque use) of the last try
    for _ in range(SLOW_PASSES):
        # slowed by s, the velocity scales by s, the acceleration by s^2, the jerk by s^3 (the
        # window factor, at longer stages, a little less: so again until the check holds); the
        # torque's inertial and speed terms by s^2, gravity not at all (so again until it holds)
        use = jerk_check(dq_c, ddq_c, x, xd * slow, xdd * slow * slow, t / slow, jmax)
        use[:, ~limited] = 0.0
        if not np.all(np.isfinite(use)):
            return None
        worst_j = float(np.max(use))
        worst_t = 0.0 if model is None else float(np.max(stage_check(model, ctx.torque, CHECK, xd * slow,
                                                                     xdd * slow * slow).use))
        if worst_j <= 1.0 + CHECK_TOLERANCE and worst_t <= 1.0 + CHECK_TOLERANCE:
            return x, xd * slow, xdd * slow * slow, t / slow, use
        step_t = _torque_step(slow, worst_t, last)
        last = (slow * slow, worst_t)
        slow *= min(max(worst_j, 1.0) ** (-1 / 3), step_t, 1.0 - 1e-6)
    return None  # never held: the caller refuses the run rather than pass a profile unchecked


def _torque_step(slow: float, worst: float, last) -> float:
    """The factor the next uniform slow-down takes for the torque, whose worst use ``worst`` at
    ``slow`` is about gravity + inertia x slow^2: worst^(-1/2) (right where gravity is nil), or,
    from the second try on, the slow-down the line through the last two tries (``last``: slow^2,
    use) puts at 1 - TORQUE_AIM, where that is more. Where gravity carries most of the use, the
    first alone took more than SLOW_PASSES tries to end within CHECK_TOLERANCE."""
    step = max(worst, 1.0) ** (-1 / 2)
    if worst <= 1.0 or last is None or last[1] <= worst or last[0] <= slow * slow:
        return step
    inertia = (last[1] - worst) / (last[0] - slow * slow)
    room = 1.0 - TORQUE_AIM - (worst - inertia * slow * slow)  # what the aim leaves beside gravity
    if room <= 0.0:
        return step  # gravity alone is over the aim: no slow-down holds (the caller refuses the run)
    return min(step, math.sqrt(room / inertia) / slow)


def fine_grid(piece: RunPiece, path_jerk: float):
    """The re-timing grid: every TOPP-RA stage cut into equal times of at most STAGE on its
    profile, and around every point at rest the points a path jerk of ``path_jerk`` (path units
    per s^3) passes every STAGE (x = path_jerk t^3 / 6; TOPP-RA's profile leaves rest far faster,
    so its times there are much shorter than the stages'). -> (x (N+1,) path units, x* (N+1,) the
    profile's x_dot^2 there)."""
    dt = np.diff(piece.t)
    m = np.maximum(1, np.ceil(dt / STAGE)).astype(np.int64)
    i = np.repeat(np.arange(len(dt)), m)
    k = np.arange(len(i)) - np.repeat(np.cumsum(m) - m, m)
    tau = k * (dt / m)[i]
    x = np.append(piece.x[i] + piece.xd[i] * tau + 0.5 * piece.xdd[i] * tau * tau, piece.x[-1])
    rest = piece.x[piece.xd == 0]
    if math.isfinite(path_jerk) and path_jerk > 0:
        near = path_jerk * (np.r_[0.25, 0.5, np.arange(1, REST_POINTS + 1)] * STAGE) ** 3 / 6
        x = np.concatenate([x, (rest[:, None] + near[None]).ravel(), (rest[:, None] - near[None]).ravel()])
    x = np.unique(np.clip(x, 0.0, 1.0))
    x = x[np.concatenate([[True], np.diff(x) * piece.S > MIN_STAGE])]
    x[0], x[-1] = 0.0, 1.0
    return x, envelope(piece, x)


def envelope(piece: RunPiece, x) -> np.ndarray:
    """The TOPP-RA profile's x_dot^2 (N+1,) at the points x (path units): linear in x in each of
    its stages, 0 at its points at rest."""
    j = np.clip(np.searchsorted(piece.x, x, side="right") - 1, 0, len(piece.xdd) - 1)
    env = np.maximum(piece.xd[j] ** 2 + 2 * piece.xdd[j] * (x - piece.x[j]), 0.0)
    env[np.isin(x, piece.x[piece.xd == 0])] = 0.0
    return env


def split_long(x, xd, xdd, dt, min_dx: float):
    """The grid x with every stage longer than CUT * STAGE in time (dt (N,), on the profile x_dot =
    xd (N+1,), path acceleration xdd (N,)) cut into equal times of at most that, and the profile's
    x_dot^2 at the new grid's points (the same motion: x_dot^2 is linear in x in a stage); no two
    points closer than min_dx. -> (x, x_dot^2), (M+1,) each."""
    # no more parts than min_dx fit in the stage (equal times are about equal lengths in a slow stage)
    m = np.clip(np.ceil(dt / (CUT * STAGE)), 1, np.maximum(np.floor(np.diff(x) / min_dx), 1)).astype(np.int64)
    i = np.repeat(np.arange(len(dt)), m)
    tau = (np.arange(len(i)) - np.repeat(np.cumsum(m) - m, m)) * (dt / m)[i]
    new = np.append(x[i] + xd[i] * tau + 0.5 * xdd[i] * tau * tau, x[-1])
    new = np.maximum.accumulate(new)
    keep = np.concatenate([[True], np.diff(new) > 0])
    new = new[keep]
    y = np.append(np.maximum(xd[i] + xdd[i] * tau, 0.0) ** 2, xd[-1] ** 2)[keep]
    return new, y


def _accel_forms(d, dq, ddq, scale):
    """Each channel's acceleration at both ends of every stage as linear forms in x at the stage's
    two grid points: (start, end), each (N, 2, dof) coefficients of (x_i, x_i+1), times scale."""
    w = (0.5 / d)[:, None]
    start = np.stack([-dq[:, 0] * w + ddq[:, 0], dq[:, 0] * w], axis=1) * scale
    end = np.stack([-dq[:, 1] * w, dq[:, 1] * w + ddq[:, 1]], axis=1) * scale
    return start, end


def solve_grid(x, env, dq, ddq, amax, jerk, start=None, passes: int = PASSES) -> np.ndarray:
    """The linear programs of the module docstring: x_dot^2 (N+1,) at the grid points x.

    env (N+1,) upper bounds, dq, ddq (N, 2, dof) derivatives at both ends of every stage, amax,
    jerk (dof,) planned limits (jerk NaN: none); start (N+1,): a profile to start from (the last
    grid's solution on a refined grid), else env."""
    # here, not at the top: scipy.optimize's import costs every compile a CPU-second, jerk limits or not
    from scipy.optimize import linprog

    N, dof = dq.shape[0], dq.shape[2]
    top = float(env.max())
    d = np.diff(x)
    first, end = _accel_forms(d, dq, ddq, top / amax[None, None, :])  # accelerations / amax, x = top * y
    i = np.arange(N)
    pair = np.tile(np.stack([i, i + 1, i + 1], axis=1), (4 * dof, 1))  # (a third column of zeros)
    forms = np.concatenate([np.c_[s * f[:, :, j], np.zeros(N)] for j in range(dof) for f in (first, end)
                            for s in (1.0, -1.0)])
    limited = [j for j in range(dof) if math.isfinite(jerk[j])]
    share = np.zeros(N + 1)
    share[:-1] += 0.5 * d
    share[1:] += 0.5 * d
    # the TOPP-RA profile (or the start) stands where no program solves (limit_run then slows it down)
    upper = env / top
    # the programs' unknowns are y / upper (1 where upper is 0, fixed at 0): near rest y is 1e-7 of
    # its largest, HiGHS's feasibility tolerance, and its points would all read as at rest
    col = np.where(upper > 0, upper, 1.0)
    # the first pass's budgets over the duration's tangent at the upper bounds (below the duration
    # of every profile under them), the next ones' at the last solution (so they stay feasible)
    y = None if start is None else np.clip(start, 0.0, env) / top
    duration = math.inf if y is None else _duration(x, y, top)
    grow = GROW
    scale = 1.0
    for k in range(passes):
        fresh = k == 0 or y is None
        # a fresh pass's tangent at the upper bounds, lower each time one finds no profile (a point
        # the budgets there stop, with its neighbour): the tangent at a slower profile allows more
        at = upper * scale if fresh else y
        c, g = stage_time_tangent(d, at, top)
        rows = [(pair, forms, np.ones(len(pair)))]
        rows += [_jerk_rows(first[:, :, j], end[:, :, j], jerk[j] / amax[j], c, g) for j in limited]
        A, b = _rows(*(np.concatenate(part) for part in zip(*rows)), col)
        # -dT/dy at the tangent's point: each point's share of the time (a linear objective at x*
        # alone lets a few points fall to rest)
        weight = share / np.maximum(at, FLOOR) ** 1.5 * col
        low = np.zeros(N + 1) if fresh else y / grow
        high = upper if fresh else np.minimum(upper, grow * y + LIFT * upper)
        res = linprog(-weight / weight.max(), A_ub=A, b_ub=b, bounds=np.c_[low / col, high / col],
                      method="highs-ds", options={"primal_feasibility_tolerance": 1e-10})
        trial = np.clip(res.x * col, low, high) if res.status == 0 else None
        # a trust region: kept if faster, else the next pass tries a smaller one around the last
        t_trial = math.inf if trial is None else _duration(x, trial, top)
        if t_trial < duration:
            gain, y, duration = 1.0 - t_trial / duration, trial, t_trial
            if gain < CONVERGED:
                break
        elif y is None:
            scale *= 0.25
        else:
            grow = math.sqrt(grow)
    return (upper if y is None else y) * top


def _duration(x, y, top: float) -> float:
    """The profile's duration; inf where a stage is at rest at both ends (never ends)."""
    return math.inf if np.any((y[:-1] <= 0) & (y[1:] <= 0)) else float(profile(x, y * top)[2][-1])


def _jerk_rows(first, end, jerk, c, g):
    """One channel's jerk rows (cols, vals (R, 3), rhs (R,)) over y = x_dot^2 / top: its
    acceleration's step at every grid point within SPLIT of the budget around it (half of each
    stage beside it; from rest outside the run), its change inside every stage within the rest,
    each budget ``jerk`` (of amax, per s) times the stage durations' tangent ``c + g y``
    (:func:`stage_time_tangent`: below the duration, so the programs' solutions keep the budgets
    of their true durations). first, end (N, 2): the acceleration (of amax) at both ends of every
    stage as forms in the stage's two points."""
    N = len(c)
    gp = np.arange(N + 1)
    cols = np.stack([np.maximum(gp - 1, 0), gp, np.minimum(gp + 1, N)], axis=1)
    step = np.zeros((N + 1, 3))  # start of stage i minus end of stage i-1 (rest outside)
    step[:N, 1:] += first
    step[1:, :2] -= end
    around = np.zeros((N + 1, 3))  # half of each neighbouring stage's duration tangent
    around[:N, 1:] += 0.5 * g
    around[1:, :2] += 0.5 * g
    b_step = np.zeros(N + 1)
    b_step[:N] += 0.5 * c
    b_step[1:] += 0.5 * c
    k_s, k_w = SPLIT * jerk, (1.0 - SPLIT) * jerk
    within = end - first
    zero = np.zeros((N, 1))
    pair = np.c_[gp[:-1], gp[1:], gp[1:]]
    # and every step within half the slack whatever the stages' durations (a slow stage's budget is long)
    cap = np.full(N + 1, 0.5 * SLACK * jerk)
    return (np.concatenate([cols, cols, pair, pair, cols, cols]),
            np.concatenate([step - k_s * around, -step - k_s * around,
                            np.c_[within - k_w * g, zero], np.c_[-within - k_w * g, zero], step, -step]),
            np.concatenate([k_s * b_step, k_s * b_step, k_w * c, k_w * c, cap, cap]))


def stage_time_tangent(d, y, top: float):
    """The tangent plane of every stage's duration ``2 d / (sqrt(top y_i) + sqrt(top y_i+1))`` at
    y (N+1,) (x_dot^2 / top): (c (N,) s, g (N, 2) s per unit of y). The duration is convex in y,
    so ``c + g[:, 0] y_i + g[:, 1] y_i+1`` is at most it for every y >= 0 (exact at y; homogeneous
    of degree -1/2, so c is 1.5 times it). A point with y = 0 gets no slope: it must stay at 0 (its
    upper bound), and a stage at rest at both ends gets LONG_STAGE."""
    v = np.sqrt(top * np.maximum(y, 0.0))
    vs = v[:-1] + v[1:]
    moving = vs > 0
    dt = np.where(moving, 2 * d / np.where(moving, vs, 1.0), LONG_STAGE)
    ends = np.stack([v[:-1], v[1:]], axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(ends > 0, -(d * top / np.where(moving, vs, 1.0) ** 2)[:, None] / ends, 0.0)
    return np.where(moving, 1.5 * dt, LONG_STAGE), g


def _rows(cols, vals, rhs, col):
    """A stacked system (sparse CSR, b) over the unknowns y / col (col (n,) the columns' scales):
    every row scaled to a largest coefficient of 1 (a stage of a micron beside one of a millimetre
    leaves rows whose coefficients differ by many orders, which HiGHS calls infeasible). cols, vals
    (R, K) each over y, rhs (R,)."""
    from scipy import sparse  # here, as linprog: only where jerk limits are planned

    R, K = cols.shape
    n = len(col)
    vals = vals * col[cols]
    scale = np.abs(vals).max(axis=1)
    scale = np.where(scale > 0, scale, 1.0)
    A = sparse.csr_matrix(((vals / scale[:, None]).ravel(), (np.repeat(np.arange(R), K), cols.ravel())),
                          shape=(R, n))
    return A, rhs / scale


def profile(x, y):
    """(x_dot (N+1,), path acceleration (N,), time (N+1,)) of x_dot^2 = y on the grid x; a stage
    at rest at both ends (none from the program, which is infeasible for it) takes no time."""
    xd = np.sqrt(np.maximum(y, 0.0))
    d = np.diff(x)
    vsum = xd[:-1] + xd[1:]
    dt = np.where(vsum > 0, 2 * d / np.where(vsum > 0, vsum, 1.0), 0.0)
    xdd = (y[1:] - y[:-1]) / (2 * d)
    return xd, xdd, np.concatenate([[0.0], np.cumsum(dt)])


def jerk_check(dq, ddq, x, xd, xdd, t, jerk) -> np.ndarray:
    """Per stage and channel (N, dof), the guarantee's bound on third differences over
    JERK_SPACING over the channel's jerk (dof,): ``R + 0.75 E / h`` for the intervals ending in the
    stage, E the acceleration's total variation over an interval I between two of the CHECK points
    of the stages (the steps at the grid points, and the changes between the points inside each
    stage, from rest outside the run) less ``R |I|``, at the one of the RATES R (per channel) with
    the least largest bound. At most 1 everywhere: every third difference over JERK_SPACING reads
    at most the jerk limit. dq, ddq (N, f, dof) at CHECK; x, xd, t (N+1,), xdd (N,) the
    profile. NaN for a channel without a jerk limit."""
    N, f, dof = dq.shape
    x0, x1 = xd[:-1] ** 2, xd[1:] ** 2
    w = x0[:, None] + (x1 - x0)[:, None] * CHECK[None]
    acc = dq * xdd[:, None, None] + ddq * w[:, :, None]  # (N, f, dof)
    # the time at each CHECK point: x = x_i + f d reached after 2 f d / (xd_i + sqrt(xd_i^2 + 2 u f d))
    fd = CHECK[None] * np.diff(x)[:, None]
    root = np.sqrt(np.maximum(x0[:, None] + 2 * xdd[:, None] * fd, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = np.where(fd > 0, 2 * fd / (xd[:-1, None] + root), 0.0)
    tt = (t[:-1, None] + np.minimum(tau, np.diff(t)[:, None])).ravel()  # (N f,)
    moves = np.zeros((N, f, dof))
    moves[:, 1:] = np.abs(np.diff(acc, axis=1))
    step = np.abs(np.vstack([acc[:, 0], np.zeros((1, dof))]) - np.vstack([np.zeros((1, dof)), acc[:, -1]]))
    before = np.zeros((N, f, dof))
    before[:, 0] = step[:-1]  # the step just before each stage's first point
    after = np.zeros((N, f, dof))
    after[:, -1] = step[1:]  # and just after its last
    cum = np.cumsum((moves + before).reshape(N * f, dof), axis=0)
    pre, post = before.reshape(N * f, dof), after.reshape(N * f, dof)
    out = np.empty((N, dof))
    with np.errstate(divide="ignore", invalid="ignore"):
        for j in range(dof):
            best = None
            for rate in jerk[j] * RATES:
                lowest = np.minimum.accumulate(cum[:, j] - pre[:, j] - rate * tt)
                # over rate |I|, of the intervals ending at each point
                excess = cum[:, j] + post[:, j] - rate * tt - lowest
                use = (rate + 0.75 * excess.reshape(N, f).max(axis=1) / JERK_SPACING) / jerk[j]
                if best is None or use.max() < best.max():
                    best = use
            out[:, j] = best
    return out
