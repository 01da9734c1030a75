"""The fast solver's side of one run: the path's derivatives on the grid in one inverse-kinematics
call, the grid-wide velocity cap, and the speed profile from :mod:`.reachability`.

Numerically the same problem ``topp._plan_run`` hands toppra (``PathVelocityConstraint`` and
``JointAccelerationConstraint`` with interpolation discretisation), without toppra's per-call
set-up and without evaluating the path's derivatives once per constraint.
"""

from __future__ import annotations

import numpy as np

from .reachability import solve

SOLVERS = ("fast", "toppra")


def grid_derivatives(rp, xs: np.ndarray):
    """(dq (n,d), ddq (n,d)): ``rp(xs, 1)`` and ``rp(xs, 2)`` of a ``topp.RunPath`` (path units,
    joint units per path unit and per path unit squared), from one inverse-kinematics evaluation
    at the grid points and their forward-difference partners."""
    xs = np.atleast_1d(np.asarray(xs, dtype=float))
    n = len(xs)
    s = np.clip(xs, 0.0, 1.0) * rp.S
    piece = rp.path.locate(s)
    # The second derivative is the forward difference of the exact first one inside the piece
    # (backward at a piece's end), with RunPath's step.
    end = rp.path.piece_start[piece + 1]
    h = np.minimum(1e-4, np.maximum((end - s) / 3, 0))
    back = h <= 1e-9
    h = np.where(back, 1e-4, h)
    s2 = np.where(back, np.maximum(s - h, 0), s + h)
    d = rp._first(np.concatenate([s, s2]), np.concatenate([piece, piece]))[1]
    d1, d2 = d[:n], d[n:]
    ddq = (d2 - d1) / (np.where(back, -h, h)[:, None] / rp.S)
    if rp.e_ratio is not None:
        d1 = np.column_stack([d1, rp.e_ratio[piece] * rp.S])
        ddq = np.column_stack([ddq, np.zeros(n)])
    return d1, ddq


def velocity_cap2(dq: np.ndarray, vmax: np.ndarray, feed: np.ndarray, S: float) -> np.ndarray:
    """Bound on x_dot^2 at each grid point (n,): every coordinate's speed limit through dq (n,d)
    and the feed cap (mm/s) on the Cartesian speed S x_dot; ``PathVelocityConstraint``'s xbound."""
    with np.errstate(divide="ignore"):
        cap = np.min(vmax[None] / np.abs(dq), axis=1)
    return np.minimum(cap, feed / S) ** 2


def fast_speeds(dq, ddq, amax, cap2, x_grid):
    """Path speeds x_dot (n,) on x_grid from rest to rest, or None where toppra would return None."""
    x, _, _ = solve(dq, ddq, -amax, amax, cap2, np.diff(x_grid))
    if not np.all(np.isfinite(x)):
        return None
    return np.sqrt(np.maximum(x, 0.0))
