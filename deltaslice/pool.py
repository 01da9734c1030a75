"""Process pools for slicing, planning and sampling, started with the garbage collector frozen.

A forked worker inherits the parent's objects (numba's and llvmlite's compiled-code graphs, the
toolpath, the planned pieces). Its collections would walk all of them, and touching their headers
copies the pages they live on, so each worker would pay in time and memory for what it only reads.
Freezing the collector while the workers fork keeps those objects out of the workers' collections
(Python's advice for fork without exec, ``gc.freeze``); the parent unfreezes at once, unchanged.
"""

from __future__ import annotations

import ctypes
import gc
import multiprocessing
import os
import sys
from collections import deque
from concurrent.futures import ProcessPoolExecutor

from . import interrupt
from .errors import DeltasliceError


def check_workers(workers, where: str, none_ok: bool = False):
    """``workers`` if it is a number of processes (an integer >= 1; or None where ``none_ok``: all
    cores), else DeltasliceError naming ``where`` (the function given it)."""
    if workers is None and none_ok:
        return workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise DeltasliceError(f"{where}: workers = {workers!r}: expected an integer >= 1{' or None' if none_ok else ''}")
    return workers


def resolve_workers(workers, where: str) -> int:
    """The number of processes ``workers`` asks for: itself (checked as :func:`check_workers`
    does), or every core for None."""
    return check_workers(workers, where, none_ok=True) or os.cpu_count() or 1


def start_pool(workers: int, mp_context=None, initializer=None, initargs=()) -> ProcessPoolExecutor:
    """A ProcessPoolExecutor of ``workers`` processes, started now. mp_context: None for fork on
    Linux (Python 3.14 made forkserver the default there: its workers would start from a fresh
    interpreter, without this process's loaded kernels and malloc settings) and the platform's
    default elsewhere. With fork every worker forks at the first task, which runs here with the
    collector frozen; with spawn the freeze costs nothing and changes nothing."""
    if mp_context is None and sys.platform.startswith("linux"):
        mp_context = multiprocessing.get_context("fork")
    pool = ProcessPoolExecutor(workers, mp_context=mp_context, initializer=initializer, initargs=initargs)
    gc.freeze()
    try:
        pool.submit(int).result()
    except BaseException:
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    finally:
        gc.unfreeze()
    return pool


# glibc's mallopt parameters (malloc.h) and the values keep_freed_memory sets
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20  # up to this size from the heap (the cap of glibc's own growing threshold)
TRIM_THRESHOLD = 64 << 20  # an arena's top is given back once this much of it is free


def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed memory for the next allocations of this process and of the
    workers it forks. By default an array over 128 KB is mapped on its own and unmapped when
    freed (the threshold then grows with the arrays freed) and the heap's top is given back past
    128 KB free (twice the grown threshold), so the planning workers' kernels would write into
    fresh pages the kernel zeroes, a page fault each. Here arrays up to 32 MB come from the heap
    and at most 64 MB free at the top of each arena (the main one and each thread's) is kept, per
    process: each process can hold up to 64 MB more than it uses. For the console script,
    which owns its process (its pools fork: :func:`start_pool`); a program that imports deltaslice
    keeps its own allocator settings. Returns whether the settings were taken (False without
    glibc: other systems have no mallopt; musl's ignores them)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))


_INHERITED: dict = {}  # what forked_map's workers inherit, set only while they fork


def can_fork() -> bool:
    """Whether worker processes can be forked here (not on Windows; macOS's default is spawn)."""
    return "fork" in multiprocessing.get_all_start_methods()


def inherited(name: str):
    """In a worker of :func:`forked_map`: the object the parent passed as ``name``."""
    return _INHERITED[name]


def forked_map(fn, tasks, workers: int, *, started=None, in_flight: int = 2, **inherit):
    """``fn(*task)`` for every task (an iterable of argument tuples) in ``workers`` forked
    processes, the results yielded in task order, at most ``in_flight`` tasks per worker in flight
    (memory bounded by what is in flight). started: a callable run here once the first tasks are
    submitted (what it raises stops the map). ``inherit``: objects the workers read with
    :func:`inherited`, passed by forking (shared, never pickled); the parent keeps no reference to
    them after."""
    tasks = iter(tasks)
    queue = deque()
    _INHERITED.update(inherit)
    try:
        pool = start_pool(workers, mp_context=multiprocessing.get_context("fork"))
    finally:
        _INHERITED.clear()

    def submit():
        task = next(tasks, None)
        if task is not None:
            queue.append(pool.submit(fn, *task))

    try:
        for _ in range(in_flight * workers):
            submit()
        if started is not None:
            with interrupt.beside_workers():
                started()
        while queue:
            result = queue.popleft().result()
            submit()
            yield result
    finally:
        stop_pool(pool)


def stop_pool(pool) -> None:
    """Shut a pool down, its tasks not started dropped: once its running tasks end, or at once after
    a Ctrl-C. A terminal's Ctrl-C reaches the workers too and they leave (:mod:`.interrupt`),
    perhaps halfway through sending a result, and waiting for the executor's thread, which waits
    for the rest of that result, hung the compile. A Ctrl-C that reached this process alone leaves
    the workers blocked on the pool's pipes, which they hold open themselves: they are ended here,
    or they would outlive the command (which leaves with os._exit) and hold its output pipes."""
    if not interrupt.requested():
        pool.shutdown(wait=True, cancel_futures=True)
        return
    pool.shutdown(wait=False, cancel_futures=True)
    for child in multiprocessing.active_children():
        child.terminate()
