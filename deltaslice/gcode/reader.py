"""Reading G-code lines into per-move columns: one handler per command (a table from the command
word to a method of :class:`_Reader`, as Klipper's G-code dispatch), the reader's state in one
object. What the moves mean (work or travel, layers, filament) is :mod:`.moves`'."""

from __future__ import annotations

import math
import re
from array import array
from collections import Counter
from dataclasses import dataclass

import numpy as np

from ..errors import GcodeError
from ..toolpath import EventKind, Role
from .arcs import ARC_CHORDS_BASE, ARC_CHORDS_PER_LINE, _arc_points, _ArcBudget
from .source import _source_machine
from .words import _COMMAND, _LINE_NUMBER, _SETTING, _START_TAG, _TYPE_TO_ROLE, _number, _params, _words

#: Feed used before the file sets one (mm/s) when no printer is given.
DEFAULT_FEED = 50.0
# No move of a print pushes or pulls 10 m of filament (a Bowden tube's load is under 1 m). More
# is E in other units or read in the wrong mode (absolute vs relative); E1e6 alone was 9 h of
# filament-only motion whose verify ran out of memory.
MAX_MOVE_FILAMENT = 10_000.0

_MOTION = {"G0": 0, "G1": 1, "G2": 2, "G3": 3}
_EVENT_M = {
    "M104": EventKind.HOTEND_SET, "M109": EventKind.HOTEND_WAIT, "M140": EventKind.BED_SET,
    "M190": EventKind.BED_WAIT, "M106": EventKind.FAN, "M107": EventKind.FAN,
}
_LASER_M = {"M3": 3, "M4": 4, "M5": 0}
_MOTION_LETTERS = set("XYZEFIJRS")

# The columns the reader gathers per move, in this order (typecodes of array.array), and the
# bytes of a move before each column and in all (a block of a stream's temporary file holds its
# moves column after column).
_RAW = (("x", "d"), ("y", "d"), ("z", "d"), ("e", "d"), ("feed", "d"), ("role", "h"), ("layer", "i"), ("kind", "b"),
        ("power", "d"), ("lmode", "b"))
_RAW_OFFSETS = np.cumsum([0] + [np.dtype(code).itemsize for _name, code in _RAW]).tolist()


@dataclass
class _ReadState:
    """What reading a file found besides its moves: the start point, the events (move index, kind,
    value), the dialect (E words, bare numbers, laser commands), the layer comments and heights,
    the settings block; kept: the moves' columns when no sink took them (_RAW's arrays)."""

    start: np.ndarray
    n: int
    events: list
    e_words: bool
    bare_words: bool
    laser_seen: bool
    have_layer_comments: bool
    n_layers: int
    layer_z_comment: dict
    source: dict
    kept: tuple | None


def _new_columns() -> tuple:
    """Empty typed arrays, one per _RAW column: a 60 MB G-code has 1.5 M moves (8 bytes a value,
    not a Python number's 32)."""
    return tuple(array(code) for _name, code in _RAW)


class _Reader:
    """The state of reading one file, line by line (:meth:`line`), and the handler of each command.

    Modal state: position (bed frame) and the G92 offset (bed = file + offset after the first
    move), the E register, absolute or relative positions and E, the unit, the feed, the motion
    mode, the plane, the laser's mode and power. Found so far: the dialect, layer and role
    comments, the settings block, events, skipped commands, the moves' columns."""

    # slots: a dozen of these are read on every line of a file of millions
    __slots__ = ("abs_e", "abs_xyz", "arc_chords", "bare_retracted", "bare_words", "bed", "block", "columns",
                 "cura_settings", "default_feed", "e_most", "e_pushed", "e_reg", "e_words", "events", "feed", "handed",
                 "have_layer_comments", "laser_mode", "laser_seen", "layer_idx", "layer_z_comment", "line_no",
                 "motion_mode", "offset", "plane", "pos", "printer", "prusa_layers", "retract_bound", "role_comment",
                 "s_value", "settings", "shown", "shown_line", "sink", "skipped", "start", "started", "takes_filament",
                 "takes_laser_power", "tool", "unit", "where", "z_hi", "z_lo")

    def __init__(self, name: str, prusa_layers: bool, printer, sink, block: int):
        self.shown, self.prusa_layers, self.printer, self.sink, self.block = name, prusa_layers, printer, sink, block
        self.default_feed = printer.slicing.travel_speed if printer is not None and hasattr(printer, "slicing") \
            else DEFAULT_FEED
        self.bed = getattr(printer, "bed", None)
        # the heights the printer's bed allows (its work envelope), checked here so a refusal names
        # the line; the envelope's x-y extent waits for the placement (--center), planning.check_reachable
        self.z_lo, self.z_hi = self.bed.z_limits() if self.bed is not None else (-math.inf, math.inf)
        tool = self.tool = getattr(printer, "tool", None)
        # the other kind of tool's words are refused, not reinterpreted: E words fired the laser
        self.takes_filament = tool is None or tool.takes_filament
        self.takes_laser_power = tool is None or tool.takes_laser_power
        # filament pushed so far and the most it ever was (mm, the file's amounts): their difference
        # is how far the filament is pulled back, retractions in a row adding up
        self.retract_bound = tool.max_retract_length if tool is not None else math.inf
        self.e_pushed = self.e_most = 0.0
        self.start = np.zeros(3)
        self.pos = [0.0, 0.0, 0.0]
        self.offset = [0.0, 0.0, 0.0]
        self.e_reg = 0.0
        self.abs_xyz = self.abs_e = True
        self.unit = 1.0
        self.feed = None
        self.motion_mode = None
        self.plane = "G17"
        self.laser_mode = 0
        self.s_value = 0.0
        self.laser_seen = self.e_words = self.bare_words = False
        # Slic3r's no-extrusion flavour (see _extrusion): 0 nothing retracted; 1 a bare number lowered
        # the register (a retraction, maybe still going on); 2 then a move without a bare number (the travel)
        self.bare_retracted = 0
        self.role_comment = None
        self.layer_idx = -1  # from comments
        self.layer_z_comment: dict[int, float] = {}
        self.have_layer_comments = False
        self.settings: dict[str, str] = {}
        self.cura_settings: list[str] = []
        # per move: x y z e (file's mm), feed mm/s, role from comment or -1, layer, kind (0 G0, 1 G1..G3
        # without an E word, 2 with E, 3 with a bare-number E), laser power S while M3/M4 is on else 0,
        # laser mode (0 off, 3 constant M3, 4 dynamic M4)
        self.columns = _new_columns()
        self.events: list[tuple[int, int, float]] = []
        self.skipped: Counter = Counter()
        self.started = False
        self.handed = 0  # moves handed to the sink
        self.arc_chords = 0  # points all arcs so far became (bounded: ARC_CHORDS_BASE)
        self.line_no, self.where, self.shown_line = 0, name, ""

    # ------------------------------------------------------------------ lines

    def line(self, line_no: int, line: str) -> None:
        """Read one line of the file (without its newline)."""
        s = line.strip()
        if not s:
            return
        if s[0] == ";":
            self._comment(s, line_no)
            return
        self.line_no, self.where, self.shown_line = line_no, f"{self.shown}:{line_no}", s
        cut = s.find(";")
        if cut >= 0:
            s = s[:cut]
        if "(" in s:
            s = re.sub(r"\([^)]*\)", "", s)
        s = s.strip()
        if not s or s == "%":
            return
        if s[0] in "Nn":  # line numbers and checksums
            s = _LINE_NUMBER.sub("", s).split("*")[0].strip()
            if not s:
                return
        found = self._line_words(s)
        if found is None:
            return
        cmds, params_w = self._commands(*found)
        for cmd in cmds:
            _HANDLERS.get(cmd, _Reader._skip)(self, cmd, params_w)

    def _line_words(self, s: str):
        """(words, whether the line has no command word of its own) of a command line, or None when
        the line is done with (a skipped M or T command, whose parameters may be free text as in
        M117 Hello; GRBL's power and feed alone)."""
        where, shown_line = self.where, self.shown_line
        head = _COMMAND.match(s)
        if head is not None:
            cmd = head.group(1).upper() + head.group(2)
            if cmd[0] in "MT" and cmd not in _HANDLERS:
                self.skipped[cmd] += 1
                return None
            return _words(s, where, shown_line), False
        if s[0].upper() not in _MOTION_LETTERS:
            raise GcodeError(f"{where}: {shown_line!r} does not start with a G, M or T command")
        words = _words(s, where, shown_line)
        if self.motion_mode is not None:
            return words, True
        if {w[0] for w in words} <= {"F", "S"}:  # GRBL sets power and feed on their own lines
            given = _params(words, where, "FS")
            self.s_value = given.get("S", self.s_value)
            if given.get("F", 1.0) <= 0:
                raise GcodeError(f"{where}: feed F{given['F']:g} must be > 0")
            self.feed = given["F"] * self.unit / 60.0 if "F" in given else self.feed
            return None
        raise GcodeError(f"{where}: {shown_line!r} has no command and no motion mode is active (expected G0/G1 first)")

    def _commands(self, words, modal: bool):
        """(commands, parameter words) of a line: several modal G codes (G90 G21) may share it; a
        motion, G92 or M command must stand alone, or what its numbers mean would be ambiguous.
        modal: the line has no command word of its own (the motion mode's parameters)."""
        where = self.where
        cmds, params_w = ([self.motion_mode] if modal else []), []
        for letter, num in words:
            if letter in ("G", "M", "T"):
                v = _number(letter, num, where)
                cmds.append(letter + (str(int(v)) if v.is_integer() else num))
            else:
                params_w.append((letter, num))
        if len(cmds) > 1:
            acting = [c for c in cmds if c in _MOTION or c == "G92" or c[0] != "G"]
            if acting or len(set(cmds)) != len(cmds):
                raise GcodeError(f"{where}: conflicting commands {' '.join(cmds)} on one line: give each its own line")
            if params_w:
                raise GcodeError(f"{where}: parameters {params_w[0][0]}{params_w[0][1]} with several commands {' '.join(cmds)}")
        return cmds, params_w

    def _comment(self, s: str, line_no: int) -> None:
        """A comment line: layer changes and heights, the role, deltaslice's start point, settings."""
        c = s[1:]
        if c.startswith("LAYER:") and not self.prusa_layers:
            self.have_layer_comments = True
            self.layer_idx += 1
        elif c.startswith("LAYER_CHANGE") and c.strip() == "LAYER_CHANGE":
            self.have_layer_comments = True
            self.layer_idx += 1
        elif c.startswith("Z:") and self.layer_idx >= 0 and self.layer_idx not in self.layer_z_comment:
            try:
                z = float(c[2:]) * self.unit
                if math.isfinite(z):
                    self.layer_z_comment[self.layer_idx] = z
            except ValueError:
                pass
        elif c.startswith("TYPE:"):
            self.role_comment = int(_TYPE_TO_ROLE.get(c[5:].strip().upper(), Role.OTHER))
        elif s.startswith(_START_TAG) and not self.started:
            try:
                start = np.array([float(v) for v in s[len(_START_TAG):].split()[:3]])
                if start.shape != (3,) or not np.all(np.isfinite(start)):
                    raise ValueError
            except ValueError:
                raise GcodeError(f"{self.shown}:{line_no}: malformed start comment {s!r}") from None
            self.start = start
            self.pos = list(start)
        elif c.startswith("SETTING_3 "):
            self.cura_settings.append(c[10:])
        elif "=" in c:
            m = _SETTING.match(s)
            if m:
                self.settings[m.group(1)] = m.group(2)

    # ------------------------------------------------------------------ motion: G0 G1 G2 G3

    def _move(self, cmd: str, params_w) -> None:
        """G0/G1/G2/G3: the move's target, its filament, and its point(s) (an arc's chords)."""
        where, unit = self.where, self.unit
        self.motion_mode = cmd
        params = _params(params_w, where, "XYZEFIJRSK")
        if "F" in params:
            if params["F"] <= 0:
                raise GcodeError(f"{where}: feed F{params['F']:g} must be > 0")
            self.feed = params["F"] * unit / 60.0
        if "S" in params:
            if params["S"] < 0:
                raise GcodeError(f"{where}: power S{params['S']:g} must be >= 0")
            self.s_value = params["S"]
        pos, offset = self.pos, self.offset
        target = list(pos)
        for k, ax in enumerate("XYZ"):
            if ax in params:
                v = params[ax] * unit
                target[k] = v + offset[k] if self.abs_xyz else pos[k] + v
        if not all(math.isfinite(v) and abs(v) < 1e12 for v in target):
            raise GcodeError(f"{where}: position {target} is not a finite coordinate")
        if not self.z_lo <= target[2] <= self.z_hi:
            raise GcodeError(f"{where}: {self.shown_line!r} moves the tool to x = {target[0]:.2f}, "
                             f"y = {target[1]:.2f}, z = {target[2]:.2f} mm, outside the work envelope of "
                             f"{self.printer.name}: {self.bed.outside(target)}")
        bare = "bare" in params
        moved = target != pos
        de = self._extrusion(params, bare, moved) if "E" in params else 0.0
        if self.bare_retracted == 1 and moved and not bare:
            self.bare_retracted = 2
        arc = cmd in ("G2", "G3")
        if not moved and de == 0.0 and not (arc and ("I" in params or "J" in params)):
            if not any(a in params for a in "XYZ"):
                return  # a feed or power change only
        if arc:
            pts = self._arc(cmd, params, target)
            seg = np.linalg.norm(np.diff(np.vstack([pos, pts]), axis=0), axis=1)
            share = seg / seg.sum() if seg.sum() > 0 else np.full(len(pts), 1 / len(pts))
            self._append(pts[:, 0].tolist(), pts[:, 1].tolist(), pts[:, 2].tolist(), (de * share).tolist(), cmd,
                         params, bare)
        else:
            self._append([target[0]], [target[1]], [target[2]], [de], cmd, params, bare)
        self.pos = target
        self.started = True

    def _extrusion(self, params: dict, bare: bool, moved: bool) -> float:
        """The filament a move's E word pushes (mm, negative: pulled back), checked against the
        tool, the largest move and the longest retraction."""
        where = self.where
        if not self.takes_filament:
            kind = self.tool.channel_kind
            raise GcodeError(f"{where}: {self.shown_line!r} extrudes filament (an E amount), but "
                             f"{self.printer.name}'s tool is a {kind}: give it a {kind}'s G-code, an image or an SVG")
        self.e_words = self.e_words or not bare
        self.bare_words = self.bare_words or bare
        v = params["E"] * self.unit
        if self.abs_e and bare and self.bare_retracted == 2 and not moved and v > 0:
            # Slic3r 1.3 resets its E register to 0 after every retraction (GCode::retract
            # calls reset_e) but in the no-extrusion flavour writes no G92 E0 for it. The
            # standing number after a retraction and its travel is therefore the unretract
            # measured from 0: "-2, 2" is 2 mm back and 2 mm forward, not 2 back and 4
            # forward (read as a difference, the first unretract of a job pushes 2 mm of
            # extra filament). Read from 0 the amount is exactly Slic3r's: the retracted
            # length plus its retract_restart_extra. A standing number before the travel
            # still belongs to the retraction (the rest of a wipe) and is a difference.
            # Work moves keep the register constant (Slic3r sets e_per_mm to 0 without an
            # extrusion axis), so the retractions themselves read right as differences.
            de = v
        elif self.abs_e:
            de = v - self.e_reg
        else:
            de = v
        self.e_reg = v if self.abs_e else self.e_reg + v
        if bare and de < 0:
            self.bare_retracted = 1
        elif bare and de > 0 and not moved:
            self.bare_retracted = 0
        if not math.isfinite(de) or abs(de) > 1e12:
            raise GcodeError(f"{where}: extrusion {de:g} mm is not a finite amount")
        if abs(de) > MAX_MOVE_FILAMENT:
            raise GcodeError(
                f"{where}: {self.shown_line!r} moves {de:.6g} mm of filament in one move, more than "
                f"{MAX_MOVE_FILAMENT / 1000:g} m: is E absolute (M82) or relative (M83) as the slicer "
                "wrote it, and in mm?"
            )
        self.e_pushed += de
        if self.e_pushed > self.e_most:
            self.e_most = self.e_pushed
        elif self.e_most - self.e_pushed > self.retract_bound:
            raise GcodeError(
                f"{where}: {self.shown_line!r} retracts the filament {self.e_most - self.e_pushed:.2f} mm from where "
                f"it last extruded, more than {self.printer.name}'s [tool] max_retract_length = "
                f"{self.retract_bound:g} mm (a filament unload is the firmware's; raise the bound with "
                "--set tool.max_retract_length=MM)")
        return de

    def _arc(self, cmd: str, params: dict, target: list) -> np.ndarray:
        """(k, 3) mm the chords' ends of a G2/G3 arc to ``target``, within the file's chord budget."""
        where, unit, line_no = self.where, self.unit, self.line_no
        if self.plane != "G17":
            raise GcodeError(f"{where}: arcs are read in the XY plane only (G17), not {self.plane}")
        ij = None
        if "I" in params or "J" in params:
            ij = (params.get("I", 0.0) * unit, params.get("J", 0.0) * unit)
        r_word = params.get("R")
        allowed = ARC_CHORDS_BASE + ARC_CHORDS_PER_LINE * line_no
        try:
            pts = _arc_points(self.pos, target, ij, None if r_word is None else r_word * unit, cmd == "G2", where,
                              budget=allowed - self.arc_chords)
        except _ArcBudget as over:
            raise GcodeError(
                f"{where}: the arcs up to this line would be {self.arc_chords + over.chords} chords, more than "
                f"{allowed} for {line_no} lines (this arc, of radius {over.radius:.6g} mm, takes "
                f"{over.chords}): are I, J and R in mm?"
            ) from None
        self.arc_chords += len(pts)
        return pts

    def _append(self, x: list, y: list, z: list, e: list, cmd: str, params: dict, bare: bool) -> None:
        """Add k moves (their x, y, z, e lists) in the current modal state; hand a full block to the sink."""
        xs, ys, zs, es, fs, roles, layers, kinds, powers, lmodes = self.columns
        feed = self.feed if self.feed is not None else self.default_feed
        role = self.role_comment if self.role_comment is not None else -1
        layer = max(self.layer_idx, 0)
        kind = 0 if cmd == "G0" else (3 if bare else (2 if "E" in params else 1))
        mode = self.laser_mode
        power = self.s_value if mode else 0.0
        if len(x) == 1:  # a line, not an arc's chords
            xs.append(x[0])
            ys.append(y[0])
            zs.append(z[0])
            es.append(e[0])
            fs.append(feed)
            roles.append(role)
            layers.append(layer)
            kinds.append(kind)
            powers.append(power)
            lmodes.append(mode)
        else:
            k = len(x)
            xs.extend(x)
            ys.extend(y)
            zs.extend(z)
            es.extend(e)
            fs.extend([feed] * k)
            roles.extend([role] * k)
            layers.extend([layer] * k)
            kinds.extend([kind] * k)
            powers.extend([power] * k)
            lmodes.extend([mode] * k)
        if self.sink is not None and len(xs) >= self.block:
            self.sink(self.columns)
            self.handed += len(xs)
            self.columns = _new_columns()

    # ------------------------------------------------------------------ modes: G90 G91 M82 M83 G20 G21 G17-G19

    def _no_parameters(self, params_w) -> None:
        if params_w:
            _params(params_w, self.where, "")  # refuses any parameter

    def _absolute(self, _cmd: str, params_w) -> None:
        """G90: absolute positions and E."""
        self._no_parameters(params_w)
        self.abs_xyz = self.abs_e = True

    def _relative(self, _cmd: str, params_w) -> None:
        """G91: relative positions and E."""
        self._no_parameters(params_w)
        self.abs_xyz = self.abs_e = False

    def _extrusion_mode(self, cmd: str, params_w) -> None:
        """M82 absolute E, M83 relative E."""
        self._no_parameters(params_w)
        self.abs_e = cmd == "M82"

    def _units(self, cmd: str, params_w) -> None:
        """G20 inches, G21 mm."""
        self._no_parameters(params_w)
        self.unit = 25.4 if cmd == "G20" else 1.0

    def _plane(self, cmd: str, params_w) -> None:
        """G17/G18/G19: the arcs' plane (only G17's arcs are read)."""
        self._no_parameters(params_w)
        self.plane = cmd

    # ------------------------------------------------------------------ G92, events, laser, the rest

    def _set_position(self, _cmd: str, params_w) -> None:
        """G92: before the first move it sets where the tool is; after, it moves the file's
        coordinates, not the tool (the offset); E sets the register."""
        params = _params(params_w, self.where, "XYZE")
        if not params:
            params = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
        if "E" in params:
            self.e_reg = params["E"] * self.unit
        for k, ax in enumerate("XYZ"):
            if ax in params:
                if self.started:
                    self.offset[k] = self.pos[k] - params[ax] * self.unit
                else:
                    self.pos[k] = params[ax] * self.unit
        if not self.started:
            self.start = np.array(self.pos, float)

    def _temperature(self, cmd: str, params_w) -> None:
        """M104/M109 hot end, M140/M190 bed: an event at the next move (S, or R, in C)."""
        params = _params(params_w, self.where, None)
        value = params.get("S", params.get("R"))
        if value is None:
            self.skipped[f"{cmd} without S"] += 1
            return
        if not 0 <= value <= 1000:
            raise GcodeError(f"{self.where}: temperature {value:g} C outside 0..1000")
        self._event(_EVENT_M[cmd], value)

    def _fan_on(self, _cmd: str, params_w) -> None:
        """M106: the fan at S (0..255, full when not given)."""
        params = _params(params_w, self.where, None)
        self._event(EventKind.FAN, min(max(params.get("S", 255.0), 0.0), 255.0))

    def _fan_off(self, _cmd: str, params_w) -> None:
        """M107: the fan off."""
        _params(params_w, self.where, None)
        self._event(EventKind.FAN, 0.0)

    def _event(self, kind: EventKind, value: float) -> None:
        self.events.append((self.handed + len(self.columns[0]), int(kind), float(value)))

    def _laser(self, cmd: str, params_w) -> None:
        """M3 constant power, M4 dynamic power (GRBL's laser mode), M5 off; S the power."""
        if not self.takes_laser_power and cmd != "M5":  # M5 switches a laser off: nothing to refuse
            raise GcodeError(f"{self.where}: {self.shown_line!r} is a laser command, but {self.printer.name}'s tool "
                             f"is an {self.tool.channel_kind}: slice the part for it, or compile this file for a "
                             "laser printer")
        params = _params(params_w, self.where, "S")
        if "S" in params:
            if params["S"] < 0:
                raise GcodeError(f"{self.where}: power S{params['S']:g} must be >= 0")
            self.s_value = params["S"]
        self.laser_mode = _LASER_M[cmd]
        self.laser_seen = True
        self._event(EventKind.LASER_MODE, self.laser_mode)

    def _skip(self, cmd: str, _params_w) -> None:
        """A command that does not move the tool (homing, probing, dwell...): counted, then said."""
        self.skipped[cmd] += 1

    # ------------------------------------------------------------------ the end

    def say_skipped(self, echo) -> None:
        """Say the commands skipped (``echo``: callable(str) or None)."""
        if self.skipped and echo is not None:
            total = sum(self.skipped.values())
            detail = ", ".join(f"{c} x{k}" for c, k in self.skipped.most_common(8))
            echo(f"{self.shown}: skipped {total} commands that do not move the tool ({detail})")

    def state(self) -> _ReadState:
        """Hand the last moves to the sink; what the file held besides its moves (kept: the moves'
        columns when there is no sink)."""
        raw = self.columns
        n = self.handed + len(raw[0])
        if self.sink is not None and len(raw[0]):
            self.sink(raw)
        if n == 0:
            raise GcodeError(f"{self.shown}: no moves found (expected G0/G1/G2/G3 lines)")
        return _ReadState(self.start, n, self.events, self.e_words, self.bare_words, self.laser_seen,
                          self.have_layer_comments, self.layer_idx + 1 if self.have_layer_comments else 0,
                          self.layer_z_comment, _source_machine(self.settings, self.cura_settings),
                          None if self.sink is not None else raw)


#: command word -> handler; a command not here is skipped (counted and said)
_HANDLERS = {
    **{cmd: _Reader._move for cmd in _MOTION},
    "G90": _Reader._absolute, "G91": _Reader._relative, "M82": _Reader._extrusion_mode, "M83": _Reader._extrusion_mode,
    "G20": _Reader._units, "G21": _Reader._units,
    **{cmd: _Reader._plane for cmd in ("G17", "G18", "G19")},
    "G92": _Reader._set_position,
    **{cmd: _Reader._temperature for cmd in ("M104", "M109", "M140", "M190")},
    "M106": _Reader._fan_on, "M107": _Reader._fan_off,
    **{cmd: _Reader._laser for cmd in _LASER_M},
}
