"""The G-code reader's table of handlers (deltaslice/gcode/reader.py): every command it names is
handled, not skipped; the mode commands take no parameters; the event commands give their events."""

from __future__ import annotations

import pytest

from deltaslice.errors import GcodeError
from deltaslice.gcode import parse_gcode
from deltaslice.gcode.reader import _HANDLERS
from deltaslice.toolpath import EventKind


def _parse(text: str):
    notes: list[str] = []
    tp = parse_gcode(text, name="t.gcode", echo=notes.append)
    return tp, notes


def test_every_command_of_the_table_is_handled_and_the_rest_skipped():
    motion = {"G0", "G1", "G2", "G3"}
    lines = [c if c not in motion and c not in ("M104", "M109", "M140", "M190") else f"{c} S0"
             for c in sorted(_HANDLERS) if c not in motion]
    lines = [ln for ln in lines if not ln.startswith("G20")] + ["G21", "G28", "T0", "M117 hello", "G1 X1 Y1 F600"]
    _tp, notes = _parse("\n".join(lines) + "\n")
    skipped = [n for n in notes if "skipped" in n]
    assert skipped == ["t.gcode: skipped 3 commands that do not move the tool (G28 x1, T0 x1, M117 x1)"], notes


@pytest.mark.parametrize("cmd", ["G90", "G91", "G20", "G21", "G17", "M82", "M83"])
def test_a_mode_command_takes_no_parameter(cmd):
    with pytest.raises(GcodeError, match=rf"t.gcode:1: unexpected word X1"):
        _parse(f"{cmd} X1\nG1 X1\n")


def test_the_event_commands_give_their_events_at_the_next_move():
    text = "G1 X1 F600\nM106\nM106 S300\nM107\nM104 S210\nM140 R60\nM190\nG1 X2\n"
    tp, notes = _parse(text)
    events = [(int(i), EventKind(k), v) for i, k, v in tp.events.tolist()]
    assert events == [(1, EventKind.FAN, 255.0), (1, EventKind.FAN, 255.0), (1, EventKind.FAN, 0.0),
                      (1, EventKind.HOTEND_SET, 210.0), (1, EventKind.BED_SET, 60.0)]
    assert any("M190 without S x1" in n for n in notes), notes  # a wait for no temperature is skipped


def test_g20_reads_inches_and_g21_millimetres():
    tp, _ = _parse("G20\nG1 X1 Y0 F60\nG21\nG1 X30 Y0\n")
    assert tp.xyz[:, 0].tolist() == [25.4, 30.0]
