"""Planning: Toolpath -> Trajectory.

``plan(toolpath, printer)`` splits the toolpath into runs (consecutive working moves with one
tool state) and travels (:mod:`.jobs`), plans every run time-optimally in joint space
(:mod:`.topp`) and every travel with ruckig or as straight moves (:mod:`.travel`), in parallel
processes (:mod:`.scheduler`), and returns a :class:`~.trajectory.Trajectory`;
``plan_stream`` does the same for a toolpath handed over in chunks. Both build one
:class:`~.context.PlanContext` and plan through :func:`_plan_time_optimal`.
``planner="trapezoid"`` gives the conventional Cartesian planner instead (:mod:`.trapezoid`),
made safe for the joint limits.
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np

from ..errors import DeltasliceError, ToolpathWarning, UnreachableError
from ..pool import resolve_workers
from ..toolpath import Toolpath, unit_notes
from . import scheduler
from .context import SOLVERS, SPEED_LIMITS, PlanContext
from .jobs import (LASER_ROLES, end_events, job_chunks, job_toolpath, moves_anything, printed_top, split_runs,
                   stream_jobs, toolpath_jobs)
from .pieces import Piece
from .spool import SPOOL_MOVES, PieceSpool
from .tolerances import JOINT_RANGE, NO_MOTION
from .trajectory import Trajectory
from .travel import from_rest, to_rest

__all__ = ["plan", "plan_stream", "Piece", "Trajectory", "split_runs", "check_reachable", "PlanContext"]


def check_reachable(toolpath: Toolpath, printer, hint: bool = True) -> None:
    """Raise UnreachableError naming the layer and position of the first point outside the work
    envelope (below the bed, above max_height or off the bed: ``printer.bed.contains``) or out of
    reach; hint: say whether the part would fit centred (False for a stretch of a part, which
    cannot tell: then only that --center exists)."""
    kin = printer.kinematics()
    pts = np.concatenate([toolpath.start[None], toolpath.xyz])
    ok = printer.bed.contains(pts)
    ok[ok] = kin.reachable(pts[ok])
    if ok.all():
        return
    i = int(np.flatnonzero(~ok)[0])
    layer = int(toolpath.layer[max(i - 1, 0)]) if len(toolpath) else 0
    p = pts[i]
    where = f"layer {layer}: x = {p[0]:.2f}, y = {p[1]:.2f}, z = {p[2]:.2f} mm"
    lo, hi = printer.bed.z_limits()
    if not lo <= p[2] <= hi:  # no placement on the bed moves a point back into the z range
        raise UnreachableError(f"{where} is outside the work envelope of {printer.name}: {printer.bed.outside(p)}")
    if not kin.reachable(p[None])[0]:
        problem = f"is out of reach of {printer.name} ({_why_unreachable(kin, p)})"
    else:
        problem = f"is outside the work envelope of {printer.name}: {printer.bed.outside(p)}"
    from ..toolpath import fits_centred

    if not hint:
        hint = "; if the file was placed for another bed, --center (center=True) moves it to this one's centre"
    elif fits_centred(toolpath, printer):
        hint = "; the part would fit centred on the bed: use --center (center=True)"
    else:
        hint = "; it would not fit centred on the bed either"
    raise UnreachableError(f"{where} {problem}{hint}")


def _why_unreachable(kin, p) -> str:
    """Which of the kinematics' limits the point (3,) mm breaks."""
    q = kin.inverse(p[None])[0]
    if not np.all(np.isfinite(q)):
        return "no real inverse kinematics"
    lo, hi = kin.position_min, kin.position_max
    bad = np.flatnonzero((q < lo - JOINT_RANGE) | (q > hi + JOINT_RANGE))
    if bad.size:
        j = int(bad[0])
        return f"joint {j + 1} would be at {q[j]:.4g}, outside {lo[j]:.4g}..{hi[j]:.4g}"
    if kin.condition(q[None])[0] >= kin.singularity_limit:
        return f"too close to a singularity (Jacobian condition {kin.condition(q[None])[0]:.0f})"
    return "beyond a mechanical limit (ball-joint tilt)"


def _counting_dropped(progress, dropped: int, total: int):
    """``progress`` (callable(done, total) or None) called in the moves of the toolpath given to
    :func:`plan`, counting the ``dropped`` moves :func:`.jobs.job_toolpath` replaced as done."""
    if progress is None or dropped == 0:
        return progress
    return lambda done, _n: progress(done + dropped, total)


def _link_feed(ctx: PlanContext, fastest: float) -> float:
    """The feed (mm/s) of the moves from the rest pose and back to it under the feed speed limit:
    the travel speed, no faster than ``fastest``: the fastest feed the toolpath asks for before
    its first extrusion (from rest), in all (back to rest)."""
    return float(min(ctx.travel_speed, fastest))


def _check_tool(toolpath: Toolpath, printer) -> None:
    """Refuse a toolpath made for the other kind of tool: filament for a laser, laser burns for
    an extruder (the channel would carry a meaning its player does not have); and one that
    retracts the filament further than ``[tool] max_retract_length``."""
    laser_moves = np.isin(toolpath.role, LASER_ROLES)
    if not printer.tool.takes_filament and np.any(toolpath.e[toolpath.working] > 0):
        raise DeltasliceError(f"the toolpath extrudes filament but {printer.name} has a laser: "
                              "slice it for an extruder printer, or give the laser an image, an SVG or laser G-code")
    if not printer.tool.takes_laser_power and laser_moves.any():
        raise DeltasliceError(f"the toolpath has {int(laser_moves.sum())} laser moves but {printer.name} has an extruder")
    # how far the filament is pulled back from the most it was pushed (retractions in a row add up),
    # as the G-code reader measures it line by line; a stretch of a print (plan_stream) from its own start
    pushed = np.cumsum(toolpath.e)
    back = np.maximum.accumulate(np.maximum(pushed, 0.0)) - pushed
    if len(back) and back.max() > printer.tool.max_retract_length:
        i = int(np.argmax(back > printer.tool.max_retract_length))
        raise DeltasliceError(
            f"layer {int(toolpath.layer[i])}: the toolpath retracts the filament {back[i]:.2f} mm from where it last "
            f"extruded, more than {printer.name}'s [tool] max_retract_length = {printer.tool.max_retract_length:g} mm")


def plan(toolpath: Toolpath, printer, *, speed_limit="feed", planner="toppra", workers=None, progress=None,
         solver="fast", spool=None) -> Trajectory:
    """Plan a toolpath for a printer.

    speed_limit: "feed" obeys the toolpath's feed rates; "machine" only the actuators' limits.
    planner: "toppra" (time-optimal, joint space) or "trapezoid" (conventional, made safe).
    workers: processes for the runs and travels (default: all cores). progress: callable(done, total)
    or None, in moves of the toolpath.
    solver: "fast" (:mod:`.reachability`, compiled) or "toppra" (toppra's seidel solver, the
    reference), for the time-optimal planner's runs and travels.
    spool: keep the planned pieces in a temporary file rather than in memory (:mod:`.spool`);
    None: for toolpaths of more than ``SPOOL_MOVES`` moves. Memory is then bounded by what is
    planned at once (a run, or a window of a long run), not by the print.
    """
    if not isinstance(toolpath, Toolpath):
        raise DeltasliceError(f"plan: toolpath: expected a Toolpath, got {type(toolpath).__name__}")
    _check_options("plan", printer, speed_limit, planner, solver, workers, progress)
    if spool is not None and not isinstance(spool, bool):
        raise DeltasliceError(f"plan: spool = {spool!r}: expected True, False or None")
    if len(toolpath) == 0:
        raise DeltasliceError("the toolpath has no moves: nothing to plan")
    if not moves_anything(toolpath):
        raise DeltasliceError(f"the toolpath's {len(toolpath)} move(s) have zero length and no extrusion: nothing to plan")
    _check_tool(toolpath, printer)
    for note in unit_notes(toolpath):
        warnings.warn(note, ToolpathWarning, stacklevel=2)
    ctx = PlanContext.of(printer, speed_limit, solver)
    source = _Whole(ctx, printer, toolpath)
    if planner == "trapezoid":
        return _plan_trapezoid(ctx, printer, source, progress, resolve_workers(workers, "plan"))
    if spool is None:
        spool = len(source.toolpath) > SPOOL_MOVES
    progress = _counting_dropped(progress, len(toolpath) - len(source.toolpath), len(toolpath))
    return _plan_time_optimal(printer, ctx, source, workers, progress, PieceSpool() if spool else [])


def plan_stream(chunks, printer, *, moves: int | None = None, speed_limit="feed", workers=None, progress=None,
                solver="fast") -> Trajectory:
    """Plan a toolpath handed over in consecutive chunks, holding a few of them at a time: a G-code
    of millions of moves read a stretch at a time (:func:`deltaslice.gcode.open_gcode`) is never
    held whole. The time-optimal planner, as :func:`plan` gives it; the pieces are kept on disk.

    chunks: an iterable of Toolpaths, each starting where the one before ends, layers numbered
    through the print (every chunk's layer_z the print's), events indexed within their chunk.
    moves: the moves in all chunks (for progress), or None. The other options are :func:`plan`'s.

    Each chunk's last run or travel is planned with the next chunk's moves (it may go on there),
    so the jobs are those of the chunks joined, and a run of at most STREAM_RUN moves is planned
    exactly as :func:`plan` plans it (the jobs go to the workers CHUNK_MAX at a time, as those of a
    print of more than 8 * CHUNK_MAX jobs do: a smaller print planned whole batches its travels
    otherwise, which moves their last bits). A run longer than that which goes on past a chunk is planned
    window by window as its stretches come (:func:`.topp.iter_run_parts`): its merging and
    blending differ from the whole run's at the stretches' ends only (its duration within 0.1 %).
    A point out of reach is found when its chunk comes, after what is before it is planned."""
    _check_options("plan_stream", printer, speed_limit, "toppra", solver, workers, progress)
    if moves is not None and (not isinstance(moves, (int, np.integer)) or moves < 0):
        raise DeltasliceError(f"plan_stream: moves = {moves!r}: expected a count of moves or None")
    source = _Streamed(PlanContext.of(printer, speed_limit, solver), printer, chunks, moves)
    if progress is not None:
        report, lead = progress, source.lead
        progress = lambda done, total: report(done + lead["dropped"], total)  # noqa: E731
    return _plan_time_optimal(printer, source.ctx, source, workers, progress, PieceSpool())


def _plan_time_optimal(printer, ctx: PlanContext, source, workers, progress, pieces) -> Trajectory:
    """The time-optimal plan of a print (:class:`_Whole` or :class:`_Streamed`): the move from
    rest, its jobs (:mod:`.scheduler`) into ``pieces`` (a list or a PieceSpool), the move to rest,
    as a Trajectory timing the print's events."""
    planner = scheduler.Scheduler(ctx, pieces, source.n_moves, progress, first=source.head(pieces),
                                  toolpath=source.toolpath)
    job_start, job_piece = planner.run(source.jobs(), source.chunk, source.few, workers)
    tail = source.tail()
    events, n_moves = source.events()
    return _trajectory(printer, pieces, tail, ctx.speed_limit, job_start, job_piece, events, n_moves)


class _Whole:
    """A whole toolpath's plan: its jobs made in the workers from the toolpath they inherit, in
    chunks of an eighth of the print; the moves from and to rest planned (after every point's
    reach is checked) while the workers start on the first chunks."""

    def __init__(self, ctx: PlanContext, printer, given: Toolpath):
        self.ctx, self.printer, self.given = ctx, printer, given
        self.toolpath, self.lead_feed = job_toolpath(given, ctx.tool)
        self.laser = ctx.tool.takes_laser_power
        self.ranges = split_runs(self.toolpath, self.laser)
        n_jobs = 2 * len(self.ranges) + 1  # at most: a travel before every run, one after the last
        self.chunk, self.few = scheduler.chunk_size(n_jobs), n_jobs < scheduler.FEW_JOBS
        self.n_moves = len(self.toolpath)
        self._tail = None

    def rest_links(self) -> tuple[list, list]:
        """Check every point's reach (of the toolpath as given: its points hold the job's, and an
        error names its layers and says whether centring it would help), then plan the moves from
        the rest pose and back to it (every trajectory starts at the machine's rest pose and parks
        there at the end)."""
        ctx, toolpath = self.ctx, self.toolpath
        check_reachable(self.given, self.printer)
        return (from_rest(ctx, toolpath.start, feed=_link_feed(ctx, self.lead_feed)),
                to_rest(ctx, toolpath.xyz[-1], top=printed_top(toolpath), feed=_link_feed(ctx, toolpath.feed.max())))

    def head(self, pieces):
        """What the scheduler runs once the workers have their first chunks: the rest links."""

        def first():
            head, self._tail = self.rest_links()
            pieces.extend(head)

        return first

    def jobs(self):
        return toolpath_jobs(self.toolpath, self.ranges, self.laser)

    def tail(self) -> list:
        return self._tail

    def events(self) -> tuple[np.ndarray, int]:
        """The events (the toolpath's, indexed in its moves) and the number of moves."""
        return self.toolpath.events, len(self.toolpath)


class _Streamed:
    """A print handed over in chunks: each checked as it comes (a Toolpath, starting where the one
    before ends, for this tool, within reach), its jobs made here (:func:`.jobs.stream_jobs`) and
    handed to the workers CHUNK_MAX at a time; the move from rest planned first."""

    few = False
    toolpath = None

    def __init__(self, ctx: PlanContext, printer, chunks, moves: int | None):
        self.ctx, self.printer, self.n_moves = ctx, printer, moves
        self.chunk = scheduler.chunk_size(None)
        self.moves, self.last, self.motion, self.top, self.feed = 0, None, False, -np.inf, 0.0
        self.event_rows = []
        self.lead = {"dropped": 0}
        self.stream = self._checked(job_chunks(chunks, ctx.tool, self.lead))
        self.first = next(self.stream, None)
        if self.first is None:
            raise DeltasliceError("the toolpath has no moves: nothing to plan")

    def _checked(self, chunks):
        for tp in chunks:
            if not isinstance(tp, Toolpath):
                raise DeltasliceError(f"plan_stream: chunks: expected Toolpaths, got {type(tp).__name__}")
            if not len(tp):
                continue
            if self.last is not None and not np.allclose(tp.start, self.last, rtol=0, atol=NO_MOTION):
                raise DeltasliceError(f"plan_stream: the chunk at move {self.moves} starts at {tp.start.tolist()}, "
                                      f"not where the one before ends ({self.last.tolist()})")
            _check_tool(tp, self.printer)
            check_reachable(tp, self.printer, hint=False)
            self.motion = self.motion or moves_anything(tp)
            self.top = max(self.top, printed_top(tp))
            self.feed = max(self.feed, float(tp.feed.max()))
            ev = tp.events.copy()
            ev["index"] += self.moves
            self.event_rows.append(ev)
            self.moves += len(tp)
            self.last = tp.xyz[-1]
            yield tp

    def head(self, pieces):
        """The move from rest, planned now: nothing to run once the workers start."""
        pieces.extend(from_rest(self.ctx, self.first.start, feed=_link_feed(self.ctx, self.lead["feed"])))
        return None

    def jobs(self):
        return stream_jobs(itertools.chain([self.first], self.stream), self.ctx.tool.takes_laser_power)

    def tail(self) -> list:
        if not self.motion:
            raise DeltasliceError(f"the toolpath's {self.moves} move(s) have zero length and no extrusion: nothing to plan")
        return to_rest(self.ctx, self.last, top=self.top, feed=_link_feed(self.ctx, self.feed))

    def events(self) -> tuple[np.ndarray, int]:
        return np.concatenate([*self.event_rows, end_events(self.ctx.tool, self.moves)]), self.moves


def _plan_trapezoid(ctx: PlanContext, printer, source: _Whole, progress, workers: int) -> Trajectory:
    """The conventional planner, made safe (:func:`.trapezoid.plan_safe`, its peak checks sampled by
    ``workers`` processes), between the rest links."""
    from .trapezoid import _moves, plan_safe

    toolpath = source.toolpath
    head, tail = source.rest_links()
    traj = plan_safe(toolpath, printer, speed_limit=ctx.speed_limit, progress=progress, head=head, tail=tail,
                     workers=workers)
    # one trapezoid per kept move: move m starts at t0[number of kept moves before m]
    kept_before = np.concatenate([[0], np.cumsum(_moves(toolpath)[-1])])
    t0 = traj.pieces[len(head)].t0
    times = t0[np.minimum(kept_before[toolpath.events["index"]], len(t0) - 1)]
    traj.events = _at_rest(toolpath.events["index"], len(toolpath), _event_times(toolpath.events, times),
                           sum(p.duration for p in head), traj.duration - sum(p.duration for p in tail))
    return traj


def _check_options(caller, printer, speed_limit, planner, solver, workers, progress) -> None:
    """Refuse what is not a loaded Printer with its reach checked, and options the planner does not know."""
    from ..machine import Printer

    if not isinstance(printer, Printer):
        raise DeltasliceError(
            f"{caller}: printer: expected a loaded Printer (deltaslice.load_printer(path)), got {type(printer).__name__} {printer!r:.60}")
    if not printer.reach_checked:
        raise DeltasliceError(f"{caller}: printer {printer.name} was loaded with reach_checks=False: plan with "
                              "deltaslice.machine.check_reach(printer) instead (the printer it returns has its rest "
                              "pose set and its reach checked)")
    if speed_limit not in SPEED_LIMITS:
        raise DeltasliceError(f"speed_limit must be 'feed' or 'machine', not {speed_limit!r}")
    if planner not in ("toppra", "trapezoid"):
        raise DeltasliceError(f"planner must be 'toppra' or 'trapezoid', not {planner!r}")
    if solver not in SOLVERS:
        raise DeltasliceError(f"solver must be one of {', '.join(SOLVERS)}, not {solver!r}")
    resolve_workers(workers, caller)
    if progress is not None and not callable(progress):
        raise DeltasliceError(f"{caller}: progress: expected a callable(done, total) or None, got {type(progress).__name__}")


def _at_rest(index: np.ndarray, n: int, events: tuple, offset: float, end: float) -> tuple:
    """Events timed within the toolpath's own motion, moved onto the whole trajectory: those
    before the first move happen at t = 0, at the rest pose (a heater warms up and a wait holds
    there, not over the bed); those after the last move at ``end`` (s), the last move's end,
    before the tool lifts clear and parks (heaters, fan and laser off first); the rest shift by
    ``offset`` (s). index: (m,) the events' move indices; n: the toolpath's moves."""
    return tuple(
        (0.0 if i == 0 else end if i >= n else t + offset, k, v)
        for (t, k, v), i in zip(events, index.tolist())
    )


def _trajectory(printer, pieces, tail, speed_limit, job_start, job_piece, events, n_moves: int) -> Trajectory:
    """The planned pieces with the tail, as a Trajectory timing the toolpath's ``events`` (indices
    into its ``n_moves`` moves) from each job's first move and first piece."""
    if len(job_piece) == 0 or len(pieces) == job_piece[0]:
        raise DeltasliceError("the toolpath never moves the tool or the filament: nothing to plan")
    pieces.extend(tail)
    traj = Trajectory(printer, pieces, planner="toppra", speed_limit=speed_limit)
    moves = np.append(job_start, n_moves)
    piece_at = np.append(job_piece, len(pieces) - len(tail))
    ev = events["index"]
    k = piece_at[np.searchsorted(moves, ev, side="right") - 1]
    parked = traj.duration - sum(p.duration for p in tail)  # the last move's end, before the lift and park
    times = np.where(ev >= n_moves, parked, traj.starts[np.minimum(k, len(pieces))])
    traj.events = _at_rest(ev, n_moves, _event_times(events, times), 0.0, parked)
    return traj


def _event_times(ev: np.ndarray, times) -> tuple:
    """((time_s, kind, value), ...) of the events ``ev`` (a toolpath's) at the given times (s), in order.
    An event inside a move range (a travel, or a run not cut by a wait) fires at the range's start."""
    return tuple((float(t), int(k), float(v)) for t, k, v in zip(np.asarray(times, float).tolist(), ev["kind"], ev["value"]))
