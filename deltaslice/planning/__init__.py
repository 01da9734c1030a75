"""Planning: Toolpath -> Trajectory.

``plan(toolpath, printer)`` splits the toolpath into runs (consecutive working
moves with one tool state) and travels, plans every run time-optimally in joint
space with toppra (in parallel processes), every travel with ruckig (or toppra
when the joint-space move would not clear the part), and returns a
:class:`~.trajectory.Trajectory`. ``planner="trapezoid"`` gives the conventional
Cartesian planner instead (:mod:`.trapezoid`), made safe for the joint limits.
"""

from __future__ import annotations

import itertools
import warnings
from array import array
from collections import deque

import numpy as np

from ..errors import DeltasliceError, ToolpathWarning, UnreachableError
from ..pool import resolve_workers, start_pool, stop_pool
from ..toolpath import WAIT_KINDS, EventKind, Role, Toolpath, make_events, unit_notes
from .pieces import Piece, PieceBatch
from .spool import SPOOL_MOVES, PieceSpool
from .topp import SOLVERS, RunSpec, is_long, iter_run, iter_run_parts, plan_runs
from .trajectory import Trajectory
from .jerk import jerk_limited
from .travel import from_rest, plan_travels, to_rest

__all__ = ["plan", "plan_stream", "Piece", "Trajectory", "split_runs", "check_reachable"]

_WORKER = {}
# Jobs per chunk handed to a worker: an eighth of the print's (small prints still make 8 chunks), at
# most CHUNK_MAX: a chunk's runs and travels are solved in batches, each with a set-up of a few
# milliseconds that a larger chunk shares over more jobs; the cap keeps the last chunk, which one
# worker may plan while the other is done, short.
CHUNKS_PER_PRINT = 8
CHUNK_MAX = 128
WARM_UP_JOBS = 8  # the first chunk's jobs planned in the parent before the pool forks (its kernels)
# Moves a run handed over in chunks (plan_stream) gathers before it is planned as its parts come.
STREAM_RUN = 50_000


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
    bad = np.flatnonzero((q < lo - 1e-9) | (q > hi + 1e-9))
    if bad.size:
        j = int(bad[0])
        return f"joint {j + 1} would be at {q[j]:.4g}, outside {lo[j]:.4g}..{hi[j]:.4g}"
    if kin.condition(q[None])[0] >= kin.singularity_limit:
        return f"too close to a singularity (Jacobian condition {kin.condition(q[None])[0]:.0f})"
    return "beyond a mechanical limit (ball-joint tilt)"


LASER_ROLES = (int(Role.LASER), int(Role.LASER_DYNAMIC))


def job_toolpath(toolpath: Toolpath, printer, end: bool = True) -> tuple[Toolpath, float]:
    """The toolpath as the machine runs it, between its approach and its park.

    The moves before the first working move (the input's own way to the start: lifts, travels
    from wherever its reader assumed the tool was, which for a G-code is the bed centre) are
    replaced by the machine's approach (:func:`.travel.from_rest`), which comes down vertically
    onto the first working move's start: the toolpath starts there. The filament those moves
    push or pull (a prime) becomes one zero-length move at that point, their events happen
    before it. end: add the events that switch the tool's heaters, fan and laser off
    (``tool.off_events``, value 0) after the last move. A toolpath with no working move keeps
    its moves but starts at its first point (the approach comes down onto it) where a later move
    still moves. Returns (the
    toolpath, the fastest feed of the moves up to its first working move, mm/s: what the
    approach may go at)."""
    work = toolpath.working | np.isin(toolpath.role, LASER_ROLES)
    k = int(np.argmax(work)) if work.any() else 0
    lead_feed = float(toolpath.feed[: k + 1].max())
    events = toolpath.events
    if k:
        primed = float(toolpath.e[:k].sum())
        prime = int(abs(primed) > 1e-12)  # the zero-length move pushing it, or none
        point = toolpath.xyz[k - 1]

        def col(name, first):
            """Column ``name``: the prime move's value ``first`` (if any), then moves k.. ."""
            values = getattr(toolpath, name)
            return np.concatenate([np.full((prime, *values.shape[1:]), first, values.dtype), values[k:]])

        events = events.copy()
        events["index"] = np.where(events["index"] < k, 0, events["index"] - k + prime)
        toolpath = Toolpath(point, col("xyz", point), col("feed", toolpath.feed[k]), col("e", primed),
                            col("tool", 0.0), col("role", int(Role.RETRACT)), col("layer", toolpath.layer[k]),
                            toolpath.layer_z, events)
    elif not work.any() and ((toolpath.lengths[1:] > 1e-9) | (toolpath.e[1:] != 0)).any():
        toolpath = Toolpath(toolpath.xyz[0], toolpath.xyz, toolpath.feed, toolpath.e, toolpath.tool, toolpath.role,
                            toolpath.layer, toolpath.layer_z, events)
    if end:
        toolpath = toolpath.with_events(np.concatenate([toolpath.events, end_events(printer, len(toolpath))]))
    return toolpath, lead_feed


def end_events(printer, index: int) -> np.ndarray:
    """The events that end every job (its tool's heaters, fan and laser set to 0) before move
    ``index`` (the toolpath's length: after its last move), an EVENT_DTYPE array."""
    return make_events([(index, int(EventKind[name.upper()]), 0.0) for name in printer.tool.off_events])


def _counting_dropped(progress, dropped: int, total: int):
    """``progress`` (callable(done, total) or None) called in the moves of the toolpath given to
    :func:`plan`, counting the ``dropped`` moves :func:`job_toolpath` replaced as done."""
    if progress is None or dropped == 0:
        return progress
    return lambda done, _n: progress(done + dropped, total)


def _link_feed(printer, fastest: float) -> float:
    """The feed (mm/s) of the moves from the rest pose and back to it under the feed speed limit:
    the printer's travel speed, no faster than ``fastest``: the fastest feed the toolpath asks
    for before its first extrusion (from rest), in all (back to rest)."""
    return float(min(printer.slicing.travel_speed, fastest))


def _printed_top(toolpath: Toolpath) -> float:
    """The highest point of the toolpath's working moves (all moves where none works), mm: what
    the tool lifts clear of at the end."""
    work = toolpath.working | np.isin(toolpath.role, LASER_ROLES)
    ends = toolpath.xyz[work] if work.any() else toolpath.xyz
    return float(max(ends[:, 2].max(initial=-np.inf), toolpath.start[2]))


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


def split_runs(toolpath: Toolpath, laser: bool | None = None):
    """[(i, j)] half-open ranges of working moves with one tool value each; a run also ends
    at a wait event (M109/M190), where the machine must stand still while the heater comes up.

    Laser moves instead form runs with a power per move (zero in overscans and short gaps,
    which the tool crosses without stopping), cut only where the power mode (M3/M4) changes.
    laser: whether the tool is a laser (the printer's tool channel); None: whether any move has
    a laser role."""
    waits = toolpath.events["index"][np.isin(toolpath.events["kind"], [int(k) for k in WAIT_KINDS])]
    laser_moves = np.isin(toolpath.role, LASER_ROLES)
    if laser if laser is not None else laser_moves.any():
        member = np.concatenate([[False], toolpath.working | laser_moves, [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(member))
        dynamic = toolpath.role == int(Role.LASER_DYNAMIC)
        out = []
        for i, j in zip(edges[0::2].tolist(), edges[1::2].tolist()):
            cuts = np.union1d(np.flatnonzero(np.diff(dynamic[i:j])) + 1 + i, waits[(waits > i) & (waits < j)]).astype(int)
            bounds = [i, *cuts.tolist(), j]
            out.extend(zip(bounds[:-1], bounds[1:]))
        return out
    # A working move starts a run where the move before is not working, the tool value changes
    # or a wait stands before it; in one pass over the toolpath (run by run in numpy, each run's
    # cuts cost more than its moves).
    n = len(toolpath)
    member = np.asarray(toolpath.working, bool)
    cut = np.zeros(n, bool)
    cut[1:] = np.diff(toolpath.tool) != 0
    cut[waits[(waits > 0) & (waits < n)]] = True
    cut &= member
    starts = np.flatnonzero(member & ~np.concatenate([[False], member[:-1]]) | cut)
    ends = np.flatnonzero(member & ~np.concatenate([member[1:] & ~cut[1:], [False]])) + 1
    return list(zip(starts.tolist(), ends.tolist()))


def _run_spec(toolpath: Toolpath, i: int, j: int, laser: bool) -> RunSpec:
    """Moves i..j-1 as a run: views of the toolpath's read-only columns, not copies (a spiral
    vase's one run would hold its moves twice), the run's start point being the move before;
    laser: a laser's run, with its power per move (see :func:`split_runs`)."""
    pts = toolpath.xyz[i - 1 : j] if i > 0 else np.concatenate([toolpath.start[None], toolpath.xyz[:j]])
    roles = toolpath.role[i:j]
    if laser:
        power = toolpath.tool[i:j]
        dynamic = bool(np.any(roles == int(Role.LASER_DYNAMIC)))
        return RunSpec(pts, toolpath.feed[i:j], toolpath.e[i:j], float(power.max()), int(toolpath.layer[i]),
                       power=power, dynamic_power=dynamic)
    return RunSpec(pts, toolpath.feed[i:j], toolpath.e[i:j], float(toolpath.tool[i]), int(toolpath.layer[i]))


def _init_worker(printer, toolpath=None):
    """A planning process's state: the printer, its kinematics and, where the jobs name their
    moves by index (:func:`_jobs`' ``by_index``), the toolpath (inherited by a forked worker, not
    pickled; pickled once to each worker where processes are spawned)."""
    _WORKER["printer"] = printer
    _WORKER["kin"] = printer.kinematics()
    _WORKER["toolpath"] = toolpath


def _job_args(kind: str, job):
    """A job's RunSpec or plan_travel keywords: ``job`` itself, or made here from the moves it
    names (a tuple: (i, j) of a run, (i, j, printed_top) of a travel; see :func:`_jobs`) in the
    process's toolpath (:func:`_init_worker`)."""
    if type(job) is not tuple:
        return job
    toolpath = _WORKER["toolpath"]
    if kind == "run":
        return _run_spec(toolpath, job[0], job[1], _WORKER["printer"].tool.channel_kind == "laser")
    i, j, printed_top = job
    return _travel_args(toolpath, i, j, toolpath.xyz[i - 1] if i > 0 else toolpath.start, printed_top)


def _plan_chunk(args):
    """Plan a chunk of jobs in print order: ("run", RunSpec) or ("travel", plan_travel's keywords),
    or the moves they are made from (:func:`_job_args`). Returns a PieceBatch of one list of
    pieces per job (what a worker hands back)."""
    jobs, speed_limit, solver = args
    jobs = [(kind, _job_args(kind, job)) for kind, job in jobs]
    printer, kin = _WORKER["printer"], _WORKER["kin"]
    out = [None] * len(jobs)
    # The chunk's travels in one batch: their straight moves are solved together.
    travels = [i for i, (kind, _job) in enumerate(jobs) if kind == "travel"]
    for i, pieces in zip(travels, plan_travels(kin, printer, [jobs[i][1] for i in travels], speed_limit=speed_limit,
                                               solver=solver)):
        out[i] = pieces
    # and its runs: the short ones are solved as batches (topp.plan_runs).
    runs = [i for i, (kind, _job) in enumerate(jobs) if kind != "travel"]
    for i, pieces in zip(runs, plan_runs(kin, printer, [jobs[i][1] for i in runs], speed_limit, solver=solver)):
        out[i] = pieces
    return PieceBatch([jerk_limited(kin, printer, pieces) for pieces in out])


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
    if not ((toolpath.lengths > 1e-9) | (toolpath.e != 0)).any():
        raise DeltasliceError(f"the toolpath's {len(toolpath)} move(s) have zero length and no extrusion: nothing to plan")
    _check_tool(toolpath, printer)
    for note in unit_notes(toolpath):
        warnings.warn(note, ToolpathWarning, stacklevel=2)
    kin = printer.kinematics()
    given, moves = toolpath, len(toolpath)
    toolpath, lead_feed = job_toolpath(toolpath, printer)
    top = _printed_top(toolpath)

    def rest_links():
        """Check every point's reach (of the toolpath as given: its points hold the job's, and an
        error names its layers and says whether centring it would help), then plan the moves from
        the rest pose and back to it (every trajectory starts at the machine's rest pose and parks
        there at the end)."""
        check_reachable(given, printer)
        return (from_rest(kin, printer, toolpath.start, speed_limit, feed=_link_feed(printer, lead_feed)),
                to_rest(kin, printer, toolpath.xyz[-1], speed_limit, top=top,
                        feed=_link_feed(printer, toolpath.feed.max())))

    if planner == "trapezoid":
        from .trapezoid import _moves, plan_safe

        head, tail = rest_links()
        traj = plan_safe(toolpath, printer, speed_limit=speed_limit, progress=progress, head=head, tail=tail)
        # one trapezoid per kept move: move m starts at t0[number of kept moves before m]
        kept_before = np.concatenate([[0], np.cumsum(_moves(toolpath, printer)[-1])])
        times = traj.pieces[len(head)].t0[np.minimum(kept_before[toolpath.events["index"]], len(traj.pieces[len(head)].t0) - 1)]
        traj.events = _at_rest(toolpath.events["index"], len(toolpath), _event_times(toolpath.events, times),
                               sum(p.duration for p in head), traj.duration - sum(p.duration for p in tail))
        return traj
    if spool is None:
        spool = len(toolpath) > SPOOL_MOVES
    return _plan_toppra(toolpath, printer, speed_limit, workers, _counting_dropped(progress, moves - len(toolpath), moves),
                        solver, rest_links, spool)


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
    seen = {"moves": 0, "last": None, "motion": False, "top": -np.inf, "feed": 0.0}
    events = []

    def checked(chunks):
        for tp in chunks:
            if not isinstance(tp, Toolpath):
                raise DeltasliceError(f"plan_stream: chunks: expected Toolpaths, got {type(tp).__name__}")
            if not len(tp):
                continue
            if seen["last"] is not None and not np.allclose(tp.start, seen["last"], rtol=0, atol=1e-9):
                raise DeltasliceError(f"plan_stream: the chunk at move {seen['moves']} starts at {tp.start.tolist()}, "
                                      f"not where the one before ends ({seen['last'].tolist()})")
            _check_tool(tp, printer)
            check_reachable(tp, printer, hint=False)
            seen["motion"] = seen["motion"] or bool(((tp.lengths > 1e-9) | (tp.e != 0)).any())
            seen["top"] = max(seen["top"], _printed_top(tp))
            seen["feed"] = max(seen["feed"], float(tp.feed.max()))
            ev = tp.events.copy()
            ev["index"] += seen["moves"]
            events.append(ev)
            seen["moves"] += len(tp)
            seen["last"] = tp.xyz[-1]
            yield tp

    lead = {"dropped": 0}
    stream = checked(_job_chunks(chunks, printer, lead))
    if progress is not None:
        report = progress
        progress = lambda done, total: report(done + lead["dropped"], total)  # noqa: E731
    first = next(stream, None)
    if first is None:
        raise DeltasliceError("the toolpath has no moves: nothing to plan")
    kin = printer.kinematics()
    pieces = PieceSpool()
    pieces.extend(from_rest(kin, printer, first.start, speed_limit, feed=_link_feed(printer, lead["feed"])))
    laser = printer.tool.channel_kind == "laser"
    job_start, job_piece = _plan_jobs(_stream_jobs(itertools.chain([first], stream), laser), pieces, CHUNK_MAX, moves,
                                      False, printer, speed_limit, workers, progress, solver)
    if not seen["motion"]:
        raise DeltasliceError(f"the toolpath's {seen['moves']} move(s) have zero length and no extrusion: nothing to plan")
    tail = to_rest(kin, printer, seen["last"], speed_limit, top=seen["top"], feed=_link_feed(printer, seen["feed"]))
    events.append(end_events(printer, seen["moves"]))
    return _trajectory(printer, pieces, tail, speed_limit, job_start, job_piece, np.concatenate(events), seen["moves"])


def _job_chunks(chunks, printer, lead: dict):
    """:func:`job_toolpath` (without its end events) of a toolpath handed over in chunks: the
    chunks before the first working move are held and joined to the one that has it, which is
    handed on from that move; the chunks after it pass as they are (not checked here: anything
    that is not a Toolpath goes on to :func:`plan_stream`'s check). ``lead["feed"]`` is set to
    job_toolpath's fastest feed before the first working move once that chunk is handed on, and
    ``lead["dropped"]`` to the moves it replaced (less its prime move), for progress."""
    held = None
    for tp in chunks:
        if held is False or not isinstance(tp, Toolpath):
            yield tp
            continue
        held = tp if held is None else held.then(tp)
        if (held.working | np.isin(held.role, LASER_ROLES)).any():
            job, lead["feed"] = job_toolpath(held, printer, end=False)
            lead["dropped"] = len(held) - len(job)
            yield job
            held = False
    if held:
        job, lead["feed"] = job_toolpath(held, printer, end=False)
        yield job


def _stream_jobs(chunks, laser: bool):
    """:func:`_jobs` of consecutive chunks joined, holding one chunk and what is held back from
    the one before: the last run or travel of each chunk waits for the next chunk's moves; a run
    grown past STREAM_RUN moves is handed over as a "parts" job (:func:`_run_parts`), after
    which what follows it in its last chunk goes on."""
    held, at, top = None, 0, 0.0  # moves held back (from a job's first move), the first one's index, the printed top
    while True:
        tp = next(chunks, None)
        if tp is None:
            if held is not None:
                yield from _jobs(held, split_runs(held, laser), laser, at, printed_top=top)
            return
        cur = tp if held is None else held.then(tp)
        tops = {}
        items = list(_jobs(cur, split_runs(cur, laser), laser, at, printed_top=top, tops=tops))
        yield from items[:-1]
        start, _end, kind, _job = items[-1]
        top = tops["before"]  # the last job's, which is held back
        held, at = cur.subset(slice(start - at, None)), start
        del cur, items, _job
        if kind == "run" and len(held) > STREAM_RUN:
            after = {}
            yield at, at, "parts", _run_parts(held, at, chunks, after, laser)
            if "at" not in after:
                raise DeltasliceError("plan_stream: a run handed over in parts was not planned to its end")
            held, at, top = after["rest"], after["at"], max(top, after["top"])


def _run_parts(run: Toolpath, at: int, chunks, after: dict, laser: bool):
    """RunSpecs of a run as it comes: ``run`` (a toolpath all of whose moves are the run, its first
    being move ``at`` of the print), then its moves in each chunk taken from ``chunks`` until it
    ends. Then ``after`` holds what is left: "rest" (the moves after the run in its last chunk, a
    Toolpath, or None), "at" (the first one's index) and "top" (the run's highest point, mm)."""
    top = float(run.xyz[:, 2].max())
    yield _run_spec(run, 0, len(run), laser)
    last, n = run.subset(slice(len(run) - 1, None)), at + len(run) - 1  # the run's last move, and its index
    del run
    while True:
        tp = next(chunks, None)
        if tp is None:
            after.update(rest=None, at=n + 1, top=top)
            return
        joined = last.then(tp)
        ranges = split_runs(joined, laser)
        j0 = ranges[0][1] if ranges and ranges[0][0] == 0 else 1  # the run goes on to move j0
        if j0 > 1:
            yield _run_spec(joined, 1, j0, laser)
            top = max(top, float(joined.xyz[1:j0, 2].max()))
        if j0 < len(joined):
            after.update(rest=joined.subset(slice(j0, None)), at=n + j0, top=top)
            return
        last, n = joined.subset(slice(len(joined) - 1, None)), n + len(joined) - 1


def _check_options(caller, printer, speed_limit, planner, solver, workers, progress) -> None:
    from ..machine import Printer

    if not isinstance(printer, Printer):
        raise DeltasliceError(
            f"{caller}: printer: expected a loaded Printer (deltaslice.load_printer(path)), got {type(printer).__name__} {printer!r:.60}")
    if not printer.reach_checked:
        raise DeltasliceError(f"{caller}: printer {printer.name} was loaded with reach_checks=False: plan with "
                              "deltaslice.machine.check_reach(printer) instead (the printer it returns has its rest "
                              "pose set and its reach checked)")
    if speed_limit not in ("feed", "machine"):
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


def _jobs(toolpath: Toolpath, ranges, laser: bool, offset: int = 0, printed_top: float = 0.0, tops: dict | None = None,
          by_index: bool = False):
    """(first move, end move, kind, job) of every run and of the travels between them (and before
    the first, after the last), in print order, made one at a time: a print of 270k runs would
    hold hundreds of MB of them at once. offset: the toolpath's first move's index in the print;
    printed_top: the top of what is printed already (mm), for a toolpath that goes on from
    another; ``tops["before"]``, when given, is set to the printed top before each job yielded.
    by_index: each job the moves it is made from, (i, j) of a run and (i, j, printed_top) of a
    travel (:func:`_job_args` makes it where it is planned, from the toolpath the planning
    workers inherit: making and pickling every job's arrays in the parent would take the CPU the
    workers plan with)."""
    pos = toolpath.start
    prev_end = 0
    tops = {} if tops is None else tops
    for i, j in ranges:
        tops["before"] = printed_top
        if i > prev_end:
            yield offset + prev_end, offset + i, "travel", ((prev_end, i, printed_top) if by_index else
                                                             _travel_args(toolpath, prev_end, i, pos, printed_top))
        yield offset + i, offset + j, "run", (i, j) if by_index else _run_spec(toolpath, i, j, laser)
        pos = toolpath.xyz[j - 1]
        printed_top = max(printed_top, float(toolpath.xyz[i:j, 2].max()))
        prev_end = j
    if prev_end < len(toolpath):
        tops["before"] = printed_top
        end = len(toolpath)
        yield offset + prev_end, offset + end, "travel", ((prev_end, end, printed_top) if by_index else
                                                           _travel_args(toolpath, prev_end, end, pos, printed_top))


def _slots(jobs, chunk: int):
    """Consecutive jobs grouped for the workers: ("pool", [(start, end, kind, job), ...]) of at most
    ``chunk`` jobs, or ("here", (start, end, kind, job)) for a long run the main process plans (a
    run handed over in parts too: "parts", see :func:`plan_stream`)."""
    group = []
    for item in jobs:
        if item[2] == "parts" or (item[2] == "run" and is_long(item[1] - item[0])):  # a run's moves, from its first and end move
            if group:
                yield "pool", group
                group = []
            yield "here", item
        else:
            group.append(item)
            if len(group) == chunk:
                yield "pool", group
                group = []
    if group:
        yield "pool", group


def _plan_toppra(toolpath, printer, speed_limit, workers, progress, solver, rest_links, spool) -> Trajectory:
    """The time-optimal planner: the move from rest, the toolpath's runs and travels, the move to
    rest. rest_links: () -> (head, tail), those two moves' pieces after the reach check, called
    while the workers start on the first runs (nothing they plan is taken before it returns)."""
    laser = printer.tool.channel_kind == "laser"
    ranges = split_runs(toolpath, laser)
    n_jobs = 2 * len(ranges) + 1  # at most: a travel before every run, one after the last
    # The chunks do not depend on the number of workers: a chunk's travels are solved as one batch
    # (travel.plan_travels), so the same chunks give the same bytes whatever --workers is.
    chunk = max(1, min(CHUNK_MAX, n_jobs // CHUNKS_PER_PRINT))
    pieces = PieceSpool() if spool else []
    links = {}

    def first():
        links["head"], links["tail"] = rest_links()
        pieces.extend(links["head"])

    job_start, job_piece = _plan_jobs(_jobs(toolpath, ranges, laser, by_index=True), pieces, chunk, len(toolpath),
                                      n_jobs < 8, printer, speed_limit, workers, progress, solver, first=first,
                                      toolpath=toolpath)
    return _trajectory(printer, pieces, links["tail"], speed_limit, job_start, job_piece, toolpath.events, len(toolpath))


def _plan_jobs(jobs, pieces, chunk: int, n_moves: int | None, few: bool, printer, speed_limit, workers, progress,
               solver, first=None, toolpath=None):
    """Plan ``jobs`` (see :func:`_jobs`) into ``pieces`` (a list or a PieceSpool), returning per job
    its first move and the index of its first piece (arrays of int64).

    Runs and travels are planned in the worker processes in print order (the first chunk here,
    before they fork, so they inherit its loaded kernels), at most a few chunks ahead of what has
    been put away (memory bounded by what is in flight, not by the print); a
    long run (:func:`.topp.is_long`) is planned here, window by window, while the workers go on
    with what follows it, so its pieces can be put away one by one. A run handed over in parts
    (plan_stream) is planned here once everything before it is put away: what follows it is
    read only after it. n_moves: the moves in all (for progress), or None; few: too few jobs for
    worker processes to pay (they are planned here). first: a callable run here before anything
    is put away, once the workers have their first chunks (so it costs no time where it raises
    nothing; where it raises, the chunks not yet started are cancelled and the running ones
    waited for), or None. toolpath: the toolpath jobs that name their moves come from (inherited
    by the workers), or None."""
    workers = resolve_workers(workers, "plan")
    job_start, job_piece = array("q"), array("q")  # per job: its first move, the index of its first piece
    done = 0
    slots = _slots(jobs, chunk)

    def report(moves):
        nonlocal done
        done += moves
        if progress:
            progress(min(int(round(done)), n_moves) if n_moves else int(round(done)), n_moves)

    def put_away(group, results):
        for (start, end, _kind, _job), res in zip(group, results.groups):
            job_start.append(start)
            job_piece.append(len(pieces))
            pieces.extend(res)
        report(group[-1][1] - group[0][0])

    def plan_here(item):
        start, end, kind, spec = item
        spec = _job_args(kind, spec)
        job_start.append(start)
        job_piece.append(len(pieces))
        before = 0.0
        if kind == "parts":
            for piece, taken in iter_run_parts(printer.kinematics(), printer, spec, speed_limit, solver=solver):
                pieces.append(piece)
                report(taken - before)
                before = taken
            return
        for piece, frac in iter_run(printer.kinematics(), printer, spec, speed_limit, solver=solver):
            pieces.append(piece)
            report((frac - before) * (end - start))
            before = frac

    def as_chunk(group):
        return [(kind, job) for _s, _e, kind, job in group], speed_limit, solver

    # this process plans the warm-up, long runs and, with one worker, everything: its jobs too are
    # made from the toolpath
    _init_worker(printer, toolpath)
    try:
        if workers == 1 or few:
            if first is not None:
                first()
            for where, item in slots:
                if where == "here":
                    plan_here(item)
                else:
                    put_away(item, _plan_chunk(as_chunk(item)))
        else:
            ahead = 4 * workers  # chunks in flight; slots queued at most twice that
            queue, in_flight = deque(), 0
            # The first chunk's first jobs are planned here, and dropped, before the workers fork:
            # the compiled kernels load in this process once and the workers inherit them (each
            # loading them at its first chunk cost it a tenth of a second and held the first results
            # back). Only a few: the rest of the chunk's work ran here with the other core idle. The
            # chunk itself goes to the workers like the others (the same pieces wherever it is planned).
            head = next(slots, None)
            if head is not None:
                slots = itertools.chain([head], slots)
                if head[0] == "pool":
                    try:
                        _plan_chunk(as_chunk(head[1][:WARM_UP_JOBS]))
                    except DeltasliceError:
                        if first is not None:
                            first()  # the reach check speaks first, as when the workers plan the chunk
                        raise  # the error of the chunk's first job that fails: it is among these
            pool = start_pool(workers, initializer=_init_worker, initargs=(printer, toolpath))
            try:

                def run_first():
                    nonlocal first
                    if first is not None:
                        try:
                            first()
                        except BaseException:
                            # no worker outlives the error: the chunks not started are dropped, the
                            # ones running finish (a few tenths of a second)
                            stop_pool(pool)
                            raise
                        first = None

                for where, item in slots:
                    if where == "here" and item[2] == "parts":  # its parts are read as it is planned: nothing after it is read before
                        run_first()
                        while queue:
                            _drain_one(queue, put_away, plan_here)
                        in_flight = 0
                        plan_here(item)
                        continue
                    future = pool.submit(_plan_chunk, as_chunk(item)) if where == "pool" else None
                    queue.append((item, future))
                    in_flight += future is not None
                    while in_flight > ahead or len(queue) > 2 * ahead:
                        run_first()
                        in_flight -= _drain_one(queue, put_away, plan_here)
                run_first()
                while queue:
                    _drain_one(queue, put_away, plan_here)
            finally:
                stop_pool(pool)
    finally:
        _WORKER["toolpath"] = None  # this process keeps no toolpath once it is planned
    return np.asarray(job_start), np.asarray(job_piece)


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


def _drain_one(queue, put_away, plan_here) -> int:
    """Put away the oldest slot: a chunk's results (waiting for its worker; returns 1) or a long
    run planned here (0)."""
    item, future = queue.popleft()
    if future is None:
        plan_here(item)
        return 0
    put_away(item, future.result())
    return 1


def _event_times(ev: np.ndarray, times) -> tuple:
    """((time_s, kind, value), ...) of the events ``ev`` (a toolpath's) at the given times (s), in order.
    An event inside a move range (a travel, or a run not cut by a wait) fires at the range's start."""
    return tuple((float(t), int(k), float(v)) for t, k, v in zip(np.asarray(times, float).tolist(), ev["kind"], ev["value"]))


def _travel_args(toolpath, i, j, pos, printed_top) -> dict:
    """plan_travel's keywords for the non-working moves [i, j) that go from pos to the start of move j."""
    target = toolpath.xyz[j - 1]
    layer = int(toolpath.layer[min(j, len(toolpath) - 1)])
    if j - i == 1:  # most travels are one move: the same values from the move's scalars
        e = float(toolpath.e[i])
        # a step of nonzero length: a sum of squares is zero only where every square is
        moved = any(d * d > 0.0 for d in (toolpath.xyz[i] - pos).tolist())
        feed = float(toolpath.feed[i]) if moved else 0.0
        return dict(a=np.asarray(pos, float), b=np.asarray(target, float), layer=layer, printed_top=printed_top,
                    retract=e if e < 0 else 0.0, unretract=e if e > 0 else 0.0, via=toolpath.xyz[i:i].copy(),
                    feed=(feed if feed > 0.0 or feed != feed else 0.0) or None)
    e = toolpath.e[i:j]
    steps = np.linalg.norm(toolpath.xyz[i:j] - np.concatenate([[pos], toolpath.xyz[i : j - 1]]), axis=1)
    return dict(
        a=np.asarray(pos, float),
        b=np.asarray(target, float),
        layer=layer,
        printed_top=printed_top,
        retract=float(e[e < 0].sum()),
        unretract=float(e[e > 0].sum()),
        via=toolpath.xyz[i : j - 1].copy(),
        feed=float(toolpath.feed[i:j][steps > 0].max(initial=0.0)) or None,
    )
