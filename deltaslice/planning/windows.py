"""Long runs planned window by window (:func:`iter_windows`), so the planner's memory is bounded
by a window, not by the run (a spiral vase is one run of a million moves)."""

from __future__ import annotations

import numpy as np

from ..errors import PlanningError
from .context import PlanContext
from .runpath import RunSpec, _Polyline
from .solver import _plan_polyline, _StartTooFast


# A run of more than LONG_RUN segments is planned in windows of WINDOW segments (each planned
# LOOKAHEAD further), so the planner's memory is bounded by a window, not by the run; the
# lookahead is the price of that, a fraction of a window more solving each.
LONG_RUN = 8000
WINDOW = 6000
LOOKAHEAD = 1000  # segments each window plans past its cut (and at least LOOKAHEAD_MM)
LOOKAHEAD_MM = 50.0


def is_long(n_moves: int) -> bool:
    """Whether a run of ``n_moves`` moves is planned in windows (see :func:`iter_run`)."""
    return n_moves > LONG_RUN


def _stretches(box: list, tol: float):
    """A prepared polyline (taken out of ``box``, so only this generator holds it) as consecutive
    stretches of WINDOW segments (views, not copies), each with the blend tolerance ``tol`` (mm)."""
    poly = box.pop()
    m = len(poly.points) - 1
    for a in range(0, m, WINDOW):
        yield poly.part(a, min(a + WINDOW, m)), tol


class _Held:
    """The polyline of a long run, split at its cuts, held from one vertex (``v0``, an index in the
    split polyline) to as far as the windows have looked: stretches are taken from the run's
    iterator as they are needed and the part before a window that can no longer be planned again
    is dropped, so what is held is a few windows whatever the run's length.

    stretches: (polyline, blend tolerance left, mm) pairs. seg: (k,) the held segments' lengths, mm
    (a cut segment's two halves once it is split); tol: (k,) the tolerance left where each came
    from; s0: the arc length at v0 (mm), summed segment by segment from the run's start as
    ``np.cumsum`` sums, so the lookahead's arc lengths are the same bits however the run arrives."""

    def __init__(self, stretches):
        self.stretches = stretches
        self.v0, self.s0, self.ended = 0, 0.0, False
        first, tol = next(stretches)
        self.poly = first
        self.seg = np.linalg.norm(np.diff(first.points, axis=0), axis=1)
        self.tol = np.full(len(self.seg), tol)

    @property
    def last(self) -> int:
        """The index of the last vertex held."""
        return self.v0 + len(self.seg)

    def pull(self) -> bool:
        """Take the next stretch; False when the run has ended."""
        if self.ended:
            return False
        nxt = next(self.stretches, None)
        if nxt is None:
            self.ended = True
            return False
        nxt, tol = nxt
        p, cat = self.poly, np.concatenate
        power = None if p.power is None else cat([p.power, nxt.power])
        self.poly = _Polyline(cat([p.points, nxt.points[1:]]), cat([p.feed, nxt.feed]), cat([p.e, nxt.e]), power)
        self.seg = cat([self.seg, np.linalg.norm(np.diff(nxt.points, axis=0), axis=1)])
        self.tol = cat([self.tol, np.full(len(nxt.points) - 1, tol)])
        return True

    def reach(self, v: int) -> None:
        """Hold vertex v, or up to the run's end."""
        while self.last < v and self.pull():
            pass

    def arc_ends(self) -> np.ndarray:
        """The arc length at the end of every held segment (mm, from the run's start)."""
        return np.cumsum(np.concatenate([[self.s0], self.seg]))[1:]

    def reach_arc(self, s: float) -> None:
        """Hold the run up to arc length s (mm), or to its end."""
        while (self.arc_ends()[-1] if len(self.seg) else self.s0) < s and self.pull():
            pass

    def split(self, c: int) -> None:
        """Split segment c at its middle: a new vertex c + 1, half the filament on either side."""
        i, p = c - self.v0, self.poly
        mid = 0.5 * (p.points[i] + p.points[i + 1])
        halves = np.linalg.norm(np.diff(np.stack([p.points[i : i + 1], mid[None], p.points[i + 1 : i + 2]], axis=1),
                                        axis=1), axis=2)[0]
        e = p.e.copy()
        e[i] *= 0.5
        power = None if p.power is None else np.insert(p.power, i + 1, p.power[i])
        self.poly = _Polyline(np.insert(p.points, i + 1, mid, axis=0), np.insert(p.feed, i + 1, p.feed[i]),
                              np.insert(e, i + 1, e[i]), power)
        self.seg = np.insert(self.seg, i + 1, halves[1])
        self.seg[i] = halves[0]
        self.tol = np.insert(self.tol, i + 1, self.tol[i])

    def drop_before(self, v: int) -> None:
        """Let go of the vertices before v (copied, so the memory goes)."""
        i = v - self.v0
        if i <= 0:
            return
        self.s0 = float(np.cumsum(np.concatenate([[self.s0], self.seg[:i]]))[-1])
        p = self.poly
        self.poly = _Polyline(p.points[i:].copy(), p.feed[i:].copy(), p.e[i:].copy(),
                              None if p.power is None else p.power[i:].copy())
        self.seg, self.tol = self.seg[i:].copy(), self.tol[i:].copy()
        self.v0 = v

    def part(self, a: int, b: int) -> tuple[_Polyline, float]:
        """Vertices a..b of the split polyline, and the blend tolerance left along them (mm)."""
        return self.poly.part(a - self.v0, b - self.v0), float(self.tol[a - self.v0 : b - self.v0].min())


def _next_cut(held: _Held, prev: int) -> int | None:
    """The vertex the next window ends at, after the one ending at vertex ``prev``: its segment split
    at the middle of the longest segment within WINDOW // 8 of WINDOW segments on (a straight point:
    no blend arc crosses it, both windows see the same geometry around it); None when fewer than
    WINDOW // 2 segments would follow it (the last window takes them)."""
    target = prev + WINDOW
    held.reach(target + WINDOW // 2 + 1)
    if not target < held.last - WINDOW // 2:
        return None
    lo, hi = target - WINDOW // 8, min(target + WINDOW // 8, held.last - 1)
    c = lo + int(np.argmax(held.seg[lo - held.v0 : hi - held.v0]))
    held.split(c)
    return c + 1


def _iter_windows(ctx: PlanContext, spec: RunSpec, stretches, kind: str):
    """A long run planned window by window so the planner's memory is bounded by a window, not
    the run (a spiral vase is one run of a million moves). Each window plans its WINDOW
    segments plus a lookahead to rest, then keeps the part up to its cut, ending at the speed
    the lookahead allowed there; the next window starts at that speed, so the pieces join
    without stopping. Cuts are at the middle of the longest segment near every WINDOW-th
    (:func:`_next_cut`). A window that cannot start that fast (its grid refined differently)
    makes the previous one re-plan to the speed it can start at (so each piece is handed out
    only once its successor has started). ``stretches``: the run's prepared polyline in
    consecutive stretches with the blend tolerance left in each, taken as the windows reach them
    (:class:`_Held`); spec: the run (its tool, layer and power mode). Yields (piece, segments of
    the run done)."""
    held = _Held(stretches)
    ends = [0]  # the windows' first vertices, and the run's last once known
    final = False  # whether ends[-1] is the run's last vertex

    def add_cut() -> None:
        nonlocal final
        c = _next_cut(held, ends[-1])
        final = c is None
        ends.append(held.last if final else c)

    held_piece, starts, k = None, [0.0], 0  # held_piece: the last window's, until the next one starts
    caps = {}  # window -> the fastest its successor can start, after a re-plan
    while True:
        while not final and len(ends) < k + 2:
            add_cut()
        if k >= len(ends) - 1:
            break
        if k:
            held.drop_before(ends[k - 1])  # the previous window may still be planned again
        a, b = ends[k], ends[k + 1]
        last = final and k == len(ends) - 2
        end = b
        if not last:
            # Look ahead LOOKAHEAD segments and at least LOOKAHEAD_MM past the cut, every cut in
            # that stretch decided first.
            while True:
                held.reach(b + LOOKAHEAD)
                s_cut = held.arc_ends()[b - 1 - held.v0]
                held.reach_arc(s_cut + LOOKAHEAD_MM)
                far = held.v0 + int(np.searchsorted(held.arc_ends(), s_cut + LOOKAHEAD_MM)) + 1
                end = max(b + LOOKAHEAD, far)
                if held.ended:
                    end = min(held.last, end)
                # a cut is decided before the windows reach it: splitting a segment later would move
                # the arc lengths this lookahead was measured with (deciding one early changes nothing)
                if final or ends[-1] + WINDOW - WINDOW // 8 > end + 1:
                    break
                add_cut()
            held.reach(end)
        cap = None if last else (b - a, caps.get(k, np.inf))
        poly, tol = held.part(a, end)
        try:
            piece, cut_speed = _plan_polyline(ctx, spec, poly, tol, kind, v_start=starts[k], cap=cap)
        except _StartTooFast as exc:
            if held_piece is None or k - 1 in caps:  # the previous piece is gone already, or was re-planned once
                raise PlanningError(f"layer {spec.layer}: a long run's windows do not join (start {starts[k]:.4g} mm/s, "
                                    f"at most {exc.speed:.4g} mm/s)") from None
            caps[k - 1] = exc.speed
            held_piece = None
            del starts[k:]
            k -= 1
            continue
        if held_piece is not None:
            yield held_piece, a - k
        held_piece = piece
        starts.append(cut_speed)
        k += 1
    yield held_piece, ends[-1] - (len(ends) - 2)
