"""G-code as the source machines' authors wrote it: dialects, errors, events, files sliced for
another machine, centring; and a fuzzer that finds no exception but GcodeError."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from conftest import printer
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from deltaslice.errors import GcodeError, UnreachableError
from deltaslice.gcode import ARC_TOLERANCE, gcode_text, parse_gcode, read_gcode
from deltaslice.pipeline import write_gcode
from deltaslice.planning import check_reachable, plan
from deltaslice.slicing.extrusion import filament_per_mm
from deltaslice.toolpath import EventKind, Role, ToolpathBuilder, centred, fits_centred


def parse(text, p=None, **kw):
    notes = []
    tp = parse_gcode(text, name="t.gcode", printer=p, echo=notes.append, **kw)
    return tp, notes


# --------------------------------------------------------------------------- dialects


def test_slic3r_no_extrusion_bare_numbers_are_read():
    etitc = printer("delta_etitc")
    text = """G21
G90
G1 Z0.5 F7800.000
G1 -2.00000 F2400.00000
G1 X10 Y0 F7800.000
G1 2.00000 F2400.00000
G1 F1800
G1 X22.259 Y-21.228 2.00000
G1 X30 Y0 2.00000
G1 0.00000 F2400.00000
G1 X0 Y0 F7800
"""
    tp, notes = parse(text, etitc)
    assert any("no-extrusion" in n for n in notes)
    work = tp.working
    assert work.tolist() == [False, False, False, False, True, True, False, False]
    assert np.allclose(tp.xyz[4], [22.259, -21.228, 0.5])
    # the flow model of the printer: first layer width and the file's 0.5 mm layer
    s = etitc.slicing
    per_mm = filament_per_mm(s.first_layer_width, 0.5, etitc.tool.filament_area, s.extrusion_multiplier)
    assert np.allclose(tp.e[work], tp.lengths[work] * per_mm)
    # standing bare numbers stay retracts: Slic3r resets its register to 0 after each retraction
    # without a G92, so "-2, 2, 0" is 2 mm back, 2 forward, 2 back (not 4 forward: 2 mm too much)
    retract = tp.role == Role.RETRACT
    assert tp.e[retract].tolist() == pytest.approx([-2.0, 2.0, -2.0])


def test_slic3r_no_extrusion_wipe_and_restart_extra():
    # Slic3r --wipe --retract-restart-extra 0.5: the retraction partly while moving back over the
    # perimeter (a travel, not work), the rest standing; the unretract is 2 + 0.5 from the reset 0
    etitc = printer("delta_etitc")
    text = """G1 Z0.35 F7800.000
G1 -2.00000 F2400.00000
G1 X10 Y0 F7800.000
G1 2.50000 F2400.00000
G1 X20 Y0 2.50000
G1 X20 Y10 2.50000
G1 X20 Y4 1.63620
G1 X20 Y2 0.60000
G1 0.50000 F2400.00000
G1 X0 Y0 F7800.000
G1 2.50000 F2400.00000
G1 X0 Y10 2.50000
"""
    tp, _ = parse(text, etitc)
    assert tp.working.tolist() == [False, False, False, False, True, True, False, False, False, False, False, True]
    assert tp.e[~tp.working].tolist() == pytest.approx([0, -2, 0, 2.5, -0.8638, -1.0362, -0.1, 0, 2.5])
    wipe = ~tp.working & (tp.lengths > 0) & (tp.e < 0)
    assert wipe.sum() == 2 and (tp.tool[wipe] == 0).all() and (tp.role[wipe] == Role.TRAVEL).all()


def test_file_without_e_words_g1_works_g0_travels():
    etitc = printer("delta_etitc")
    tp, notes = parse("G0 X0 Y0 Z0.4 F3000\nG1 X20 Y0 F600\nG1 X20 Y20\nG0 X0 Y0\nG1 Z1\n", etitc)
    assert tp.working.tolist() == [False, True, True, False, False]  # a z-only G1 does not extrude
    assert (tp.e[tp.working] > 0).all() and (tp.e[~tp.working] == 0).all()
    assert any("no E words" in n and "G0 moves are travels" in n for n in notes)
    # without a printer the moves still work, with no filament amounts
    tp2, _ = parse("G1 X20 Y0 F600\n")
    assert tp2.working.all() and tp2.e.sum() == 0


def test_no_e_words_on_a_laser_switch_the_laser_on():
    laser = printer("delta_espe_laser")
    tp, notes = parse("G0 X-5 Y-5\nG1 X5 Y-5 F600\nG0 X0 Y0\n", laser)
    assert tp.tool.tolist() == [0.0, laser.tool.max_power, 0.0]
    assert tp.role[1] == Role.LASER and any("laser on" in n for n in notes)


def test_grbl_laser_power_modes_and_s_scale():
    laser = printer("delta_espe_laser")
    text = """G21 G90
M3 S250
G0 X-10 Y-10
G1 X10 Y-10 F600
X10 Y10 S1000
M4 S500
G1 X-10 Y10
M5
G1 X-10 Y-10
"""
    tp, _ = parse(text, laser)
    assert tp.tool.tolist() == [0.0, 0.25, 1.0, 0.5, 0.0]  # G0 never burns; M5 switches off
    assert tp.working.tolist() == [False, True, True, True, False]
    assert [(i, k, v) for i, k, v in tp.events.tolist()] == [
        (0, EventKind.LASER_MODE, 3.0), (3, EventKind.LASER_MODE, 4.0), (4, EventKind.LASER_MODE, 0.0)]
    # the printer's S scale: S255 is full power on a machine whose $30 is 255
    small = dataclasses.replace(laser, tool=dataclasses.replace(laser.tool, s_max=255.0))
    tp2, _ = parse("M3 S255\nG1 X5 Y0 F600\n", small)
    assert tp2.tool.tolist() == [1.0]
    # the tool channel is a fraction of full power whatever the laser's watts (max_power is
    # reported only): a 5 W laser at S500 is at 0.5, and without M3/M4 at 1.0; both write back
    strong = dataclasses.replace(laser, tool=dataclasses.replace(laser.tool, max_power=5.0))
    tp4, _ = parse("M3 S500\nG1 X5 Y0 F600\n", strong)
    assert tp4.tool.tolist() == [0.5]
    assert parse("G1 X5 Y0 F600\n", strong)[0].tool.tolist() == [1.0]
    assert parse(gcode_text(tp4, strong), strong)[0].tool.tolist() == [0.5]
    # on an extruder the laser words are refused (tests/test_safety_contract.py); read without a
    # printer they are only events
    tp3, _ = parse("M3 S255\nG1 X5 Y0 E1 F600\n")
    assert tp3.tool.tolist() == [1.0] and tp3.events["kind"].tolist() == [EventKind.LASER_MODE]


@pytest.mark.parametrize("code, sign", [("G2", -1), ("G3", 1)])
def test_full_circle(code, sign):
    tp, _ = parse(f"G1 X10 Y0 F600 E0\n{code} X10 Y0 I-10 J0 E3.0\n")
    arc = slice(1, None)
    pts = tp.xyz[arc]
    assert len(pts) > 20 and np.allclose(pts[-1], [10, 0, 0])
    assert np.allclose(np.hypot(pts[:, 0], pts[:, 1]), 10)
    assert tp.lengths[arc].sum() == pytest.approx(2 * np.pi * 10, rel=1e-3)
    assert tp.e[arc].sum() == pytest.approx(3.0) and tp.working[arc].all()
    # direction: the first chord turns clockwise for G2
    assert np.sign(pts[0, 1]) == sign


def test_ij_arc_end_off_the_circle_is_refused_with_its_line():
    with pytest.raises(GcodeError, match=r"t.gcode:2: arc end .* off the circle"):
        parse("G1 X10 Y0\nG2 X0 Y-20 I-10 J0\n")
    # slicer rounding (3 decimals) is accepted and the arc ends exactly at the given point
    tp, _ = parse("G1 X10 Y0\nG2 X0.0004 Y-10.0005 I-10 J0\n")
    assert np.allclose(tp.xyz[-1], [0.0004, -10.0005, 0])


@pytest.mark.parametrize("line", ["G2 X20 Y0 R1e300", "G3 X20 Y0 R-1e300", "G2 X20 Y0 I5 J1e15",
                                  "G2 X10 Y0 I1e-300 J0", "G3 X10.000001 Y0 R1e12"])
def test_huge_or_tiny_radius_never_divides_by_zero(line):
    try:
        tp, _ = parse(f"G1 X10 Y0 F600\n{line}\n")
    except GcodeError as exc:
        assert "t.gcode:2" in str(exc)
    else:
        assert np.all(np.isfinite(tp.xyz))


def test_nearly_straight_r_arc_is_its_chord():
    tp, _ = parse("G1 X0 Y0\nG2 X10 Y0 R1e9\n")
    assert len(tp) == 2 and np.allclose(tp.xyz[-1], [10, 0, 0])
    # a real arc still becomes chords within the tolerance
    tp, _ = parse("G1 X0 Y0\nG2 X10 Y0 R5\n")
    assert len(tp) > 10 and np.allclose(np.hypot(tp.xyz[1:, 0] - 5, tp.xyz[1:, 1]), 5, atol=ARC_TOLERANCE)


def test_g92_mid_file_is_a_coordinate_offset():
    text = "G90\nG1 X10 Y10 Z1 F600\nG92 X0 Y0\nG1 X5 Y0\nG91\nG1 X1\nG90\nG92 Z0\nG1 Z1\nG1 X0 Y0\n"
    tp, _ = parse(text)
    assert np.allclose(tp.xyz, [[10, 10, 1], [15, 10, 1], [16, 10, 1], [16, 10, 2], [10, 10, 2]])
    # before the first move G92 says where the tool is: the start
    tp, _ = parse("G92 X5 Y6 Z7\nG1 X10\n")
    assert np.allclose(tp.start, [5, 6, 7]) and np.allclose(tp.xyz[0], [10, 6, 7])
    # G92 E resets the extruder register only
    tp, _ = parse("G1 X1 E5\nG92 E0\nG1 X2 E1\n")
    assert tp.e.tolist() == [5.0, 1.0]


def test_exponents_are_read_as_written():
    tp, _ = parse("G1 X20 Y1e-05 E1\nG1 X2.5e1 Y-1.5e+00 E2\n")
    assert tp.xyz[0].tolist() == [20.0, 1e-05, 0.0] and tp.xyz[1].tolist() == [25.0, -1.5, 0.0]
    assert tp.e.tolist() == [1.0, 1.0]
    with pytest.raises(GcodeError, match=r"t.gcode:2: E1e999 is not finite"):
        parse("G1 X1 E1\nG92 E1e999\nG1 X2 E2\n")
    with pytest.raises(GcodeError, match=r"t.gcode:1: .*not finite"):
        parse("G1 X1e400\n")


def test_last_move_back_to_the_start_plans(tmp_path):
    """Regression: a travel that leaves and returns to where it began was dropped whole, so a
    job of one such travel had no pieces and sampling raised IndexError (planning/trajectory.py)."""
    etitc = printer("delta_etitc")
    tp, _ = parse("G0 X10 Y0 F1200\nG0 X0 Y0\n", etitc)
    traj = plan(tp, etitc, workers=1)
    s = traj.samples()
    assert traj.duration > 0 and len(s) > 10
    p = etitc.kinematics().forward(s.q)
    assert p[:, 0].max() == pytest.approx(10.0, abs=0.05)  # the travel really goes out and back
    # a working loop that ends where it started, followed by that travel
    tp, _ = parse("G1 X0 Y0 Z0.5 F1200\nG1 X10 Y0 E0.5\nG1 X10 Y10 E0.5\nG1 X0 Y0 E0.5\nG0 X5 Y5\nG0 X0 Y0\n", etitc)
    assert plan(tp, etitc, workers=1).samples().t[-1] > 0


@pytest.mark.parametrize(
    "text, match",
    [
        ("G1 X10 X20\n", r"t.gcode:1: X given twice"),
        ("G1 X10\nG1 G90 X10\n", r"t.gcode:2: conflicting commands G1 G90"),
        ("G1 X1 E1 2.0\n", r"t.gcode:1: E given twice"),
        ("G0 X1\nG1 X2 M3\n", r"t.gcode:2: conflicting commands"),
        ("G1 X1\nG1 Q5\n", r"t.gcode:2: unexpected word Q5"),
        ("G1 X\n", r"t.gcode:1: X has no value"),
        ("G1 X1\nG1 X2 Y3 $\n", r"t.gcode:2: malformed line"),
        ("X10 Y10\n", r"t.gcode:1: .*no motion mode"),
        ("G18\nG2 X10 Y0 I5 J0\n", r"t.gcode:2: .*XY plane"),
        ("G1 X1\nM104 S5000\n", r"t.gcode:2: temperature 5000"),
    ],
)
def test_duplicate_and_conflicting_words_are_errors_naming_the_line(text, match):
    with pytest.raises(GcodeError, match=match):
        parse(text)


def test_modal_state_lines_are_accepted():
    tp, _ = parse("G90 G21 G17\nG1 X1 F600\nX2 Y1\nM117 free text: 1.2.3 $ X\nN10 G1 X3*77\n")
    assert tp.xyz[:, 0].tolist() == [1.0, 2.0, 3.0] and tp.xyz[1, 1] == 1.0


# --------------------------------------------------------------------------- events


def test_heater_fan_events_and_their_round_trip(tmp_path):
    text = """M140 S60
M104 S215
M190 S60
M109 R200
G1 X1 Y0 Z0.2 E0.1 F600
M106
M106 S127.5
G1 X2 E0.2
M107
M104 S0
"""
    tp, _ = parse(text)
    assert tp.events.tolist() == [
        (0, EventKind.BED_SET, 60.0), (0, EventKind.HOTEND_SET, 215.0), (0, EventKind.BED_WAIT, 60.0),
        (0, EventKind.HOTEND_WAIT, 200.0), (1, EventKind.FAN, 255.0), (1, EventKind.FAN, 127.5),
        (2, EventKind.FAN, 0.0), (2, EventKind.HOTEND_SET, 0.0)]
    write_gcode(tp, tmp_path / "o.gcode")
    back = read_gcode(tmp_path / "o.gcode")
    assert back.equals(tp)
    text = (tmp_path / "o.gcode").read_text()
    assert "M109 S200" in text and "M106 S127.5" in text and "M107" in text


def test_builder_events_and_laser_round_trip(tmp_path):
    laser = printer("delta_espe_laser")
    b = ToolpathBuilder()
    b.new_layer(0.0)
    b.event(EventKind.LASER_MODE, 3)
    b.add([[5, 0, 0], [5, 5, 0]], 20.0, 0.0, [0.0, 0.4], [Role.TRAVEL, Role.LASER])
    b.event(EventKind.LASER_MODE, 0)
    tp = b.build()
    assert tp.events.tolist() == [(0, 6, 3.0), (2, 6, 0.0)]
    write_gcode(tp, tmp_path / "l.gcode", laser)
    back = read_gcode(tmp_path / "l.gcode", printer=laser)
    assert back.equals(tp) and back.tool.tolist() == [0.0, 0.4]


def test_laser_doc_states_the_s_word_the_writer_writes():
    # an engraving (no M3/M4 events of its own): the writer puts M4 S0 ... M5 around the run and
    # S = power x [tool] s_max on its moves (GRBL's $30), not x power_counts (the PWM steps)
    from conftest import ROOT

    laser = printer("delta_espe_laser")
    assert laser.tool.s_max != laser.tool.power_counts
    b = ToolpathBuilder()
    b.new_layer(0.0)
    b.add([[5, 0, 0], [5, 5, 0], [0, 5, 0]], 20.0, 0.0, [0.0, 0.5, 0.25],
          [Role.TRAVEL, Role.LASER_DYNAMIC, Role.LASER_DYNAMIC])
    text = gcode_text(b.build(), laser)
    s_words = [w for ln in text.splitlines() if ln.startswith("G1") for w in ln.split() if w.startswith("S")]
    assert s_words == [f"S{round(0.5 * laser.tool.s_max)}", f"S{round(0.25 * laser.tool.s_max)}"]
    doc = (ROOT / "docs" / "laser.md").read_text()
    assert "S<power x [tool] s_max>" in doc and "power_counts>" not in doc


# --------------------------------------------------------------------------- another machine's file

PRUSA_TAIL = """
; filament_diameter = 1.75
; nozzle_diameter = 0.4
; bed_shape = 0x0,250x0,250x210,0x210
"""


def test_settings_block_warns_and_rescales_filament():
    etitc = printer("delta_etitc")
    body = "M83\nG1 X100 Y100 Z0.2 F600\nG1 X110 Y100 E1.0\nG1 E-0.8\nG1 X120 Y100\nG1 E1.0\nG1 X130 Y100 E1.0\n"
    tp, notes = parse(body + PRUSA_TAIL, etitc)
    ratio = (1.75 / 3.0) ** 2
    # extrusion rescaled (a volume); the retraction and the unretraction that undoes it keep their
    # length, only the 0.2 mm the unretraction adds beyond it (a restart extra) is plastic, rescaled
    assert tp.e.tolist() == pytest.approx([0.0, ratio, -0.8, 0.0, 0.8 + 0.2 * ratio, ratio])
    assert any("1.75 mm filament" in n and "rescaled" in n and f"{ratio:.4f}" in n
               and "retractions" in n and "kept at their length" in n for n in notes)
    assert any("0.4 mm nozzle" in n for n in notes)
    assert any("250 x 210 mm bed" in n and "--center" in n for n in notes)
    # the same file for a 1.75 mm printer: no rescaling, no filament note
    kossel = printer("linear_kossel")
    tp2, notes2 = parse(body + PRUSA_TAIL, kossel)
    assert tp2.e.tolist() == pytest.approx([0.0, 1.0, -0.8, 0.0, 1.0, 1.0]) and not any("filament" in n for n in notes2)


def test_cura_settings_block():
    etitc = printer("delta_etitc")
    text = ("G1 X0 Y0 Z0.2 F600\nG1 X10 Y0 E1\n"
            ';SETTING_3 {"global_quality": "[general]\\\\nversion = 4\\\\n[values]\\\\nmaterial_diameter = 1.7\n'
            ';SETTING_3 5\\\\nmachine_width = 220\\\\nmachine_depth = 220\\\\n"}\n')
    tp, notes = parse(text, etitc)
    assert tp.e[1] == pytest.approx((1.75 / 3.0) ** 2)
    assert any("220 x 220 mm bed" in n for n in notes)


def test_bed_of_another_size_centred_at_zero_gets_a_note():
    etitc = printer("delta_etitc")  # a round bed, radius 80 mm
    body = "G1 X0 Y0 Z0.2 F600\nG1 X10 Y0 E1\n"
    square = "; bed_shape = -100x-100,100x-100,100x100,-100x100\n"
    _tp, notes = parse(body + square, etitc)
    bed = [n for n in notes if "mm bed" in n]
    assert len(bed) == 1 and "200 x 200 mm bed centred at (0, 0)" in bed[0] and "radius 80 mm" in bed[0]
    assert "another size" in bed[0] and "--center" not in bed[0]  # centring would not change anything
    # PrusaSlicer's polygon of a round bed the printer's size: no note
    ring = ",".join(f"{80 * math.cos(a):.4f}x{80 * math.sin(a):.4f}" for a in np.linspace(0, 2 * np.pi, 64, endpoint=False))
    _tp, notes = parse(body + f"; bed_shape = {ring}\n", etitc)
    assert not any("mm bed" in n for n in notes)
    # Cura: machine width and depth, centred at zero
    cura = (';SETTING_3 {"global_quality": "[general]\\\\nversion = 4\\\\n[values]\\\\nmachine_width = 300\\\\n'
            'machine_depth = 200\\\\nmachine_center_is_zero = True\\\\n"}\n')
    _tp, notes = parse(body + cura, etitc)
    assert any("300 x 200 mm bed centred at (0, 0)" in n and "another size" in n for n in notes)
    # a rectangular printer bed of the same size: no note
    atlas = printer("fivebar_atlas")
    hx, hy = atlas.bed.size_x / 2, atlas.bed.size_y / 2
    assert atlas.bed.shape == "rectangle"
    _tp, notes = parse(body + f"; bed_shape = {-hx}x{-hy},{hx}x{-hy},{hx}x{hy},{-hx}x{hy}\n", atlas)
    assert not any("mm bed" in n for n in notes)
    _tp, notes = parse(body + f"; bed_shape = {-hx - 20}x{-hy},{hx + 20}x{-hy},{hx + 20}x{hy},{-hx - 20}x{hy}\n", atlas)
    assert any(f"{2 * hx + 40:g} x {2 * hy:g} mm bed" in n and "another size" in n for n in notes)


def test_center_moves_the_footprint_and_the_unreachable_message_says_so():
    etitc = printer("delta_etitc")
    text = "G1 X0 Y0 Z5 F600\nG1 X100 Y100 Z0.3\nG1 X110 Y100 E1\nG1 X110 Y110 E2\nG1 X0 Y200 Z10\n"
    tp, _ = parse(text, etitc)
    with pytest.raises(UnreachableError, match=r"would fit centred on the bed: use --center"):
        check_reachable(tp, etitc)
    assert fits_centred(tp, etitc)
    c, notes = parse(text, etitc, center=True)
    w = c.working
    pts = np.concatenate([c.starts[w], c.xyz[w]])[:, :2]
    assert np.allclose(pts.min(axis=0) + pts.max(axis=0), 0)
    assert any("moved the part by (-105.00, -105.00)" in n for n in notes)
    # positioning before and after the print stays above the part's first and last points
    assert np.allclose(c.xyz[0, :2], [-5, -5]) and np.allclose(c.xyz[-1, :2], [5, 5])
    assert c.xyz[-1, 2] == 10
    check_reachable(c, etitc)
    # a part larger than the bed: the message says centring would not help
    big, _ = parse("G1 X0 Y0 Z0.3 F600\nG1 X300 Y0 E1\n", etitc)
    assert not fits_centred(big, etitc)
    with pytest.raises(UnreachableError, match="would not fit centred"):
        check_reachable(big, etitc)


def test_centred_keeps_moves_and_events():
    b = ToolpathBuilder()
    b.new_layer(0.2)
    b.event(EventKind.HOTEND_WAIT, 210)
    b.add([[10, 10, 0.2], [12, 10, 0.2], [12, 14, 0.2]], 20.0, [0.0, 0.1, 0.1], [0, 1, 1], [0, 1, 1])
    tp = b.build()
    c, shift = centred(tp)
    assert np.allclose(shift, [-11, -12]) and np.array_equal(c.events, tp.events)
    assert np.allclose(c.lengths[1:], tp.lengths[1:]) and np.array_equal(c.e, tp.e)


# --------------------------------------------------------------------------- fuzzing

_TOKENS = st.sampled_from(
    ["G0", "G1", "G2", "G3", "G90", "G91", "G92", "G20", "G21", "G17", "G18", "M82", "M83", "M104", "M109", "M106",
     "M107", "M3", "M4", "M5", "T0", "N5", "*12", ";", "(c)", "X", "Y", "Z", "E", "F", "I", "J", "R", "S", "P", "Q",
     "e", "-", "+", ".", "1e999", "nan", "inf", "0", "1", "-2.5", "1e-05", "1e300", "2.00000", "-2", " ", "\t", "%"])


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.lists(_TOKENS, max_size=8).map("".join), min_size=1, max_size=12))
def test_fuzz_gcode_like_lines_only_raise_gcode_error(lines):
    for p in (None, printer("delta_etitc"), printer("delta_espe_laser")):
        try:
            tp = parse_gcode("\n".join(lines), name="f.gcode", printer=p)
        except GcodeError:
            continue
        assert np.all(np.isfinite(tp.xyz)) and np.all(np.isfinite(tp.e)) and np.all(tp.feed > 0)


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=300))
def test_fuzz_arbitrary_text_only_raises_gcode_error(text):
    try:
        parse_gcode(text, name="f.gcode", printer=printer("delta_etitc"), center=True)
    except GcodeError:
        pass


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from(["G1", "G2", "G3"]),
                          *[st.floats(-1e6, 1e6, allow_nan=False) | st.sampled_from([0.0, 1e-300, 1e300])] * 4),
                min_size=1, max_size=6))
def test_fuzz_arcs_only_raise_gcode_error(moves):
    text = "\n".join(f"{c} X{x!r} Y{y!r} I{i!r} J{j!r} E1" for c, x, y, i, j in moves)
    try:
        tp = parse_gcode(text, name="f.gcode")
    except GcodeError:
        return
    assert np.all(np.isfinite(tp.xyz)) and math.isfinite(tp.e.sum())


def test_cli_center_option(tmp_path):
    from click.testing import CliRunner

    from deltaslice.cli import main

    job = tmp_path / "corner.gcode"
    job.write_text("M83\nG1 X100 Y100 Z0.3 F1200\nG1 X110 Y100 E0.3\nG1 X110 Y108 E0.3\n")
    out = tmp_path / "c.csv"
    args = [str(job), "--printer", "printers/delta_etitc.toml", "-o", str(out), "--quiet", "--workers", "1"]
    res = CliRunner().invoke(main, args)
    assert res.exit_code == 1 and "use --center" in res.output and "Traceback" not in res.output
    res = CliRunner().invoke(main, args + ["--center"])
    assert res.exit_code == 0, res.output
    assert "moved the part by (-105.00, -104.00)" in res.output and out.exists()
