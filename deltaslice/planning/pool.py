"""Process pools for planning and sampling, started with the garbage collector frozen.

A forked worker inherits the parent's objects (numba's and llvmlite's compiled-code graphs, the
toolpath, the planned pieces). Its collections would walk all of them, and touching their headers
copies the pages they live on, so each worker would pay in time and memory for what it only reads.
Freezing the collector while the workers fork keeps those objects out of the workers' collections
(Python's advice for fork without exec, ``gc.freeze``); the parent unfreezes at once, unchanged.
"""

from __future__ import annotations

import gc
from concurrent.futures import ProcessPoolExecutor


def start_pool(workers: int, mp_context=None, initializer=None, initargs=()) -> ProcessPoolExecutor:
    """A ProcessPoolExecutor of ``workers`` processes, started now. With the fork start method
    (Linux's default) every worker forks at the first task, which runs here with the collector
    frozen; with spawn the freeze costs nothing and changes nothing."""
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
