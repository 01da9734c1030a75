"""The Trajectory: planned pieces end to end, sampled on demand.

Pieces (runs, travels, retracts) start and end at rest (a long run's windows join at speed)
and know their duration and how to give joint positions, filament and tool state at any time
inside them. The trajectory stores only the pieces (grids and profiles, about a kilobyte a move;
on disk, :mod:`.spool`, for a long print), and samples them block by block at the output rate,
so a long print streams to disk without holding its samples in memory.
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass, field

import numpy as np

from ..pool import can_fork, forked_map, inherited
from ..samples import Samples
from .context import PlanContext
from .spool import PieceSpool
from .tolerances import SAMPLE_TIME

BLOCK = 8192  # samples per block handed to emitters
# Sampling in worker processes pays for itself from this many blocks (about 2 minutes at 1 kHz):
# a forked pool costs some tens of milliseconds to start.
PARALLEL_BLOCKS = 16
TASK_BLOCKS = 8  # blocks per task handed to a sampling worker
SAMPLE_AHEAD = 3  # tasks in flight per sampling worker (two left it waiting for the writer)


@dataclass
class Trajectory:
    """Pieces end to end (see :mod:`.pieces`), for one printer; ``info``: planner details.
    ``pieces``: a list, or a :class:`~.spool.PieceSpool` for a long print (read back in order)."""

    printer: object
    pieces: list
    planner: str = "toppra"
    speed_limit: str = "feed"
    e_start: float = 0.0
    info: dict = field(default_factory=dict)
    #: ((time_s, kind, value), ...): heater, fan and laser events (toolpath.EventKind), in order;
    #: a wait event holds the time base (the player resumes after the heater is ready).
    events: tuple = ()

    def __post_init__(self):
        self.kin = self.printer.kinematics()
        if isinstance(self.pieces, PieceSpool):  # what it keeps per piece, without reading the pieces back
            self.durations = np.asarray(self.pieces.durations, dtype=float)
            filament = np.asarray(self.pieces.filament_totals, dtype=float)
        else:
            self.durations = np.array([p.duration for p in self.pieces], dtype=float)
            filament = np.array([p.filament_total for p in self.pieces], dtype=float)
        self.starts = np.concatenate([[0.0], np.cumsum(self.durations)])
        self.e_offsets = self.e_start + np.concatenate([[0.0], np.cumsum(filament)])

    @property
    def duration(self) -> float:
        return float(self.starts[-1])

    def metadata(self) -> dict:
        return {"planner": self.planner, "speed_limit": self.speed_limit, "duration_s": f"{self.duration:.6f}"}

    def sample_at(self, t: np.ndarray, out: tuple | None = None) -> Samples:
        """Samples at absolute times t (s, sorted). Times past the end hold the last pose.
        out: (q (n,J), e (n,), tool (n,)) C-contiguous float64 arrays written in place of new ones
        (a sampling worker's slot: its samples are not copied there)."""
        t = np.asarray(t, dtype=float)
        n = len(t)
        if out is None:
            q, e, tool = np.empty((n, self.kin.n_joints)), np.empty(n), np.zeros(n)
        else:
            q, e, tool = out
            tool.fill(0.0)
        for i, lo, hi in self._piece_ranges(t):
            self.pieces[i].sample_into(self.kin, t[lo:hi] - self.starts[i], q[lo:hi], e[lo:hi], tool[lo:hi])
            e[lo:hi] += self.e_offsets[i]
        return Samples(t, q, e, tool)

    def _piece_ranges(self, t: np.ndarray):
        """(piece, lo, hi) for each piece holding samples t[lo:hi] (t sorted): piece k holds the
        times from starts[k] to before starts[k + 1]; the first piece also those before it and the
        last those after the end. Where t is in order, from the pieces' starts found in t (a
        block spans a few pieces), not every time among the starts."""
        n, last = len(t), len(self.pieces) - 1
        if n and np.all(t[1:] >= t[:-1]):
            first, end = np.clip(np.searchsorted(self.starts, t[[0, -1]], side="right") - 1, 0, last)
            bounds = np.searchsorted(t, self.starts[first + 1 : end + 1], side="left")
            k = np.arange(first, end + 1)
            lo, hi = np.concatenate([[0], bounds]), np.concatenate([bounds, [n]])
        else:
            kk = np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0, last)
            cut = np.flatnonzero(kk[1:] != kk[:-1]) + 1
            lo, hi = np.concatenate([[0], cut]), np.concatenate([cut, [n]])
            k = kk[lo]
        return [(int(i), int(a), int(b)) for i, a, b in zip(k, lo, hi) if b > a]

    def iter_samples(self, rate: float | None = None, block: int = BLOCK, workers: int = 1, transient: bool = False):
        """Blocks of Samples at ``rate`` Hz (default: the printer's output rate), from t = 0
        through the end (the last sample is at or after the end, holding the final pose).

        workers: processes sampling blocks ahead while the caller consumes them (forked, so they
        share the planned pieces without copying them; where the platform cannot fork, and for
        short trajectories, the blocks are sampled here). The blocks are the same either way
        (``transient`` ones: their samples).
        transient: for a consumer done with each block before it takes the next (the writers):
        the workers' blocks are views of buffers they write again once the next block is asked
        for (no copy of every sample), and a task's TASK_BLOCKS blocks come as one (an eighth of
        the writers' per-block work); the same samples in the same order."""
        rate = rate or self.printer.planning.output_rate
        n_total = int(np.ceil(self.duration * rate - SAMPLE_TIME)) + 1
        if workers > 1 and n_total > PARALLEL_BLOCKS * block and can_fork():
            yield from self._forked_blocks(rate, block, n_total, workers, transient)
            return
        for i0 in range(0, n_total, block):
            yield self._block(i0, min(i0 + block, n_total), rate)

    def _block(self, i0: int, i1: int, rate: float) -> Samples:
        return self.sample_at(_times(i0, i1, rate))

    def _forked_blocks(self, rate: float, block: int, n_total: int, workers: int, transient: bool = False):
        """iter_samples' blocks sampled by ``workers`` forked processes, TASK_BLOCKS blocks a task.

        The workers write their samples into slots of anonymous shared mappings and hand back
        only the slot: pickled through a pipe, 40 bytes a sample cost the reader more than the
        sampling saved. forked_map keeps SAMPLE_AHEAD * workers tasks in flight and submits the next
        one before yielding a result, so one slot more never hands a task a slot still read here:
        a task's slot is handed on only once the block after its last is asked for. The workers
        write the times too, so this process allocates nothing a block. Each block is copied out
        of its slot (the blocks are the very arrays _block gives), or with ``transient`` the
        task's rows of the slot are one block, a view."""
        if isinstance(self.pieces, PieceSpool):
            self.pieces.sync()  # the workers read the spool file as it is now
        span = block * TASK_BLOCKS
        n_slots = SAMPLE_AHEAD * workers + 1
        t, q, e, tool = (
            np.frombuffer(mmap.mmap(-1, n_slots * span * w * 8), dtype=np.float64).reshape(n_slots, span, w)
            for w in (1, self.kin.n_joints, 1, 1))
        tasks = ((i0, min(i0 + span, n_total), rate, k % n_slots)
                 for k, i0 in enumerate(range(0, n_total, span)))
        for i0, i1, k in forked_map(_sample_task, tasks, workers, in_flight=SAMPLE_AHEAD, trajectory=self,
                                    slots=(t, q, e, tool)):
            if transient:
                yield Samples(t[k, : i1 - i0, 0], q[k, : i1 - i0], e[k, : i1 - i0, 0], tool[k, : i1 - i0, 0])
                continue
            for a in range(i0, i1, block):
                rows = slice(a - i0, min(a + block, i1) - i0)
                block_slots = (t[k, rows, 0], q[k, rows], e[k, rows, 0], tool[k, rows, 0])
                yield Samples(*(block_slots if transient else (v.copy() for v in block_slots)))

    def samples(self, rate: float | None = None) -> Samples:
        """All samples at once (tests and small parts; long prints should use iter_samples)."""
        return Samples.concatenate(list(self.iter_samples(rate)))

    @property
    def active_fraction(self) -> float:
        """Fraction of the duration with at least one limit active, from the planner's own
        solution (toppra stages at a velocity or acceleration bound; ruckig and retract
        profiles are bang-bang and always at a bound)."""
        if self.duration <= 0:
            return 0.0
        if isinstance(self.pieces, PieceSpool):
            return float(sum(self.pieces.active_times) / self.duration)
        return float(sum(p.active_time for p in self.pieces) / self.duration)

    def piece_counts(self) -> dict:
        """{kind: count} of the pieces."""
        kinds = self.pieces.kinds if isinstance(self.pieces, PieceSpool) else [p.kind for p in self.pieces]
        out: dict = {}
        for k in kinds:
            out[k] = out.get(k, 0) + 1
        return out

    def stage_maxima(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds on the continuous motion of every toppra piece (runs and Cartesian travels),
        from each piece's own derivatives stage by stage (:func:`.stages.stage_maxima`): per
        joint, the peak velocity and acceleration as fractions of the printer's limits.
        (J,), (J,)."""
        from .pieces import RunPiece
        from .stages import run_stage_maxima

        J = self.printer.n_joints
        limits = PlanContext.of(self.printer).machine_limits
        vmax, amax = limits.velocity[:J], limits.acceleration[:J]
        pv, pa = np.zeros(J), np.zeros(J)
        for p in self.pieces:
            if isinstance(p, RunPiece) and len(p.x) > 1:
                m = run_stage_maxima(p, self.kin, vmax, amax)
                pv, pa = np.maximum(pv, m.velocity), np.maximum(pa, m.acceleration)
        return pv, pa


def _times(i0: int, i1: int, rate: float) -> np.ndarray:
    """The times (i1 - i0,) s of samples i0..i1-1 at ``rate`` Hz: the one definition of the time base
    that blocks sampled here and in the workers share."""
    return np.arange(i0, i1) / rate


def _sample_task(i0: int, i1: int, rate: float, k: int) -> tuple[int, int, int]:
    """In a forked sampling worker: samples i0..i1 of the inherited trajectory, in one pass,
    written into slot k of the inherited shared ``slots`` (t (slots, span, 1), q (slots, span, J),
    e and tool (slots, span, 1)). Returns (i0, i1, k)."""
    traj, (t, q, e, tool) = inherited("trajectory"), inherited("slots")
    n = i1 - i0
    t[k, :n, 0] = _times(i0, i1, rate)
    # sampled straight into the slot (a sample's values do not depend on the block it is sampled in)
    traj.sample_at(t[k, :n, 0], out=(q[k, :n], e[k, :n, 0], tool[k, :n, 0]))
    return i0, i1, k
