"""numba's ``njit`` for the compiled hot loops (reachability, kinematics kernels, path frames),
with a pass-through fallback so a broken install still runs (correct, slow).

Every kernel is compiled with numba's own ``cache=True`` (written beside its module in
``__pycache__``, or under ``NUMBA_CACHE_DIR``: the first compile after a fresh install takes
seconds, later processes load it) and numpy's error model (a division by zero gives inf or NaN,
as the vectorised code it replaces, not an exception). Only numba's public API is used: its
internals change from release to release.

numba itself is imported when a kernel is first called, not when the modules that define kernels
are: importing it takes a few tenths of a second, which a compile spends while its slicing
workers (which run no kernel) slice. Until then ``njit`` gives a
stand-in (:class:`Deferred`); the first call of any stand-in (or :func:`load`) makes numba's
dispatcher of every kernel defined so far and puts it in place of the stand-in wherever a
``deltaslice`` module holds it, so kernels calling kernels compile against dispatchers, and later
calls from Python go straight to them."""

from __future__ import annotations

import sys

_PENDING: list = []  # the stand-ins made before numba was imported, in definition order
_NJIT = None  # numba.njit once imported (a pass-through where numba is missing)


def _pass_through(*args, **kwargs):  # pragma: no cover
    if args and callable(args[0]):
        return args[0]
    return lambda f: f


class Deferred:
    """A kernel defined before numba was imported. Calling it, or reading an attribute of
    numba's dispatcher (``signatures``, ...), loads numba (:func:`load`) and goes to the dispatcher;
    ``py_func`` is the Python function."""

    def __init__(self, fn, options: dict):
        self.py_func, self.options, self.dispatcher = fn, options, None
        self.__wrapped__ = fn  # inspect.signature and friends read the Python function
        self.__name__, self.__qualname__, self.__module__, self.__doc__ = (
            fn.__name__, fn.__qualname__, fn.__module__, fn.__doc__)

    def __call__(self, *args, **kwargs):
        if self.dispatcher is None:
            load()
        return self.dispatcher(*args, **kwargs)

    def __getattr__(self, name):
        # only attributes not set in __init__ get here: numba's (signatures, ...) load it; dunder
        # lookups (copy, pickle, inspect) and a half-made instance's own fields must not
        if name.startswith("__") or name in ("py_func", "options", "dispatcher"):
            raise AttributeError(name)
        load()
        return getattr(self.dispatcher, name)

    def __reduce__(self):  # by reference, as numba pickles its dispatchers' functions
        return _kernel, (self.__module__, self.__qualname__)

    def __repr__(self):
        return f"<deferred kernel {self.__module__}.{self.__qualname__}>"


def _kernel(module: str, qualname: str):
    """The kernel ``module.qualname`` (a stand-in or numba's dispatcher), for unpickling."""
    import importlib

    return getattr(importlib.import_module(module), qualname)


def loaded() -> bool:
    """Whether numba has been imported and the kernels made (:func:`load`)."""
    return _NJIT is not None


def load() -> None:
    """Import numba and make every deferred kernel's dispatcher, put in its place in every
    ``deltaslice`` module (kernels are found by name from the kernels that call them). Does
    nothing the second time."""
    global _NJIT
    if _NJIT is not None:
        return
    try:  # numba is a declared dependency
        from numba import njit as numba_njit
    except ImportError:  # pragma: no cover
        _NJIT = _pass_through
    else:
        _NJIT = numba_njit
    for stand_in in _PENDING:
        stand_in.dispatcher = _NJIT(**stand_in.options)(stand_in.py_func)
    for name, module in list(sys.modules.items()):
        if module is None or not (name == "deltaslice" or name.startswith("deltaslice.")):
            continue
        space = vars(module)
        for key, value in list(space.items()):
            if type(value) is Deferred:
                space[key] = value.dispatcher
    _PENDING.clear()


def njit(*args, **kwargs):
    """``numba.njit(cache=True, error_model="numpy", **kwargs)``; usable bare (``@njit``) or called.
    Before numba is loaded, a :class:`Deferred` stand-in."""
    kwargs.setdefault("cache", True)
    kwargs.setdefault("error_model", "numpy")

    if args and not callable(args[0]):
        raise TypeError("njit: give options as keywords (the kernels here are typed at their first call)")

    def make(fn):
        if _NJIT is not None:
            return _NJIT(**kwargs)(fn)
        stand_in = Deferred(fn, kwargs)
        _PENDING.append(stand_in)
        return stand_in

    return make(args[0]) if args else make
