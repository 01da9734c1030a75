"""What a file's moves mean once read: which work and how (its dialect), their layers and heights,
and the Toolpath columns (whole, or a stretch of a stream)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..toolpath import Role, Toolpath, centred, make_events
from .reader import _ReadState
from .source import _source_notes

#: How notes name Slic3r 1.3's no-extrusion G-code (the E register written without its letter).
_SLIC3R_NO_EXTRUSION = "Slic3r no-extrusion flavour"

def _whole(state: _ReadState, raw: list, printer, shown, echo, center) -> Toolpath:
    """The Toolpath of a file read whole: ``raw``, a list of _RAW's columns of all its moves (typed
    arrays or numpy arrays, each taken out of the list as soon as it is copied)."""
    n = state.n
    # Built column by column and each typed array dropped once copied: peak memory is what the
    # toolpath keeps plus a few columns, not several copies of every move (a vase has millions).
    xyz = np.empty((n, 3))
    for col in range(3):
        xyz[:, col] = np.frombuffer(raw[col], dtype=np.float64)
        raw[col] = None
    layer = np.array(raw[6], dtype=np.int32) if state.have_layer_comments else None
    raw[6] = None
    cols = _moves(xyz, raw, layer)
    del raw
    say = echo or (lambda _s: None)
    working, e, tool, moved = _work(state, printer, cols, state.start)
    note = _dialect_note(printer, state)
    if note:
        say(f"{shown}: {note}")
    if state.have_layer_comments:
        layer_z = _layer_heights(state, _layer_stats(None, layer, xyz[:, 2], working, state.n_layers))
    else:
        layer, layer_z = _layers_from_z(xyz[:, 2], working)
    ratio = _source_notes(state.source, printer, shown, say, center)
    columns = _columns(state, printer, cols, working, e, tool, moved, layer, layer_z, state.start, ratio, [0.0])
    tp = Toolpath(state.start, *columns, layer_z, make_events(state.events))
    if center:
        tp, shift = centred(tp)
        say(f"{shown}: moved the part by ({shift[0]:.2f}, {shift[1]:.2f}) mm so its footprint is centred on the bed")
    return tp


@dataclass(frozen=True)
class _Moves:
    """A stretch of a file's moves as read: xyz (n, 3) mm; e (n,) mm as written; feed (n,) mm/s;
    role_comment (n,) int16 (-1: none); layer (n,) int32 or None (no layer comments); kind (n,) int8
    (0 G0, 1 no E word, 2 an E word, 3 a bare number); power (n,) S while the laser is on; lmode (n,)
    int8, the laser mode."""

    xyz: np.ndarray
    e: np.ndarray
    feed: np.ndarray
    role_comment: np.ndarray
    layer: np.ndarray | None
    kind: np.ndarray
    power: np.ndarray
    lmode: np.ndarray


def _motion(cols: _Moves, start) -> tuple[np.ndarray, np.ndarray]:
    """(moved, moved_xy) (n,) bool of moves starting at ``start`` (3,) mm, the point before the first."""
    starts = np.vstack([np.asarray(start, float)[None], cols.xyz[:-1]])
    moved_xy = np.any(starts[:, :2] != cols.xyz[:, :2], axis=1)  # finite numbers (the parser refuses others)
    return moved_xy | (starts[:, 2] != cols.xyz[:, 2]), moved_xy


def _moves(xyz, raw: list, layer) -> _Moves:
    """_Moves of _RAW's typed arrays in the list ``raw`` (x, y and z already in ``xyz``), each
    copied to an array of its own and let go of at once (reading a vase holds a few columns, not
    every column twice)."""
    cols = []
    for k, dtype in ((3, np.float64), (4, np.float64), (5, np.int16), (7, np.int8), (8, np.float64), (9, np.int8)):
        cols.append(np.array(raw[k], dtype=dtype))
        raw[k] = None
    e, feed, role_comment, kind, power, lmode = cols
    return _Moves(xyz, e, feed, role_comment, layer, kind, power, lmode)


def _work(state: _ReadState, printer, cols: _Moves, start):
    """(working, e, tool, moved) of a stretch of moves (see :func:`_apply_dialects`)."""
    moved, moved_xy = _motion(cols, start)
    e, tool, working = _apply_dialects(printer, cols.e, cols.kind, cols.power, moved, moved_xy, state.e_words,
                                       state.bare_words, state.laser_seen)
    return working, e, tool, moved


def _columns(state: _ReadState, printer, cols: _Moves, working, e, tool, moved, layer, layer_z, start, ratio, retracted):
    """(xyz, feed, e, tool, role, layer): a stretch of moves as toolpath columns, read-only (given
    to the toolpath, which keeps them rather than copies). start: the point before the first move;
    ratio: the filament rescale (:func:`_source_notes`) or None; retracted: a one-element list, the
    filament retracted and not yet pushed back before the stretch, updated to after it."""
    laser = printer is not None and printer.tool.takes_laser_power
    rc = cols.role_comment
    role = np.where(working, np.where(rc >= 0, rc, int(Role.LASER if laser else Role.OTHER)), int(Role.TRAVEL))
    role = np.where(~moved & (e != 0), int(Role.RETRACT), role).astype(np.uint8)
    if len(cols.lmode):  # GRBL M4: power follows the tool's speed (Role.LASER_DYNAMIC), M3 constant
        role = np.where(working & (cols.lmode == 4), int(Role.LASER_DYNAMIC), role).astype(np.uint8)
    if not state.e_words and printer is not None and not laser:
        e = _flow_model_e(printer, cols.xyz, np.vstack([np.asarray(start, float)[None], cols.xyz[:-1]]), working, layer,
                          layer_z, e)
    if ratio is not None:
        e, retracted[0] = _rescale_filament(e, cols.kind == 2, moved, ratio, retracted[0])
    xyz, feed = cols.xyz, np.asarray(cols.feed, dtype=np.float64)
    layer = np.asarray(layer, dtype=np.int32)
    for column in (xyz, feed, e, tool, role, layer):
        column.setflags(write=False)
    return xyz, feed, e, tool, role, layer


def _layer_stats(stats, layer, z, working, n_layers: int):
    """What a stretch of moves tells of the layers' heights, added to ``stats`` (the stretches
    before it, or None): per layer (L,) the highest working move's z (-inf: none) and the last
    move's z (NaN: none)."""
    if stats is None:
        stats = (np.full(n_layers, -np.inf), np.full(n_layers, np.nan))
    top, last = stats
    np.maximum.at(top, layer[working], z[working])
    present, first_from_end = np.unique(layer[::-1], return_index=True)
    last[present] = z[len(z) - 1 - first_from_end]
    return top, last


def _layer_heights(state: _ReadState, stats) -> np.ndarray:
    """(L,) layer heights, mm: a layer's ;Z: comment, else its highest working move, else its
    last move, else the layer's before (0 for the first). stats: :func:`_layer_stats` of every
    move (None when every layer has its comment)."""
    layer_z = np.zeros(state.n_layers)
    for li in range(state.n_layers):
        if li in state.layer_z_comment:
            layer_z[li] = state.layer_z_comment[li]
        elif stats[0][li] > -np.inf:
            layer_z[li] = stats[0][li]
        elif stats[1][li] == stats[1][li]:
            layer_z[li] = stats[1][li]
        else:
            layer_z[li] = layer_z[li - 1] if li else 0.0
    return layer_z


def _apply_dialects(printer, e, kind, power, moved, moved_xy, e_words, bare_words, laser_seen):
    """(e, tool, working): which moves work and how, as the file's author meant (the note saying
    so: :func:`_dialect_note`).

    * E words (the common case): a move that goes somewhere and pushes filament works.
    * Slic3r's no-extrusion flavour writes the E register without its letter; its amounts do
      not change along working moves, so a move carrying the bare number works and is given the
      printer's flow model (:func:`_flow_model_e`); standing bare numbers stay retracts and
      unretracts (read from the register Slic3r resets after each retraction, see the parser),
      moving ones that lower the register are wipes (travels).
    * No E at all (hand-written paths, CNC-style files): G1/G2/G3 moves in x-y work, G0 travel.
    * A laser printer: with M3/M4 the power is S / s_max while G1/G2/G3 move; without them the
      G1 rule above switches the laser on at full power (E words never reach here: the reader
      refuses them for a tool that takes no filament).
    """
    laser = printer is not None and printer.tool.takes_laser_power
    if laser and laser_seen:
        s_max = getattr(printer.tool, "s_max", 1000.0)
        # the tool channel is a fraction of full power (0..1); max_power (W) is what 1 burns (verify reports it)
        frac = np.clip(power / s_max, 0.0, 1.0)
        working = moved & (kind >= 1) & (frac > 0)
        return np.zeros(len(e)), np.where(working, frac, 0.0), working
    if bare_words and not e_words:
        # a bare-number move that lowers the register is a wipe (Slic3r's retraction while it
        # travels back over the perimeter it just printed): a travel with its retraction, not work
        working = moved_xy & (kind == 3) & (e >= 0)
    elif not e_words and not bare_words:
        working = moved_xy & (kind >= 1)
    else:
        working = moved & (e > 0)
    tool = working.astype(float)  # full extrusion, or full laser power (a fraction, not watts)
    if laser:
        e = np.zeros(len(e))
    elif bare_words and not e_words:
        e = np.where(working, 0.0, e)  # replaced by the flow model
    return e, tool, working


def _dialect_note(printer, state: _ReadState) -> str:
    """What :func:`_apply_dialects` makes of a file whose dialect is not the common one, or ""."""
    laser = printer is not None and printer.tool.takes_laser_power
    if laser and state.laser_seen:
        return ""
    if state.bare_words and not state.e_words:
        return (f"{_SLIC3R_NO_EXTRUSION}: E values without their letter; moves carrying one are work moves"
                " extruded with the printer's own flow model, those lowering it wipes; each unretraction is read "
                "from 0 (Slic3r resets its E register "
                "after a retraction without writing G92 E0)")
    if not state.e_words and not state.bare_words:
        return ("no E words: G1/G2/G3 moves are work moves "
                + ("with the laser on" if laser else ("extruded with the printer's own flow model" if printer is not None
                                                       else "(no printer given: no filament amounts)"))
                + ", G0 moves are travels")
    return ""


def _flow_model_e(printer, xyz, starts, sel, layer, layer_z, e):
    """Filament for the moves ``sel`` from the printer's flow model: the perimeter width (first
    layer width on layer 0) and the file's own layer thickness, as deltaslice's slicer extrudes."""
    from ..slicing.extrusion import filament_per_mm

    s = printer.slicing
    out = np.array(e, float)
    if not sel.any():
        return out
    thick = np.diff(np.concatenate([[0.0], layer_z]))
    thick = np.where(thick > 0, thick, s.layer_height)
    idx = np.flatnonzero(sel)
    h = thick[layer[idx]]
    w = np.where(layer[idx] == 0, s.first_layer_width, s.perimeter_width)
    keys, inverse = np.unique(np.column_stack([w, h]), axis=0, return_inverse=True)
    rate = np.array([filament_per_mm(wi, hi, printer.tool.filament_area, s.extrusion_multiplier) for wi, hi in keys])
    out[idx] = np.linalg.norm(xyz[idx] - starts[idx], axis=1) * rate[inverse.reshape(-1)]
    return out


def _rescale_filament(e, written, moved, ratio, retracted: float = 0.0):
    """(E of the moves ``written`` (with E words) for a filament of area ``ratio`` times the file's,
    the length retracted and not pushed back after them); retracted: that length before them.

    Filament pushed along a move is plastic laid down: a volume, scaled by the area ratio. A
    retraction is not: it pulls a length of filament back to relieve the melt chamber, and the
    file's slicer chose that length for the drive and hot end, not for a volume (scaled, 2 mm
    becomes 0.68 mm on a 3 mm printer and barely relieves anything). So negative amounts (standing
    retractions and wipes) keep their length, and so does the standing push that undoes them; only
    what a standing push adds beyond what is retracted (a prime, a restart extra) is plastic, scaled.
    """
    out = np.where(written & moved & (e > 0), e * ratio, e)
    for i in np.flatnonzero(written & ((e < 0) | (~moved & (e > 0)))):
        if e[i] < 0:
            retracted -= e[i]
        else:
            back = min(e[i], retracted)
            retracted -= back
            out[i] = back + (e[i] - back) * ratio
    return out, retracted


def _layers_from_z(z: np.ndarray, working: np.ndarray):
    """Layers from the heights of working moves: a new layer starts at each working
    move higher than every earlier one; the travels leading to it belong to it.
    (:meth:`GcodeStream._find_layers` takes the same two steps a block at a time.)"""
    if not working.any():
        return np.zeros(len(z), np.int32), np.array([float(z.max())])
    new, _top = _new_layers(z, working, -np.inf)
    lay_at = np.cumsum(new, dtype=np.int32) - 1
    return _layer_owners(lay_at, working, lay_at[-1]), z[new]


def _new_layers(z: np.ndarray, working: np.ndarray, top: float):
    """(new (n,) bool: the working moves higher by more than a micron than every working move
    before them and than ``top`` (mm, the highest working move before these), the highest
    working move's z after them)."""
    prev_max = np.maximum.accumulate(np.where(working, z, -np.inf))
    after = max(top, float(prev_max[-1])) if len(z) else top
    prev_max[1:] = prev_max[:-1].copy()
    prev_max[0] = -np.inf
    np.maximum(prev_max, top, out=prev_max)
    return working & (z > prev_max + 1e-6), after


def _layer_owners(lay_at: np.ndarray, working: np.ndarray, following: int) -> np.ndarray:
    """(n,) int32 the layer of every move: a working move's is ``lay_at`` (the layer begun at or
    before it), any other's the next working move's, or ``following`` after the last one."""
    # int32 indices throughout (a G-code of 2^31 moves is far beyond what is read): these
    # temporaries are the largest of reading a file without layer comments
    n = len(lay_at)
    nxt_work = np.minimum.accumulate(np.where(working, np.arange(n, dtype=np.int32), np.int32(n))[::-1])[::-1]
    owner = np.where(nxt_work < n, lay_at[np.minimum(nxt_work, n - 1)], following)
    del nxt_work
    owner = np.where(working, lay_at, owner)
    return np.maximum(owner, 0).astype(np.int32)
