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
calls from Python go straight to them.

A first compile (an empty cache, inside :func:`first_run`) compiles the kernels it needs in
parallel before it goes on (:func:`warm_up`): ``kernels.json`` lists the kernels the README's first compile calls from Python
with their argument types (``scripts/record_kernels.py`` writes it), and each is compiled by
numba's documented eager form (``numba.njit([signature], cache=True)``) in this process and in
one worker process per further core (each takes the next group of kernels as it finishes one,
longest first), which share the result through numba's cache; the run then
loads them from the cache as a later run does. A kernel called with other types, or one not
listed, compiles at its first call as before."""

from __future__ import annotations

import gc
import json
import multiprocessing
import os
import signal
import sys
import threading
import time
from contextlib import contextmanager
from pathlib import Path

_PENDING: list = []  # the stand-ins made before numba was imported, in definition order
_NJIT = None  # numba.njit once imported (a pass-through where numba is missing)
_KERNELS: dict = {}  # (module, qualname) -> the Python function and its options, for warm_up
_FIRST_RUN = {"on": False, "progress": None}  # set by first_run(): warm_up at load, reported there
MANIFEST = Path(__file__).with_name("kernels.json")
FIRST_RUN_LABEL = "compiling kernels (first run only)"


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


def load(warm: bool = True) -> None:
    """Import numba and make every deferred kernel's dispatcher, put in its place in every
    ``deltaslice`` module (kernels are found by name from the kernels that call them); then, with
    ``warm`` inside :func:`first_run`, compile the listed kernels in parallel if numba's cache has
    none of them (:func:`warm_up`). Does nothing the second time."""
    global _NJIT
    if _NJIT is not None:
        return
    entries = _manifest() if warm and _FIRST_RUN["on"] and multiprocessing.parent_process() is None else []
    for module in sorted({e["module"] for e in entries}):
        __import__(module)  # their kernels are made below with the others
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
    if entries and _NJIT is not _pass_through:
        try:
            warm_up(entries, progress=_FIRST_RUN["progress"])
        except (OSError, ValueError, TypeError, KeyError, SyntaxError, NameError):
            pass  # no process or a stale list: every kernel still compiles at its first call


def njit(*args, **kwargs):
    """``numba.njit(cache=True, error_model="numpy", **kwargs)``; usable bare (``@njit``) or called.
    Before numba is loaded, a :class:`Deferred` stand-in."""
    kwargs.setdefault("cache", True)
    kwargs.setdefault("error_model", "numpy")

    if args and not callable(args[0]):
        raise TypeError("njit: give options as keywords (the kernels here are typed at their first call)")

    def make(fn):
        _KERNELS[(fn.__module__, fn.__qualname__)] = (fn, kwargs)
        if _NJIT is not None:
            return _NJIT(**kwargs)(fn)
        stand_in = Deferred(fn, kwargs)
        _PENDING.append(stand_in)
        return stand_in

    return make(args[0]) if args else make


@contextmanager
def first_run(progress=None):
    """While the block runs, numba's first load (:func:`load`) compiles kernels.json's kernels in
    parallel if the cache has none (:func:`warm_up`), reporting to ``progress(done, total)`` (in
    kernels; None: silent). The compile command's (the README's first command) asks for it;
    elsewhere (a library call, a command using a few kernels) each compiles at its first call."""
    before = dict(_FIRST_RUN)
    _FIRST_RUN.update(on=True, progress=progress)
    try:
        yield
    finally:
        _FIRST_RUN.update(before)


def _manifest() -> list:
    """kernels.json's kernels (dicts of module, name, seconds, signatures), or [] where it is missing
    or unreadable (every kernel then compiles at its first call)."""
    try:
        return list(json.loads(MANIFEST.read_text())["kernels"])
    except (OSError, ValueError, KeyError, TypeError):
        return []


def _signatures(texts) -> list:
    """Argument types as numba writes them (``repr`` of a signature: ``(Array(float64, 1, 'C', False,
    aligned=True), int64)``), read back with the names of numba's public ``numba.types``."""
    import numba.types

    space = dict(vars(numba.types))
    return [eval(text, {"__builtins__": {}}, space) for text in texts]  # noqa: S307 (our own file)


def _compile(module: str, name: str, signatures) -> object:
    """numba's dispatcher of kernel ``module.name`` compiled now, for ``signatures`` (texts), by the
    documented eager form: a new dispatcher of the same function, written to (or read from) the cache
    the kernel's own dispatcher reads at its first call."""
    import numba

    fn, options = _KERNELS[(module, name)]
    return numba.njit(_signatures(signatures), **options)(fn)


def _reached(fn, seen=None) -> set:
    """The kernels (module, qualname) that kernel ``fn`` calls, directly or through others: numba
    compiles them with it, so kernels sharing one are best compiled in the same process."""
    seen = set() if seen is None else seen
    codes = [fn.__code__]
    while codes:
        code = codes.pop()
        codes.extend(c for c in code.co_consts if hasattr(c, "co_names"))
        for word in code.co_names:
            inner = getattr(fn.__globals__.get(word), "py_func", None)
            key = (getattr(inner, "__module__", None), getattr(inner, "__qualname__", None))
            if key in _KERNELS and key not in seen:
                seen.add(key)
                _reached(inner, seen)
    return seen


def _groups(jobs: list) -> list:
    """``jobs`` (manifest entries) in groups that share no kernel: kernels that call a common kernel
    stay together (in manifest order), compiled in one process. The group of the longest recorded
    compile time first."""
    groups = []  # [kernels reached, [job indices]]
    for i, job in enumerate(jobs):
        reach = _reached(_KERNELS[(job["module"], job["name"])][0]) | {(job["module"], job["name"])}
        joined = [g for g in groups if g[0] & reach]
        for g in joined:
            groups.remove(g)
            reach |= g[0]
        groups.append([reach, sorted([i] + [k for g in joined for k in g[1]])])
    groups.sort(key=lambda g: -sum(jobs[k]["seconds"] for k in g[1]))
    return [[jobs[k] for k in members] for _reach, members in groups]


def _take(counter) -> int:
    """The next group's index from the counter the warm-up's processes share."""
    with counter.get_lock():
        k = counter.value
        counter.value += 1
    return k


def _compile_groups(groups: list, counter, done=None, conn=None) -> None:
    """Compile the groups the shared ``counter`` hands out, until none is left, into the cache:
    the processes take the next one as each finishes (longest first), so none idles while another
    has a queue (recorded times are a poor guide on a busy machine). Per kernel, 1 (0 on a failure:
    that kernel compiles, and fails with its message, at its first call) to ``conn`` or
    added to ``done[0]``. Python's cyclic garbage collector is off meanwhile (as it was after):
    numba makes objects by the million as it compiles, and the collector's passes over them took a
    fifth of the compile's CPU; what they would free is freed by the next collection (or with a
    worker)."""
    collecting = gc.isenabled()
    gc.disable()
    try:
        while (k := _take(counter)) < len(groups):
            for job in groups[k]:
                try:
                    _compile(job["module"], job["name"], job["signatures"])
                    ok = 1
                except Exception:  # noqa: BLE001 - it fails again, with its message, when the run calls it
                    ok = 0
                if conn is not None:
                    conn.send(ok)
                else:
                    done[0] += 1
    finally:
        if collecting:
            gc.enable()


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def _compile_share(groups: list, counter, conn) -> None:
    """A warm-up worker: :func:`_compile_groups`, reporting to ``conn``. Ctrl-C ends it silently
    (the parent reports it)."""
    signal.signal(signal.SIGINT, lambda *_: os._exit(130))
    for module in sorted({job["module"] for group in groups for job in group}):
        __import__(module)
    load(warm=False)
    _compile_groups(groups, counter, conn=conn)
    conn.close()


def warm_up(entries: list, progress=None, processes: int | None = None) -> int:
    """Compile the kernels of ``entries`` (kernels.json's) into numba's cache, in this process and in
    ``processes - 1`` workers (default: one per core), if the cache holds none of them: the
    cheapest is compiled (or loaded) first, here, and a cache hit means a warm cache (nothing more
    is done). ``progress(done, total)`` hears of each kernel, and again every 0.5 s while one
    compiles. Returns the number of kernels compiled (0 when the cache was warm)."""
    import numba  # noqa: F401 (loaded by load())

    jobs = [e for e in entries if (e["module"], e["name"]) in _KERNELS]
    if not jobs:
        return 0
    cheapest = min(range(len(jobs)), key=lambda k: jobs[k]["seconds"])
    jobs.insert(0, jobs.pop(cheapest))
    probe = _compile(jobs[0]["module"], jobs[0]["name"], jobs[0]["signatures"])
    stats = getattr(probe, "stats", None)
    if stats is None or not sum(stats.cache_misses.values()):
        return 0
    groups = _groups(jobs[1:])
    done, stop = [1, 0], threading.Event()  # kernels compiled here (the probe too), by the workers
    context = multiprocessing.get_context("fork" if "fork" in multiprocessing.get_all_start_methods() else None)
    counter = context.Value("i", 0)
    workers = []
    try:
        for _ in range(max(1, min(processes or _cores(), len(groups))) - 1):
            recv, send = context.Pipe(duplex=False)
            worker = context.Process(target=_compile_share, args=(groups, counter, send), daemon=True)
            gc.freeze()  # a forked worker's collections skip what it inherits (as pool.start_pool's)
            try:
                worker.start()
            finally:
                gc.unfreeze()
            send.close()
            workers.append((worker, recv))
        reporter = threading.Thread(target=_report, args=(workers, done, len(jobs), progress, stop), daemon=True)
        reporter.start()
        _compile_groups(groups, counter, done=done)
        for worker, _recv in workers:
            worker.join()
    finally:
        stop.set()
        for worker, _recv in workers:
            if worker.is_alive():
                worker.terminate()
                worker.join()
    reporter.join()
    if progress is not None:
        progress(len(jobs), len(jobs))
    return len(jobs)


def _report(workers, done: list, total: int, progress, stop) -> None:
    """The warm-up's reporter thread: counts the workers' kernels into ``done[1]`` and calls
    ``progress`` every 0.5 s until ``stop``."""
    started = time.monotonic()
    while not stop.wait(0.5 if time.monotonic() - started > 0.5 else 0.1):
        for _worker, recv in workers:
            try:
                while recv.poll():
                    done[1] += recv.recv()
            except (EOFError, OSError):
                pass
        if progress is not None:
            progress(min(sum(done), total - 1), total)
