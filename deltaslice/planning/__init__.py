"""Planning: Toolpath -> Trajectory.

``plan(toolpath, printer)`` splits the toolpath into runs (consecutive working
moves with one tool state) and travels, plans every run time-optimally in joint
space with toppra (in parallel processes), every travel with ruckig (or toppra
when the joint-space move would not clear the part), and returns a
:class:`~.trajectory.Trajectory`. ``planner="trapezoid"`` gives the conventional
Cartesian planner instead (:mod:`.trapezoid`), made safe for the joint limits.
"""

from __future__ import annotations

from array import array
from collections import deque

import numpy as np

from ..errors import DeltasliceError, UnreachableError
from ..pool import resolve_workers, start_pool
from ..toolpath import WAIT_KINDS, Role, Toolpath
from .pieces import Piece
from .spool import SPOOL_MOVES, PieceSpool
from .topp import SOLVERS, RunSpec, is_long, iter_run, plan_runs
from .trajectory import Trajectory
from .travel import from_rest, plan_travels, to_rest

__all__ = ["plan", "Piece", "Trajectory", "split_runs", "check_reachable"]

_WORKER = {}
# Jobs per chunk handed to a worker: an eighth of the print's, at most 64 (small prints still make 8 chunks).
CHUNKS_PER_PRINT = 8


def check_reachable(toolpath: Toolpath, printer) -> None:
    """Raise UnreachableError naming the layer and position of the first point out of reach."""
    kin = printer.kinematics()
    pts = np.concatenate([toolpath.start[None], toolpath.xyz])
    ok = kin.reachable(pts)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        layer = int(toolpath.layer[max(i - 1, 0)]) if len(toolpath) else 0
        p = pts[i]
        q = kin.inverse(p[None])[0]
        why = "no real inverse kinematics"
        if np.all(np.isfinite(q)):
            lo, hi = kin.position_min, kin.position_max
            bad = np.flatnonzero((q < lo - 1e-9) | (q > hi + 1e-9))
            if bad.size:
                j = int(bad[0])
                why = f"joint {j + 1} would be at {q[j]:.4g}, outside {lo[j]:.4g}..{hi[j]:.4g}"
            elif kin.condition(q[None])[0] >= kin.singularity_limit:
                why = f"too close to a singularity (Jacobian condition {kin.condition(q[None])[0]:.0f})"
            else:
                why = "beyond a mechanical limit (ball-joint tilt)"
        from ..toolpath import fits_centred

        hint = (
            "; the part would fit centred on the bed: use --center (center=True)"
            if fits_centred(toolpath, printer)
            else "; it would not fit centred on the bed either"
        )
        raise UnreachableError(
            f"layer {layer}: x = {p[0]:.2f}, y = {p[1]:.2f}, z = {p[2]:.2f} mm is out of reach of {printer.name} ({why}){hint}"
        )


LASER_ROLES = (int(Role.LASER), int(Role.LASER_DYNAMIC))


def _check_tool(toolpath: Toolpath, printer) -> None:
    """Refuse a toolpath made for the other kind of tool: filament for a laser, laser burns for
    an extruder (the channel would carry a meaning its player does not have)."""
    laser_moves = np.isin(toolpath.role, LASER_ROLES)
    if printer.tool.channel_kind == "laser" and np.any(toolpath.e[toolpath.working] > 0):
        raise DeltasliceError(f"the toolpath extrudes filament but {printer.name} has a laser: "
                              "slice it for an extruder printer, or give the laser an image, an SVG or laser G-code")
    if printer.tool.channel_kind != "laser" and laser_moves.any():
        raise DeltasliceError(f"the toolpath has {int(laser_moves.sum())} laser moves but {printer.name} has an extruder")


def split_runs(toolpath: Toolpath):
    """[(i, j)] half-open ranges of working moves with one tool value each; a run also ends
    at a wait event (M109/M190), where the machine must stand still while the heater comes up.

    Laser moves instead form runs with a power per move (zero in overscans and short gaps,
    which the tool crosses without stopping), cut only where the power mode (M3/M4) changes."""
    waits = toolpath.events["index"][np.isin(toolpath.events["kind"], [int(k) for k in WAIT_KINDS])]
    laser = np.isin(toolpath.role, LASER_ROLES)
    if laser.any():
        member = np.concatenate([[False], toolpath.working | laser, [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(member))
        dynamic = toolpath.role == int(Role.LASER_DYNAMIC)
        out = []
        for i, j in zip(edges[0::2].tolist(), edges[1::2].tolist()):
            cuts = np.union1d(np.flatnonzero(np.diff(dynamic[i:j])) + 1 + i, waits[(waits > i) & (waits < j)]).astype(int)
            bounds = [i, *cuts.tolist(), j]
            out.extend(zip(bounds[:-1], bounds[1:]))
        return out
    out = []
    waits = toolpath.events["index"][np.isin(toolpath.events["kind"], [int(k) for k in WAIT_KINDS])]
    for i, j in toolpath.runs():
        tool = toolpath.tool[i:j]
        cuts = np.union1d(np.flatnonzero(np.diff(tool) != 0) + 1, waits[(waits > i) & (waits < j)] - i).astype(int)
        edges = np.concatenate([[0], cuts, [j - i]]) + i
        out.extend(zip(edges[:-1].tolist(), edges[1:].tolist()))
    return out


def _run_spec(toolpath: Toolpath, i: int, j: int) -> RunSpec:
    """Moves i..j-1 as a run: views of the toolpath's read-only columns, not copies (a spiral
    vase's one run would hold its moves twice), the run's start point being the move before."""
    pts = toolpath.xyz[i - 1 : j] if i > 0 else np.concatenate([toolpath.start[None], toolpath.xyz[:j]])
    roles = toolpath.role[i:j]
    if np.isin(roles, LASER_ROLES).any():
        power = toolpath.tool[i:j]
        dynamic = bool(np.any(roles == int(Role.LASER_DYNAMIC)))
        return RunSpec(pts, toolpath.feed[i:j], toolpath.e[i:j], float(power.max()), int(toolpath.layer[i]),
                       power=power, dynamic_power=dynamic)
    return RunSpec(pts, toolpath.feed[i:j], toolpath.e[i:j], float(toolpath.tool[i]), int(toolpath.layer[i]))


def _init_worker(printer):
    _WORKER["printer"] = printer
    _WORKER["kin"] = printer.kinematics()


def _plan_chunk(args):
    """Plan a chunk of jobs in print order: ("run", RunSpec) or ("travel", plan_travel's keywords).
    Returns one list of pieces per job."""
    jobs, speed_limit, solver = args
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
    return out


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
    from ..machine import Printer

    if not isinstance(toolpath, Toolpath):
        raise DeltasliceError(f"plan: toolpath: expected a Toolpath, got {type(toolpath).__name__}")
    if not isinstance(printer, Printer):
        raise DeltasliceError(
            f"plan: printer: expected a loaded Printer (deltaslice.load_printer(path)), got {type(printer).__name__} {printer!r:.60}")
    if speed_limit not in ("feed", "machine"):
        raise DeltasliceError(f"speed_limit must be 'feed' or 'machine', not {speed_limit!r}")
    if planner not in ("toppra", "trapezoid"):
        raise DeltasliceError(f"planner must be 'toppra' or 'trapezoid', not {planner!r}")
    if solver not in SOLVERS:
        raise DeltasliceError(f"solver must be one of {', '.join(SOLVERS)}, not {solver!r}")
    resolve_workers(workers, "plan")
    if progress is not None and not callable(progress):
        raise DeltasliceError(f"plan: progress: expected a callable(done, total) or None, got {type(progress).__name__}")
    if spool is not None and not isinstance(spool, bool):
        raise DeltasliceError(f"plan: spool = {spool!r}: expected True, False or None")
    if len(toolpath) == 0:
        raise DeltasliceError("the toolpath has no moves: nothing to plan")
    if not ((toolpath.lengths > 1e-9) | (toolpath.e != 0)).any():
        raise DeltasliceError(f"the toolpath's {len(toolpath)} move(s) have zero length and no extrusion: nothing to plan")
    _check_tool(toolpath, printer)
    check_reachable(toolpath, printer)
    # Every trajectory starts at the machine's rest pose and parks there at the end.
    kin = printer.kinematics()
    head = from_rest(kin, printer, toolpath.start, speed_limit)
    tail = to_rest(kin, printer, toolpath.xyz[-1], speed_limit)
    if planner == "trapezoid":
        from .trapezoid import _moves, plan_safe

        traj = plan_safe(toolpath, printer, speed_limit=speed_limit, progress=progress, head=head, tail=tail)
        # one trapezoid per kept move: move m starts at t0[number of kept moves before m]
        kept_before = np.concatenate([[0], np.cumsum(_moves(toolpath, printer)[-1])])
        times = traj.pieces[len(head)].t0[np.minimum(kept_before[toolpath.events["index"]], len(traj.pieces[len(head)].t0) - 1)]
        traj.events = _at_rest(toolpath, _event_times(toolpath, times), sum(p.duration for p in head), traj.duration)
        return traj
    if spool is None:
        spool = len(toolpath) > SPOOL_MOVES
    return _plan_toppra(toolpath, printer, speed_limit, workers, progress, solver, head, tail, spool)


def _at_rest(toolpath: Toolpath, events: tuple, offset: float, duration: float) -> tuple:
    """Events timed within the toolpath's own motion, moved onto the whole trajectory: those
    before the first move happen at t = 0, at the rest pose (a heater warms up and a wait holds
    there, not over the bed); those after the last move at the end, parked; the rest shift by
    ``offset`` (s)."""
    index = toolpath.events["index"]
    return tuple(
        (0.0 if i == 0 else duration if i >= len(toolpath) else t + offset, k, v)
        for (t, k, v), i in zip(events, index.tolist())
    )


def _jobs(toolpath: Toolpath, ranges):
    """(first move, end move, kind, job) of every run and of the travels between them (and before
    the first, after the last), in print order, made one at a time: a print of 270k runs would
    hold hundreds of MB of them at once."""
    pos = toolpath.start
    printed_top = 0.0
    prev_end = 0
    for i, j in ranges:
        if i > prev_end:
            yield prev_end, i, "travel", _travel_args(toolpath, prev_end, i, pos, printed_top)
        yield i, j, "run", _run_spec(toolpath, i, j)
        pos = toolpath.xyz[j - 1]
        printed_top = max(printed_top, float(toolpath.xyz[i:j, 2].max()))
        prev_end = j
    if prev_end < len(toolpath):
        yield prev_end, len(toolpath), "travel", _travel_args(toolpath, prev_end, len(toolpath), pos, printed_top)


def _slots(jobs, chunk: int):
    """Consecutive jobs grouped for the workers: ("pool", [(start, end, kind, job), ...]) of at most
    ``chunk`` jobs, or ("here", (start, end, kind, job)) for a long run the main process plans."""
    group = []
    for item in jobs:
        if item[2] == "run" and is_long(item[3]):
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


def _plan_toppra(toolpath, printer, speed_limit, workers, progress, solver, head, tail, spool) -> Trajectory:
    """The time-optimal planner: head (from rest), the toolpath's runs and travels, tail (to rest).

    Runs and travels are planned in the worker processes in print order, at most a few chunks
    ahead of what has been put away (memory bounded by what is in flight, not by the print); a
    long run (:func:`.topp.is_long`) is planned here, window by window, while the workers go on
    with what follows it, so its pieces can be put away one by one."""
    ranges = split_runs(toolpath)
    workers = resolve_workers(workers, "plan")
    n_jobs = 2 * len(ranges) + 1  # at most: a travel before every run, one after the last
    # The chunks do not depend on the number of workers: a chunk's travels are solved as one batch
    # (travel.plan_travels), so the same chunks give the same bytes whatever --workers is.
    chunk = max(1, min(64, n_jobs // CHUNKS_PER_PRINT))
    slots = _slots(_jobs(toolpath, ranges), chunk)

    pieces = PieceSpool() if spool else []
    pieces.extend(head)
    job_start, job_piece = array("q"), array("q")  # per job: its first move, the index of its first piece
    done = 0

    def report(moves):
        nonlocal done
        done += moves
        if progress:
            progress(min(int(round(done)), len(toolpath)), len(toolpath))

    def put_away(group, results):
        for (start, end, _kind, _job), res in zip(group, results):
            job_start.append(start)
            job_piece.append(len(pieces))
            pieces.extend(res)
        report(group[-1][1] - group[0][0])

    def plan_here(item):
        start, end, _kind, spec = item
        job_start.append(start)
        job_piece.append(len(pieces))
        before = 0.0
        for piece, frac in iter_run(printer.kinematics(), printer, spec, speed_limit, solver=solver):
            pieces.append(piece)
            report((frac - before) * (end - start))
            before = frac

    def as_chunk(group):
        return [(kind, job) for _s, _e, kind, job in group], speed_limit, solver

    if workers == 1 or n_jobs < 8:
        _init_worker(printer)
        for where, item in slots:
            if where == "here":
                plan_here(item)
            else:
                put_away(item, _plan_chunk(as_chunk(item)))
    else:
        ahead = 4 * workers  # chunks in flight; slots queued at most twice that
        queue, in_flight = deque(), 0
        with start_pool(workers, initializer=_init_worker, initargs=(printer,)) as pool:
            for where, item in slots:
                future = pool.submit(_plan_chunk, as_chunk(item)) if where == "pool" else None
                queue.append((item, future))
                in_flight += future is not None
                while in_flight > ahead or len(queue) > 2 * ahead:
                    in_flight -= _drain_one(queue, put_away, plan_here)
            while queue:
                _drain_one(queue, put_away, plan_here)
    job_start.append(len(toolpath))
    job_piece.append(len(pieces))
    if len(pieces) == len(head):
        raise DeltasliceError("the toolpath never moves the tool or the filament: nothing to plan")
    pieces.extend(tail)
    traj = Trajectory(printer, pieces, planner="toppra", speed_limit=speed_limit)
    moves, piece_at = np.asarray(job_start), np.asarray(job_piece)
    ev = toolpath.events["index"]
    k = piece_at[np.searchsorted(moves, ev, side="right") - 1]
    times = np.where(ev >= len(toolpath), traj.duration, traj.starts[np.minimum(k, len(pieces))])
    traj.events = _at_rest(toolpath, _event_times(toolpath, times), 0.0, traj.duration)
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


def _event_times(toolpath: Toolpath, times) -> tuple:
    """((time_s, kind, value), ...) of the toolpath's events at the given times (s), in order.
    An event inside a move range (a travel, or a run not cut by a wait) fires at the range's start."""
    ev = toolpath.events
    return tuple((float(t), int(k), float(v)) for t, k, v in zip(np.asarray(times, float).tolist(), ev["kind"], ev["value"]))


def _travel_args(toolpath, i, j, pos, printed_top) -> dict:
    """plan_travel's keywords for the non-working moves [i, j) that go from pos to the start of move j."""
    target = toolpath.xyz[j - 1]
    e = toolpath.e[i:j]
    layer = int(toolpath.layer[min(j, len(toolpath) - 1)])
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
