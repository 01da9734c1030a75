"""Cooling: minimum layer time (slowdown) and part-fan events, on a sliced toolpath.

PrusaSlicer's CoolingBuffer, per layer: the layer's time at its feeds decides the fan speed
(``max_fan_speed`` below ``slowdown_below_layer_time``, falling linearly to ``min_fan_speed`` at
``fan_below_layer_time``, off on the first ``disable_fan_first_layers`` layers), and a layer
quicker than ``slowdown_below_layer_time`` has its working moves slowed (none below
``min_print_speed``) until it takes that long. Bridges and overhang perimeters run the fan at
their own speeds. Whole-toolpath numpy: per-move arrays reduced per layer with ``bincount``.
"""

from __future__ import annotations

import numpy as np

from ..toolpath import EventKind, Role, Toolpath, make_events

SLOWDOWN_STEPS = 48  # bisection steps on the slowdown factor (its range halves each step)


def move_times(tp: Toolpath, feed: np.ndarray | None = None) -> np.ndarray:
    """Time of every move at its requested feed, s ((n,) f8): length / feed, or for a retract
    (no length) the filament moved / feed."""
    feed = tp.feed if feed is None else feed
    dist = tp.lengths
    return np.where(dist > 0, dist, np.abs(tp.e)) / feed


def layer_times(tp: Toolpath, feed: np.ndarray | None = None) -> np.ndarray:
    """Time of every layer at the moves' feeds, s ((L,) f8), travels and retracts included."""
    return np.bincount(tp.layer, move_times(tp, feed), minlength=tp.n_layers)


def slowed_feeds(tp: Toolpath, target: float, min_speed: float) -> np.ndarray:
    """Feeds ((n,) mm/s) that make every layer take at least ``target`` s where they can: the
    working moves of a quicker layer slowed by one factor k per layer (feed / k), none below
    ``min_speed`` (nor raised to it). k is found by bisection, all layers at once."""
    feed = tp.feed.copy()
    if target <= 0 or not len(tp):
        return feed
    t0 = layer_times(tp)
    short = t0 < target
    adjustable = tp.working & (feed > min_speed) & short[tp.layer]
    if not adjustable.any():
        return feed
    idx = np.flatnonzero(adjustable)
    lay, f, dist = tp.layer[idx], feed[idx], tp.lengths[idx]
    fixed = t0 - np.bincount(lay, dist / f, minlength=tp.n_layers)  # time of what is not slowed
    floor = np.full(len(f), min_speed)

    def time_at(k):
        return fixed + np.bincount(lay, dist / np.maximum(f / k[lay], floor), minlength=tp.n_layers)

    lo = np.ones(tp.n_layers)
    hi = np.ones(tp.n_layers)
    np.maximum.at(hi, lay, f / min_speed)  # at this factor every adjustable move is at min_speed
    for _ in range(SLOWDOWN_STEPS):
        mid = np.sqrt(lo * hi)
        enough = time_at(mid) >= target
        hi = np.where(enough, mid, hi)
        lo = np.where(enough, lo, mid)
    # hi: the least factor found that reaches the target (the largest, all at min_speed, when none does)
    feed[idx] = np.maximum(f / hi[lay], floor)
    return feed


def fan_percent(times: np.ndarray, c) -> np.ndarray:
    """Fan speed of each layer, percent ((L,)), from its time before slowdown ((L,) s)."""
    t = np.asarray(times, float)
    span = c.fan_below_layer_time - c.slowdown_below_layer_time
    if span > 0:
        ramp = np.clip((t - c.slowdown_below_layer_time) / span, 0.0, 1.0)
    else:
        ramp = (t >= c.slowdown_below_layer_time).astype(float)
    out = c.max_fan_speed + (c.min_fan_speed - c.max_fan_speed) * ramp
    out[: c.disable_fan_first_layers] = 0.0
    return out


def fan_values(tp: Toolpath, layer_fan: np.ndarray, c) -> np.ndarray:
    """The fan value (0..255) wanted at every move ((n,) f8): the layer's, or the bridge / overhang
    speed on those moves (not on the first ``disable_fan_first_layers`` layers). A travel takes
    the value of the working move it leads to, so the fan changes before the bridge starts."""
    on = tp.layer >= c.disable_fan_first_layers
    want = layer_fan[tp.layer].copy()
    want[on & (tp.role == Role.BRIDGE_INFILL)] = c.bridge_fan_speed
    want[on & (tp.role == Role.OVERHANG_PERIMETER)] = c.overhang_fan_speed
    work = np.flatnonzero(tp.working)
    if len(work):
        nxt = np.minimum(np.searchsorted(work, np.arange(len(tp))), len(work) - 1)
        want = want[work[nxt]]
    return np.round(np.round(want) * 2.55)  # whole percent first, as PrusaSlicer: no M106 for a 0.3 % change


def apply_cooling(tp: Toolpath, c) -> Toolpath:
    """``tp`` with its layers slowed to the minimum layer time and FAN events (0..255) where the
    wanted fan value changes (the fan is taken as off before the first move). c: the printer's
    :class:`~deltaslice.machine.settings.CoolingSettings`."""
    if not len(tp) or not tp.n_layers:
        return tp
    times = layer_times(tp)
    feed = slowed_feeds(tp, c.slowdown_below_layer_time, c.min_print_speed)
    want = fan_values(tp, fan_percent(times, c), c)
    prev = np.concatenate([[0.0], want[:-1]])
    at = np.flatnonzero(want != prev)
    rows = [tuple(r) for r in tp.events.tolist()] + [(int(i), int(EventKind.FAN), float(want[i])) for i in at]
    return Toolpath(tp.start, tp.xyz, feed, tp.e, tp.tool, tp.role, tp.layer, tp.layer_z, make_events(rows))
