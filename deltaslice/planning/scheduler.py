"""The scheduler of a plan's jobs (:class:`.jobs.Job`) across processes: chunks of consecutive
jobs planned in worker processes in print order, at most a few chunks ahead of what has been put
away (memory bounded by what is in flight, not by the print); a long run planned here, window by
window, while the workers go on with what follows it."""

from __future__ import annotations

import itertools
from array import array
from collections import deque

import numpy as np

from ..errors import DeltasliceError
from ..pool import resolve_workers, start_pool, stop_pool
from .batch import plan_runs
from .context import PlanContext
from .jerk import jerk_limited
from .pieces import PieceBatch
from .topp import iter_run, iter_run_parts
from .travel import plan_travels
from .windows import is_long

# Jobs per chunk handed to a worker: an eighth of the print's (small prints still make 8 chunks), at
# most CHUNK_MAX: a chunk's runs and travels are solved in batches, each with a set-up of a few
# milliseconds that a larger chunk shares over more jobs; the cap keeps the last chunk, which one
# worker may plan while the other is done, short.
CHUNKS_PER_PRINT = 8
CHUNK_MAX = 128
WARM_UP_JOBS = 8  # the first chunk's jobs planned in the parent before the pool forks (its kernels)
FEW_JOBS = 8  # fewer jobs than this are planned here: worker processes would not pay


def chunk_size(n_jobs: int | None) -> int:
    """Jobs per chunk for a print of at most ``n_jobs`` jobs (None: a print handed over in chunks,
    whose jobs are not counted ahead). The chunks do not depend on the number of workers: a
    chunk's travels are solved as one batch, so the same chunks give the same bytes whatever
    --workers is."""
    return CHUNK_MAX if n_jobs is None else max(1, min(CHUNK_MAX, n_jobs // CHUNKS_PER_PRINT))


class _Worker:
    """A planning process's state: the plan's context and, where the jobs are made where they are
    planned (:meth:`.jobs.Job.arguments`), the toolpath (inherited by a forked worker, not
    pickled; pickled once to each worker where processes are spawned)."""

    ctx: PlanContext | None = None
    toolpath = None


_WORKER = _Worker()


def init_worker(ctx: PlanContext, toolpath=None) -> None:
    """Set this process's planning state (a pool's initializer; the main process's too)."""
    _WORKER.ctx, _WORKER.toolpath = ctx, toolpath


def plan_chunk(jobs) -> PieceBatch:
    """Plan a chunk of jobs in print order in this process's context: a PieceBatch of one list of
    pieces per job (what a worker hands back)."""
    ctx, toolpath = _WORKER.ctx, _WORKER.toolpath
    laser = ctx.tool.takes_laser_power
    args = [job.arguments(toolpath, laser) for job in jobs]
    out = [None] * len(jobs)
    # The chunk's travels in one batch: their straight moves are solved together.
    travels = [i for i, job in enumerate(jobs) if job.kind == "travel"]
    for i, pieces in zip(travels, plan_travels(ctx, [args[i] for i in travels])):
        out[i] = pieces
    # and its runs: the short ones are solved as batches (batch.plan_runs).
    runs = [i for i, job in enumerate(jobs) if job.kind != "travel"]
    for i, pieces in zip(runs, plan_runs(ctx, [args[i] for i in runs])):
        out[i] = pieces
    return PieceBatch([jerk_limited(ctx, pieces) for pieces in out])


def _slots(jobs, chunk: int):
    """Consecutive jobs grouped for the workers: ("pool", [job, ...]) of at most ``chunk`` jobs, or
    ("here", job) for a long run the main process plans (a run handed over in parts too)."""
    group = []
    for job in jobs:
        if job.kind == "parts" or (job.kind == "run" and is_long(job.end - job.start)):
            if group:
                yield "pool", group
                group = []
            yield "here", job
        else:
            group.append(job)
            if len(group) == chunk:
                yield "pool", group
                group = []
    if group:
        yield "pool", group


def _drain_one(queue, put_away, plan_here) -> int:
    """Put away the oldest slot: a chunk's results (waiting for its worker; returns 1) or a long
    run planned here (0)."""
    item, future = queue.popleft()
    if future is None:
        plan_here(item)
        return 0
    put_away(item, future.result())
    return 1


class Scheduler:
    """Plans jobs into ``pieces`` (a list or a PieceSpool) and records, per job, its first move and
    the index of its first piece. n_moves: the moves in all (for progress), or None; progress:
    callable(done, total) or None; first: a callable run here before anything is put away, once
    the workers have their first chunks (so it costs no time where it raises nothing; where it
    raises, the chunks not yet started are cancelled and the running ones waited for), or None;
    toolpath: the toolpath the jobs made where they are planned come from (the workers inherit
    it), or None."""

    def __init__(self, ctx: PlanContext, pieces, n_moves: int | None, progress, first=None, toolpath=None):
        self.ctx, self.pieces, self.n_moves, self.progress = ctx, pieces, n_moves, progress
        self.first, self.toolpath = first, toolpath
        self.job_start, self.job_piece = array("q"), array("q")
        self.done = 0.0
        self.pool = None

    def run(self, jobs, chunk: int, few: bool, workers) -> tuple[np.ndarray, np.ndarray]:
        """Plan ``jobs`` in chunks of ``chunk``; few: too few jobs for worker processes to pay
        (planned here). Returns per job its first move and the index of its first piece (int64)."""
        workers = resolve_workers(workers, "plan")
        slots = _slots(jobs, chunk)
        # this process plans the warm-up, long runs and, with one worker, everything: its jobs too
        # are made from the toolpath
        init_worker(self.ctx, self.toolpath)
        try:
            if workers == 1 or few:
                self._run_first()
                for where, item in slots:
                    if where == "here":
                        self._plan_here(item)
                    else:
                        self._put_away(item, plan_chunk(item))
            else:
                self._run_pool(self._warmed_up(slots), workers)
        finally:
            _WORKER.toolpath = None  # this process keeps no toolpath once it is planned
        return np.asarray(self.job_start), np.asarray(self.job_piece)

    def _warmed_up(self, slots):
        """The slots, after the first chunk's first jobs are planned here, and dropped, before the
        workers fork: the compiled kernels load in this process once and the workers inherit
        them. Only a few: the chunk itself goes to the workers like the others (the same pieces
        wherever it is planned)."""
        head = next(slots, None)
        if head is None:
            return slots
        if head[0] == "pool":
            try:
                plan_chunk(head[1][:WARM_UP_JOBS])
            except DeltasliceError:
                self._run_first()  # the reach check speaks first, as when the workers plan the chunk
                raise  # the error of the chunk's first job that fails: it is among these
        return itertools.chain([head], slots)

    def _run_pool(self, slots, workers: int) -> None:
        """Plan the slots with ``workers`` processes, at most 4 chunks a worker in flight."""
        ahead = 4 * workers  # chunks in flight; slots queued at most twice that
        queue, in_flight = deque(), 0
        self.pool = start_pool(workers, initializer=init_worker, initargs=(self.ctx, self.toolpath))
        try:
            for where, item in slots:
                if where == "here" and item.kind == "parts":  # its parts are read as it is planned: nothing after it is
                    self._run_first()
                    while queue:
                        _drain_one(queue, self._put_away, self._plan_here)
                    in_flight = 0
                    self._plan_here(item)
                    continue
                future = self.pool.submit(plan_chunk, item) if where == "pool" else None
                queue.append((item, future))
                in_flight += future is not None
                while in_flight > ahead or len(queue) > 2 * ahead:
                    self._run_first()
                    in_flight -= _drain_one(queue, self._put_away, self._plan_here)
            self._run_first()
            while queue:
                _drain_one(queue, self._put_away, self._plan_here)
        finally:
            stop_pool(self.pool)
            self.pool = None

    def _run_first(self) -> None:
        """Run ``first`` once; where it raises, no worker outlives the error (the chunks not
        started are dropped, the ones running finish)."""
        if self.first is None:
            return
        first, self.first = self.first, None
        try:
            first()
        except BaseException:
            if self.pool is not None:
                stop_pool(self.pool)
            raise

    def _report(self, moves: float) -> None:
        self.done += moves
        if self.progress:
            done = int(round(self.done))
            self.progress(min(done, self.n_moves) if self.n_moves else done, self.n_moves)

    def _put_away(self, group, results) -> None:
        """A chunk's pieces, job by job."""
        for job, res in zip(group, results.groups):
            self.job_start.append(job.start)
            self.job_piece.append(len(self.pieces))
            self.pieces.extend(res)
        self._report(group[-1].end - group[0].start)

    def _plan_here(self, job) -> None:
        """A long run (or one handed over in parts) planned here, its pieces put away one by one."""
        spec = job.arguments(self.toolpath, self.ctx.tool.takes_laser_power)
        self.job_start.append(job.start)
        self.job_piece.append(len(self.pieces))
        before = 0.0
        if job.kind == "parts":
            for piece, taken in iter_run_parts(self.ctx, spec):
                self.pieces.append(piece)
                self._report(taken - before)
                before = taken
            return
        for piece, frac in iter_run(self.ctx, spec):
            self.pieces.append(piece)
            self._report((frac - before) * (job.end - job.start))
            before = frac
