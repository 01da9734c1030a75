"""TOPP-RA's reachability algorithm for our constraint structure, compiled with numba.

The problem toppra solves for one run, per grid point i = 0..n with u = x_dd and x = x_dot^2:

* first-order bounds 0 <= x_i <= xmax_i,
* second-order rows a_ij u + b_ij x in [lo_j, hi_j] (joint j's acceleration q'_j u + q''_j x),
  with toppra's *interpolation* discretisation: stage i also carries the rows of grid point i+1
  evaluated at x_{i+1} = x_i + 2 ds_i u_i, i.e. (a_{i+1} + 2 ds_i b_{i+1}) u + b_{i+1} x,
* x_{i+1} = x_i + 2 ds_i u_i.

It computes the controllable sets backward from x_n = x_end and the greedy forward pass exactly as
toppra's ``TOPPRA.compute_parameterization`` does (the same 0.9999 shrink of each step, held to the
stage's range of u so that it never implies a deceleration beyond the rows, and the same box on u
and x as its seidel solver), but each stage's two-variable LP is solved in closed form by
eliminating u (Fourier-Motzkin: every pair of a lower and an upper bound on u gives a bound on x;
only the bounds that can lie on their envelope over the stage's range of x are paired: the range
every pair gives, from a few pairs instead of ~22 x 22; every pair where it comes out empty or a
pair is nearly parallel), and the whole loop runs compiled: 0.5-1 us a stage (measured on the
shared 2-core machine) against toppra's ~20 us, and no per-call set-up. The first call in a fresh
install compiles it; later processes load it from numba's cache. Without numba the same code runs
as plain Python (correct, slow; :mod:`deltaslice.jit`).
"""

from __future__ import annotations

import math

import numpy as np

from ..jit import njit
from .tolerances import BOUND_ROUNDING, PAIR_ROUNDING

# toppra's constants: the seidel solver's box on both variables, its forward-pass shrink and
# the tolerance on the start velocity's controllability.
BOX = 1e8
TINY = 1e-8
SMALL = 1e-5
MAX_TRIES = 10
# A pair of bounds on u whose x coefficients differ by less than this is parallel.
PARALLEL = 1e-12


@njit(error_model="python")
def _u_rows(a, b, lo, hi, i, ds, interp, n_rows, low_p, low_r, up_p, up_r):
    """Bounds on u at stage i as u >= p + r x (low) and u <= p + r x (up); rows with no u
    term become bounds on x. lo, hi: (1, m) bounds shared by every grid point, or (n+1, m) each
    grid point's own. Returns (n_low, n_up, xl, xh); xl > xh when infeasible."""
    step = 0 if lo.shape[0] == 1 else 1
    m = a.shape[1]
    nl = 0
    nu = 0
    xl = -np.inf
    xh = np.inf
    for k in range(n_rows):
        j = k % m
        g = i
        if k < m:
            al = a[i, j]
            be = b[i, j]
        else:
            g = i + 1
            al = a[i + 1, j] + 2.0 * ds * b[i + 1, j]
            be = b[i + 1, j]
        l = lo[g * step, j]
        h = hi[g * step, j]
        # an infinite bound bounds nothing: a one-sided row gives one line, not two to pair
        if al > 0.0:
            if h != np.inf:
                up_p[nu] = h / al
                up_r[nu] = -be / al
                nu += 1
            if l != -np.inf:
                low_p[nl] = l / al
                low_r[nl] = -be / al
                nl += 1
        elif al < 0.0:
            if l != -np.inf:
                up_p[nu] = l / al
                up_r[nu] = -be / al
                nu += 1
            if h != np.inf:
                low_p[nl] = h / al
                low_r[nl] = -be / al
                nl += 1
        elif be > 0.0:
            xh = min(xh, h / be)
            xl = max(xl, l / be)
        elif be < 0.0:
            xh = min(xh, l / be)
            xl = max(xl, h / be)
        elif l > 0.0 or h < 0.0:
            xl = np.inf
    return nl, nu, xl, xh


@njit(error_model="python")
def _envelope(n, p, r, xl, xh, sign, keep):
    """The lines p_k + r_k x (k < n) that may lie on their upper (sign 1) or lower (sign -1)
    envelope over [xl, xh], into keep; returns how many. A line is left out when the line highest
    at xl, or the one highest at xh, is strictly higher at both ends (so on the whole interval):
    every intersection it makes with a line of the other side is matched by one strictly tighter.
    Lines are compared by their differences, (p_k - p_a) + (r_k - r_a) x, not by their values:
    near-duplicate lines far from zero (|p| ~ 1e6) would tie once rounded and the binding one
    could be the one left out."""
    ka = 0
    kb = 0
    for k in range(n):
        if sign * ((p[k] - p[ka]) + (r[k] - r[ka]) * xl) > 0.0:
            ka = k
        if sign * ((p[k] - p[kb]) + (r[k] - r[kb]) * xh) > 0.0:
            kb = k
    m = 0
    for k in range(n):
        below_a = sign * ((p[k] - p[ka]) + (r[k] - r[ka]) * xl) < 0.0 and sign * ((p[k] - p[ka]) + (r[k] - r[ka]) * xh) < 0.0
        below_b = sign * ((p[k] - p[kb]) + (r[k] - r[kb]) * xl) < 0.0 and sign * ((p[k] - p[kb]) + (r[k] - r[kb]) * xh) < 0.0
        if not (below_a or below_b):
            keep[m] = k
            m += 1
    return m


@njit(error_model="python")
def _pairs(nl, nu, low_p, low_r, up_p, up_r, xl, xh, keep_l, keep_u):
    """(xl, xh, near): xl, xh tightened by every pair of the lower bounds keep_l[:nl] and upper
    bounds keep_u[:nu]; near: a pair was within PARALLEL of parallel without being parallel
    (its crossing is not looked for: only its intercepts are compared)."""
    near = False
    for kk in range(nl):
        k = keep_l[kk]
        for jj in range(nu):
            j = keep_u[jj]
            c = low_r[k] - up_r[j]
            e = up_p[j] - low_p[k]
            if c > PARALLEL:
                xh = min(xh, e / c)
            elif c < -PARALLEL:
                xl = max(xl, e / c)
            else:
                near = near or c != 0.0
                if e < -PAIR_ROUNDING * (abs(up_p[j]) + abs(low_p[k]) + 1.0):
                    return np.inf, -np.inf, near
    return xl, xh, near


@njit(error_model="python", inline="always")  # one caller: typed in it, no module of its own on a first run
def _x_range(nl, nu, low_p, low_r, up_p, up_r, xl, xh, keep_l, keep_u):
    """Projection onto x of {(u, x): low_k(x) <= u <= up_j(x)} within [xl, xh]. Where it is not
    empty it is that of the bounds that can lie on their envelope (:func:`_envelope`), paired.
    Every pair is used instead where that projection is empty (rare: it makes its run refine;
    the caller's rounding test reads the gap every pair gives) or where a pair was nearly
    parallel (a bound left out could have been what held the range there). keep_l, keep_u:
    scratch index arrays of at least nl and nu."""
    if xl <= xh and math.isfinite(xl) and math.isfinite(xh):
        ml = _envelope(nl, low_p, low_r, xl, xh, 1.0, keep_l)
        mu = _envelope(nu, up_p, up_r, xl, xh, -1.0, keep_u)
        lo, hi, near = _pairs(ml, mu, low_p, low_r, up_p, up_r, xl, xh, keep_l, keep_u)
        if lo <= hi and not near:
            return lo, hi
    for k in range(nl):
        keep_l[k] = k
    for k in range(nu):
        keep_u[k] = k
    lo, hi, _near = _pairs(nl, nu, low_p, low_r, up_p, up_r, xl, xh, keep_l, keep_u)
    return lo, hi


@njit(error_model="python")
def _solve_one(a, b, lo, hi, xmax, ds, interp, x_start, x_end, xs, us, K):
    """One run in place: xs (n+1,), us (n,), K (n+1, 2). Returns 0 on success, 1 when the
    run is not controllable (xs, us NaN), 2 when the forward pass fails."""
    n = a.shape[0] - 1
    m = a.shape[1]
    n_rows = 2 * m if interp else m
    cap = n_rows + 2
    low_p = np.empty(cap)
    low_r = np.empty(cap)
    up_p = np.empty(cap)
    up_r = np.empty(cap)
    keep_l = np.empty(cap, dtype=np.int64)
    keep_u = np.empty(cap, dtype=np.int64)
    K[n, 0] = x_end
    K[n, 1] = x_end
    for i in range(n - 1, -1, -1):
        nl, nu, xl, xh = _u_rows(a, b, lo, hi, i, ds[i], interp, n_rows, low_p, low_r, up_p, up_r)
        d2 = 2.0 * ds[i]
        # The seidel solver's box, and x_{i+1} = x + 2 ds u inside K_{i+1} (on a zero-length
        # stage: x itself inside K_{i+1}, u free).
        low_p[nl] = -BOX
        low_r[nl] = 0.0
        up_p[nu] = BOX
        up_r[nu] = 0.0
        extra = 1
        if d2 > 0.0:
            low_p[nl + 1] = K[i + 1, 0] / d2
            low_r[nl + 1] = -1.0 / d2
            up_p[nu + 1] = K[i + 1, 1] / d2
            up_r[nu + 1] = -1.0 / d2
            extra = 2
        else:
            xl = max(xl, K[i + 1, 0])
            xh = min(xh, K[i + 1, 1])
        xl = max(xl, 0.0)
        xh = min(xh, min(xmax[i], BOX))
        xl, xh = _x_range(nl + extra, nu + extra, low_p, low_r, up_p, up_r, xl, xh, keep_l, keep_u)
        if xl > xh and xl - xh <= BOUND_ROUNDING * (1.0 + abs(xh)):
            xl = xh  # a single point, split by rounding
        if not (xl <= xh):
            for k in range(n + 1):
                xs[k] = np.nan
            for k in range(n):
                us[k] = np.nan
            K[i, 0] = np.nan
            K[i, 1] = np.nan
            return 1
        K[i, 0] = max(xl, 0.0)
        K[i, 1] = xh
    if x_start + SMALL < K[0, 0] or K[0, 1] + SMALL < x_start:
        for k in range(n + 1):
            xs[k] = np.nan
        for k in range(n):
            us[k] = np.nan
        return 1
    xs[0] = x_start
    i = np.int64(0)  # not a literal 0: numba would compile _u_rows for that value too
    tries = 0
    while i < n:
        x = xs[i]
        nl, nu, xl, xh = _u_rows(a, b, lo, hi, i, ds[i], interp, n_rows, low_p, low_r, up_p, up_r)
        d2 = 2.0 * ds[i]
        lo_u = -BOX
        hi_u = BOX
        if d2 > 0.0:
            lo_u = max(lo_u, (K[i + 1, 0] - x) / d2)
            hi_u = min(hi_u, (K[i + 1, 1] - x) / d2)
        elif x < K[i + 1, 0] - TINY or x > K[i + 1, 1] + TINY:
            lo_u = np.inf
        for k in range(nl):
            lo_u = max(lo_u, low_p[k] + low_r[k] * x)
        for k in range(nu):
            hi_u = min(hi_u, up_p[k] + up_r[k] * x)
        feasible = x >= xl - TINY and x <= min(xh, min(xmax[i], BOX)) + TINY
        if not feasible or lo_u > hi_u + BOUND_ROUNDING * max(1.0, abs(hi_u)):
            if tries < MAX_TRIES:
                xs[i] = max(x - TINY, 0.999 * x)
                tries += 1
                continue
            for k in range(i + 1, n + 1):
                xs[k] = np.nan
            for k in range(i, n):
                us[k] = np.nan
            return 2
        tries = 0
        us[i] = hi_u
        x_next = x + d2 * hi_u
        # toppra's shrink keeps the next point inside its set; it is a step in x whatever the
        # stage's width, so on stages refined to a few microns it is a deceleration many times the
        # limit. Held to the stage's range
        # of u, the stage's path acceleration stays within its rows.
        shrink = min(x_next - max(x_next - TINY, 0.9999 * x_next), d2 * (hi_u - lo_u))
        x_next = x_next - max(shrink, 0.0)
        xs[i + 1] = min(K[i + 1, 1], max(K[i + 1, 0], x_next))
        i += 1
    return 0


@njit(error_model="python")
def _solve_many(a, b, lo, hi, xmax, ds, offsets, interp, x_start, x_end, xs, us, K, status):
    """Runs r = 0..R-1 stacked: grid points offsets[r]..offsets[r+1]-1 of a, b, xmax, xs, K;
    stages offsets[r]-r .. offsets[r+1]-r-2 of ds, us."""
    for r in range(len(offsets) - 1):
        g0 = offsets[r]
        g1 = offsets[r + 1]
        s0 = g0 - r
        s1 = g1 - r - 1
        status[r] = _solve_one(
            a[g0:g1], b[g0:g1], lo, hi, xmax[g0:g1], ds[s0:s1], interp, x_start[r], x_end[r],
            xs[g0:g1], us[s0:s1], K[g0:g1],
        )


def _bounds(v, m: int) -> np.ndarray:
    """Row bounds as the kernels take them: (m,) -> (1, m) shared; (n+1, m) as they are."""
    v = np.ascontiguousarray(v, dtype=np.float64)
    return v.reshape(1, m) if v.ndim == 1 else v


def solve(a, b, lo, hi, xmax, ds, *, x_start=0.0, x_end=0.0, interpolation=True):
    """Time-optimal x = x_dot^2 on one grid, as toppra's TOPPRA with the seidel solver.

    a, b: (n+1, m) float, coefficients of u and x in each second-order row (q'_j(s_i), q''_j(s_i));
    lo, hi: (m,) the rows' bounds (lo <= 0 <= hi for a problem with a solution at rest), or
    (n+1, m) bounds per grid point (a torque row's gravity term moves them along the path); -inf
    or inf where a row is one-sided;
    xmax: (n+1,) first-order bound on x (>= 0, may be inf); ds: (n,) >= 0 stage lengths in path
    units (a zero-length stage keeps x and takes the largest u its rows allow);
    x_start, x_end: squared path speeds at the ends.
    interpolation: toppra's interpolation discretisation (else collocation).

    Returns (x (n+1,), u (n,), K (n+1, 2)) float64: squared path speed at the grid points, constant
    path acceleration per stage, the controllable sets. x and u are NaN when the run cannot be
    parameterised (toppra returns None there).
    """
    a = np.ascontiguousarray(a, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    n = a.shape[0] - 1
    xs = np.empty(n + 1)
    us = np.empty(n)
    K = np.full((n + 1, 2), np.nan)  # a backward pass that fails leaves the sets before it unset
    _solve_one(
        a, b, _bounds(lo, a.shape[1]), _bounds(hi, a.shape[1]),
        np.ascontiguousarray(xmax, dtype=np.float64), np.ascontiguousarray(ds, dtype=np.float64),
        bool(interpolation), float(x_start), float(x_end), xs, us, K,
    )
    return xs, us, K


def solve_batch(problems, lo, hi, *, interpolation=True):
    """Many runs in one compiled call. problems: [(a (n_r+1, m), b, xmax (n_r+1,), ds (n_r,))];
    lo, hi: (m,) shared bounds; every run from rest to rest. Returns [(x (n_r+1,), u (n_r,))]."""
    if not problems:
        return []
    sizes = np.array([len(p[0]) for p in problems])
    offsets = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    a = np.ascontiguousarray(np.concatenate([p[0] for p in problems]), dtype=np.float64)
    b = np.ascontiguousarray(np.concatenate([p[1] for p in problems]), dtype=np.float64)
    xmax = np.ascontiguousarray(np.concatenate([p[2] for p in problems]), dtype=np.float64)
    ds = np.ascontiguousarray(np.concatenate([p[3] for p in problems]), dtype=np.float64)
    R = len(problems)
    xs = np.empty(len(a))
    us = np.empty(len(ds))
    K = np.empty((len(a), 2))
    status = np.empty(R, dtype=np.int64)
    zeros = np.zeros(R)
    _solve_many(
        a, b, _bounds(lo, a.shape[1]), _bounds(hi, a.shape[1]),
        xmax, ds, offsets, bool(interpolation), zeros, zeros, xs, us, K, status,
    )
    return [(xs[offsets[r] : offsets[r + 1]], us[offsets[r] - r : offsets[r + 1] - r - 1]) for r in range(R)]
