"""The solver's constraints along a run, per stage of the grid (see :mod:`.topp`): the joint and
filament velocity limits and the feed as one bound on x_dot^2 (:class:`PathVelocityConstraint`),
the acceleration limits as linear rows in (u, x_dot^2) at fractions of every stage
(:class:`StageAccelerationConstraint`). A new limit that is linear in (u, x_dot^2) is one more
such constraint."""

from __future__ import annotations

import numpy as np

from ..jit import njit


# Stage fractions where the solver constrains acceleration: both ends and the middle. The limits
# are held by the stage-wise check at CHECK's five (and refinement where it fails), not by these:
# more fractions would add rows, not safety; the motion between them stays within the margin.
EVAL = np.array([0.0, 0.5, 1.0])
# Stage fractions of the stage-wise limit check: the quarters. Its bound adds 0.3125 of the
# samples' largest second difference, which keeps it above the continuous maximum between them
# (docs/architecture.md: limits proven on the continuous motion).
CHECK = np.linspace(0.0, 1.0, 5)
# EVAL's fractions are CHECK's 0, 2 and 4 (exactly: k/4): the derivatives are computed once per
# grid, and the constraints take a view of them.
EVAL_IN_CHECK = slice(0, None, 2)


class StageAccelerationConstraint:
    """Joint (and filament) acceleration limits imposed inside every stage.

    In stage i (x_i..x_{i+1}, width d) the path acceleration u is constant and
    x_dot^2 = x_i + 2 f d u at fraction f, so the acceleration at f is
    (q'(f) + 2 f d q''(f)) u + q''(f) x_i: collocation rows in toppra's (u, x_i), one
    set per fraction in ``frac``, derivatives from the stage's own piece. ``stage``:
    precomputed ``RunPath.stage_derivatives(x, frac)``."""

    identical = True  # toppra's flag: F and g are the same at every grid point

    def __init__(self, amax: np.ndarray, frac: np.ndarray = EVAL, stage=None):
        self.amax = np.asarray(amax, dtype=float)
        self.dof = len(self.amax)
        self.frac = np.asarray(frac, dtype=float)
        self.stage = stage

    def rows(self, path, gridpoints, unit: np.ndarray | None = None, last_once: bool = False, extra: int = 0):
        """The rows' u and x coefficients a, b (n+1, f * dof), each bounded by +-amax; with
        ``unit`` (n+1,), each row in other units of the path parameter (x' = c x, c = unit[i]):
        a / c and b / c^2 (the compiled solver's rows for moves that meet at rest, _speeds).
        last_once: the last channel's rows at the first fraction only (f * dof - f + 1 columns, in
        the order of :meth:`channels`): the filament's, which are the same at every fraction
        (q' its piece's rate, q'' = 0: RunPath.stage_derivatives), so the others repeat them.
        extra: that many more columns, left unset, after them (room for the torque rows: no copy)."""
        dq, ddq = self.stage if self.stage is not None else path.stage_derivatives(gridpoints, self.frac)
        d = np.diff(gridpoints)
        n, f, dof = dq.shape
        ch = self.channels(last_once)
        c = np.ones(n + 1) if unit is None else np.asarray(unit, dtype=float)  # x / 1.0 is x, bit for bit
        a = np.empty((n + 1, len(ch) + extra))
        b = np.empty((n + 1, len(ch) + extra))
        _rows_kernel(dq, ddq, self.frac, d, c, last_once, a, b)
        # The last grid point has no stage ahead: its own (end) derivatives, no u-term.
        a[-1, : len(ch)] = dq[-1, -1][ch] / c[-1]
        b[-1, : len(ch)] = ddq[-1, -1][ch] / (c[-1] * c[-1])
        return a, b

    def channels(self, last_once: bool = False) -> np.ndarray:
        """The channel of each of :meth:`rows`' columns: fraction-major, every channel at each
        fraction (the last one at the first fraction only, with last_once)."""
        f, dof = len(self.frac), self.dof
        return np.array([j for k in range(f) for j in range(dof) if not (last_once and k > 0 and j == dof - 1)],
                        dtype=np.int64)

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        a, b = self.rows(path, gridpoints)
        eye = np.eye(a.shape[1])
        F = np.vstack([eye, -eye])
        g = np.tile(self.amax, 2 * len(self.frac))
        return a, b, np.zeros_like(a), F, g, None, None


@njit
def _rows_kernel(dq, ddq, frac, d, unit, last_once, a, b):
    """a[i, k dof + j] = q'_j + 2 f_k d_i q''_j and b[i, k dof + j] = q''_j at fraction f_k of stage i
    (dq, ddq: (n, f, dof); rows i < n of a, b), in one pass: the same operations, in the same
    order, as the numpy expression ``dq + 2 * frac * d * ddq``, each row i then divided by unit[i]
    (a) and unit[i]^2 (b), as numpy's ``a / c, b / (c * c)`` (unit (n+1,); ones leave the rows as
    they are). last_once: the last channel at the first fraction only (the columns of
    StageAccelerationConstraint.channels)."""
    n, f, dof = dq.shape
    for i in range(n):
        c = unit[i]
        cc = c * c
        col = 0
        for k in range(f):
            w = 2.0 * frac[k] * d[i]
            for j in range(dof if not (last_once and k > 0) else dof - 1):
                a[i, col] = (dq[i, k, j] + w * ddq[i, k, j]) / c
                b[i, col] = ddq[i, k, j] / cc
                col += 1


def gridpoint_speed_factor(dq_stage: np.ndarray) -> np.ndarray:
    """Largest |q'| (n+1, dof) at each grid point over both sides of it and the stages around
    it (their start, middle and end), from stage derivatives (n, f, dof) at fractions whose
    first is 0, middle 0.5 and last 1: a cap on x_dot^2 at both ends of a stage also holds in
    its middle, where x_dot^2 is their mean."""
    out = np.empty((dq_stage.shape[0] + 1, dq_stage.shape[2]))
    _speed_factor_kernel(dq_stage, out)
    return out


@njit
def _nan_max(a, b):
    """numpy's maximum of two floats: NaN if either is."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@njit
def _speed_factor_kernel(dq, out):
    """:func:`gridpoint_speed_factor` in one pass: out[i] = max(ahead_i, behind_{i-1}) with
    ahead_i = max(|q'| at stage i's start, at its middle), behind_i = max(|q'| at its end, at its
    middle) (NaN where any is, as numpy's maximum); out[0] = ahead_0, out[n] = behind_{n-1}."""
    n, f, dof = dq.shape
    mid = f // 2
    # grid point by grid point, its channels together: one pass over dq (a pass per channel
    # read a run's whole derivative array, larger than the cache, once for each)
    for i in range(n + 1):
        for j in range(dof):
            top = 0.0
            if i < n:
                top = _nan_max(abs(dq[i, 0, j]), abs(dq[i, mid, j]))
            if i > 0:
                behind = _nan_max(abs(dq[i - 1, f - 1, j]), abs(dq[i - 1, mid, j]))
                top = _nan_max(top, behind)
            out[i, j] = top


class PathVelocityConstraint:
    """Every first-order limit at once, over the whole grid: joint (and filament)
    velocity limits through q'(x), and the feed cap on the Cartesian speed S x_dot.
    Returns only toppra's ``xbound`` (bounds on x_dot^2)."""

    identical = False

    def __init__(self, vmax: np.ndarray, feed_at_grid: np.ndarray, S: float, speed_factor: np.ndarray | None = None):
        self.speed_factor = speed_factor  # (n+1, dof) |q'| per grid point, both sides (gridpoint_speed_factor)
        self.vmax = np.asarray(vmax, dtype=float)
        self.dof = len(self.vmax)
        self.feed = np.asarray(feed_at_grid, dtype=float)
        self.S = S

    def cap2(self, path, gridpoints) -> np.ndarray:
        """The bound on x_dot^2 at each grid point (n+1,)."""
        dq = np.abs(path(gridpoints, 1)) if self.speed_factor is None else self.speed_factor
        dq = np.ascontiguousarray(dq, dtype=float)
        # the kernel reads a feed per grid point and a limit per channel unchecked: broadcast
        # them as numpy's expression did (a scalar feed; a feed for another grid refused)
        vmax = np.ascontiguousarray(np.broadcast_to(self.vmax, dq.shape[1:]))
        feed = np.ascontiguousarray(np.broadcast_to(self.feed, dq.shape[:1]), dtype=float)
        out = np.empty(len(dq))
        _cap2_kernel(dq, vmax, feed, float(self.S), out)
        return out

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        xbound = np.zeros((len(gridpoints), 2))
        xbound[:, 1] = self.cap2(path, gridpoints)
        return None, None, None, None, None, None, xbound


@njit
def _cap2_kernel(dq, vmax, feed, S, out):
    """out[i] = min(min_j vmax[j] / dq[i, j], feed[i] / S)^2 (dq (n, dof) >= 0, a zero giving
    inf), NaN where any term is: numpy's ``np.minimum(np.min(vmax / dq, axis=1), feed / S) ** 2``
    in one pass (its (n, dof) temporaries and its short reduction along each row cost more than
    the arithmetic)."""
    n, dof = dq.shape
    for i in range(n):
        cap = feed[i] / S  # NaN stays NaN: v < NaN is false
        nan = False
        for j in range(dof):
            v = vmax[j] / dq[i, j]
            nan |= v != v
            cap = v if v < cap else cap
        out[i] = np.nan if nan else cap * cap
