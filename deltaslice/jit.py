"""numba's ``njit`` for the compiled hot loops (reachability, kinematics kernels, path frames),
with a pass-through fallback so a broken install still runs (correct, slow).

Every kernel is compiled with ``cache=True`` (written beside its module in ``__pycache__``: the
first compile after a fresh install takes seconds, later processes load it) and numpy's error
model (a division by zero gives inf or NaN, as the vectorised code it replaces, not an exception)."""

from __future__ import annotations

try:  # numba is a declared dependency
    from numba import njit as _numba_njit
except ImportError:  # pragma: no cover
    _numba_njit = None


def njit(*args, **kwargs):
    """``numba.njit(cache=True, error_model="numpy", **kwargs)``; usable bare (``@njit``) or called."""
    if _numba_njit is None:  # pragma: no cover
        if args and callable(args[0]):
            return args[0]
        return lambda f: f
    kwargs.setdefault("cache", True)
    kwargs.setdefault("error_model", "numpy")
    if args and callable(args[0]):
        return _numba_njit(**kwargs)(args[0])
    return _numba_njit(*args, **kwargs)
