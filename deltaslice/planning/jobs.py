"""A print as jobs: the toolpath as the machine runs it (:func:`job_toolpath`), its runs
(:func:`split_runs`) and the travels between them, one :class:`Job` each, in print order, from a
whole toolpath (:func:`toolpath_jobs`) or one handed over in chunks (:func:`stream_jobs`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import DeltasliceError
from ..toolpath import WAIT_KINDS, EventKind, Role, Toolpath, make_events
from .runpath import RunSpec
from .tolerances import NO_FILAMENT, NO_MOTION

LASER_ROLES = (int(Role.LASER), int(Role.LASER_DYNAMIC))
# Moves a run handed over in chunks (plan_stream) gathers before it is planned as its parts come.
STREAM_RUN = 50_000


@dataclass(frozen=True, slots=True)
class Job:
    """One run or travel of a print, or a run handed over in parts. kind: "run", "travel" or
    "parts"; start, end: its first and end move in the print; i, j: its moves in the toolpath it
    is made from; printed_top: the top of what is printed before it, mm (a travel's); made: its
    RunSpec, travel keywords or (a "parts" job) iterator of RunSpecs where it was made with its
    arguments (a stretch of a streamed print), or None: made where it is planned, from moves i..j
    of the toolpath that process holds (:meth:`arguments`; the planning workers inherit the
    toolpath, so making and pickling every job's arrays in the parent costs nothing)."""

    kind: str
    start: int
    end: int
    i: int
    j: int
    printed_top: float = 0.0
    made: object = None

    def arguments(self, toolpath: Toolpath | None, laser: bool):
        """The job's RunSpec (a run's) or plan_travel keywords (a travel's): ``made``, or made from
        ``toolpath``; laser: whether the tool burns (a run's power per move)."""
        if self.made is not None:
            return self.made
        if self.kind == "run":
            return run_spec(toolpath, self.i, self.j, laser)
        pos = toolpath.xyz[self.i - 1] if self.i > 0 else toolpath.start
        return travel_args(toolpath, self.i, self.j, pos, self.printed_top)


def _working(toolpath: Toolpath) -> np.ndarray:
    """(n,) bool: the moves that work (extrude, or burn: laser roles)."""
    return toolpath.working | np.isin(toolpath.role, LASER_ROLES)


def job_toolpath(toolpath: Toolpath, tool, end: bool = True) -> tuple[Toolpath, float]:
    """The toolpath as the machine runs it, between its approach and its park.

    The moves before the first working move (the input's own way to the start: lifts, travels
    from wherever its reader assumed the tool was, which for a G-code is the bed centre) are
    replaced by the machine's approach (:func:`.travel.from_rest`), which comes down vertically
    onto the first working move's start: the toolpath starts there. The filament those moves
    push or pull (a prime) becomes one zero-length move at that point, their events happen
    before it. end: add the events that switch the ``tool``'s heaters, fan and laser off
    (``tool.off_events``, value 0) after the last move. A toolpath with no working move keeps
    its moves but starts at its first point (the approach comes down onto it) where a later move
    still moves. Returns (the toolpath, the fastest feed of the moves up to its first working
    move, mm/s: what the approach may go at)."""
    work = _working(toolpath)
    k = int(np.argmax(work)) if work.any() else 0
    lead_feed = float(toolpath.feed[: k + 1].max())
    events = toolpath.events
    if k:
        primed = float(toolpath.e[:k].sum())
        prime = int(abs(primed) > NO_FILAMENT)  # the zero-length move pushing it, or none
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
    elif not work.any() and ((toolpath.lengths[1:] > NO_MOTION) | (toolpath.e[1:] != 0)).any():
        toolpath = Toolpath(toolpath.xyz[0], toolpath.xyz, toolpath.feed, toolpath.e, toolpath.tool, toolpath.role,
                            toolpath.layer, toolpath.layer_z, events)
    if end:
        toolpath = toolpath.with_events(np.concatenate([toolpath.events, end_events(tool, len(toolpath))]))
    return toolpath, lead_feed


def end_events(tool, index: int) -> np.ndarray:
    """The events that end every job (the ``tool``'s heaters, fan and laser set to 0) before move
    ``index`` (the toolpath's length: after its last move), an EVENT_DTYPE array."""
    return make_events([(index, int(EventKind[name.upper()]), 0.0) for name in tool.off_events])


def printed_top(toolpath: Toolpath) -> float:
    """The highest point of the toolpath's working moves (all moves where none works), mm: what
    the tool lifts clear of at the end."""
    work = _working(toolpath)
    ends = toolpath.xyz[work] if work.any() else toolpath.xyz
    return float(max(ends[:, 2].max(initial=-np.inf), toolpath.start[2]))


def moves_anything(toolpath: Toolpath) -> bool:
    """Whether any move of the toolpath moves the tool or the filament."""
    return bool(((toolpath.lengths > NO_MOTION) | (toolpath.e != 0)).any())


def split_runs(toolpath: Toolpath, laser: bool = False):
    """[(i, j)] half-open ranges of working moves with one tool value each; a run also ends
    at a wait event (M109/M190), where the machine must stand still while the heater comes up.

    laser: whether the tool burns (``Tool.takes_laser_power``): laser moves then form runs with a
    power per move (zero in overscans and short gaps, which the tool crosses without stopping),
    cut only where the power mode (M3/M4) changes."""
    waits = toolpath.events["index"][np.isin(toolpath.events["kind"], [int(k) for k in WAIT_KINDS])]
    if laser:
        member = np.concatenate([[False], _working(toolpath), [False]]).astype(np.int8)
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


def run_spec(toolpath: Toolpath, i: int, j: int, laser: bool) -> RunSpec:
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


def travel_args(toolpath, i, j, pos, top) -> dict:
    """plan_travel's keywords for the non-working moves [i, j) that go from pos to the start of
    move j, above a print whose top is ``top`` (mm)."""
    target = toolpath.xyz[j - 1]
    layer = int(toolpath.layer[min(j, len(toolpath) - 1)])
    if j - i == 1:  # most travels are one move: the same values from the move's scalars, without numpy's per-call cost
        e = float(toolpath.e[i])
        # a step of nonzero length: a sum of squares is zero only where every square is
        moved = any(d * d > 0.0 for d in (toolpath.xyz[i] - pos).tolist())
        feed = float(toolpath.feed[i]) if moved else 0.0
        return dict(a=np.asarray(pos, float), b=np.asarray(target, float), layer=layer, printed_top=top,
                    retract=e if e < 0 else 0.0, unretract=e if e > 0 else 0.0, via=toolpath.xyz[i:i].copy(),
                    feed=(feed if feed > 0.0 or feed != feed else 0.0) or None)
    e = toolpath.e[i:j]
    steps = np.linalg.norm(toolpath.xyz[i:j] - np.concatenate([[pos], toolpath.xyz[i : j - 1]]), axis=1)
    return dict(
        a=np.asarray(pos, float),
        b=np.asarray(target, float),
        layer=layer,
        printed_top=top,
        retract=float(e[e < 0].sum()),
        unretract=float(e[e > 0].sum()),
        via=toolpath.xyz[i : j - 1].copy(),
        feed=float(toolpath.feed[i:j][steps > 0].max(initial=0.0)) or None,
    )


def toolpath_jobs(toolpath: Toolpath, ranges, laser: bool, offset: int = 0, top: float = 0.0, tops: dict | None = None,
                  made: bool = False):
    """The :class:`Job` of every run (``ranges``, :func:`split_runs`) and of the travels between
    them (and before the first, after the last), in print order, made one at a time: a print of
    270k runs would hold hundreds of MB of them at once. offset: the toolpath's first move's
    index in the print; top: the top of what is printed already (mm), for a toolpath that goes
    on from another; ``tops["before"]``, when given, is set to the printed top before each job
    yielded. made: each job made with its arguments (else made where it is planned)."""
    pos = toolpath.start
    prev_end = 0
    tops = {} if tops is None else tops
    for i, j in ranges:
        tops["before"] = top
        if i > prev_end:
            args = travel_args(toolpath, prev_end, i, pos, top) if made else None
            yield Job("travel", offset + prev_end, offset + i, prev_end, i, top, args)
        yield Job("run", offset + i, offset + j, i, j, top, run_spec(toolpath, i, j, laser) if made else None)
        pos = toolpath.xyz[j - 1]
        top = max(top, float(toolpath.xyz[i:j, 2].max()))
        prev_end = j
    if prev_end < len(toolpath):
        tops["before"] = top
        end = len(toolpath)
        args = travel_args(toolpath, prev_end, end, pos, top) if made else None
        yield Job("travel", offset + prev_end, offset + end, prev_end, end, top, args)


def job_chunks(chunks, tool, lead: dict):
    """:func:`job_toolpath` (without its end events) of a toolpath handed over in chunks: the
    chunks before the first working move are held and joined to the one that has it, which is
    handed on from that move; the chunks after it pass as they are (not checked here: anything
    that is not a Toolpath goes on to the caller's check). ``lead["feed"]`` is set to
    job_toolpath's fastest feed before the first working move once that chunk is handed on, and
    ``lead["dropped"]`` to the moves it replaced (less its prime move), for progress."""
    held = None
    for tp in chunks:
        if held is False or not isinstance(tp, Toolpath):
            yield tp
            continue
        held = tp if held is None else held.then(tp)
        if _working(held).any():
            job, lead["feed"] = job_toolpath(held, tool, end=False)
            lead["dropped"] = len(held) - len(job)
            yield job
            held = False
    if held:
        job, lead["feed"] = job_toolpath(held, tool, end=False)
        yield job


def stream_jobs(chunks, laser: bool):
    """:func:`toolpath_jobs` of consecutive chunks joined, holding one chunk and what is held back from
    the one before: the last run or travel of each chunk waits for the next chunk's moves; a run
    grown past STREAM_RUN moves is handed over as a "parts" job (:func:`_run_parts`), after
    which what follows it in its last chunk goes on."""
    held, at, top = None, 0, 0.0  # moves held back (from a job's first move), the first one's index, the printed top
    while True:
        tp = next(chunks, None)
        if tp is None:
            if held is not None:
                yield from toolpath_jobs(held, split_runs(held, laser), laser, at, top=top, made=True)
            return
        cur = tp if held is None else held.then(tp)
        tops = {}
        items = list(toolpath_jobs(cur, split_runs(cur, laser), laser, at, top=top, tops=tops, made=True))
        yield from items[:-1]
        kind, start = items[-1].kind, items[-1].start
        top = tops["before"]  # the last job's, which is held back
        held, at = cur.subset(slice(start - at, None)), start
        del cur, items
        if kind == "run" and len(held) > STREAM_RUN:
            after = {}
            yield Job("parts", at, at, 0, len(held), top, _run_parts(held, at, chunks, after, laser))
            if "at" not in after:
                raise DeltasliceError("plan_stream: a run handed over in parts was not planned to its end")
            held, at, top = after["rest"], after["at"], max(top, after["top"])


def _run_parts(run: Toolpath, at: int, chunks, after: dict, laser: bool):
    """RunSpecs of a run as it comes: ``run`` (a toolpath all of whose moves are the run, its first
    being move ``at`` of the print), then its moves in each chunk taken from ``chunks`` until it
    ends. Then ``after`` holds what is left: "rest" (the moves after the run in its last chunk, a
    Toolpath, or None), "at" (the first one's index) and "top" (the run's highest point, mm)."""
    top = float(run.xyz[:, 2].max())
    yield run_spec(run, 0, len(run), laser)
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
            yield run_spec(joined, 1, j0, laser)
            top = max(top, float(joined.xyz[1:j0, 2].max()))
        if j0 < len(joined):
            after.update(rest=joined.subset(slice(j0, None)), at=n + j0, top=top)
            return
        last, n = joined.subset(slice(len(joined) - 1, None)), n + len(joined) - 1
