"""What a job may ask of the machine and of your files (issue 48): the work envelope, the tool's
kind, retractions, outputs that never replace an input, and verify confirming the printer."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import printer

from deltaslice.cli import main
from deltaslice.emit import STREAM_MAGIC
from deltaslice.errors import GcodeError, UnreachableError
from deltaslice.gcode import parse_gcode
from deltaslice.planning import check_reachable
from deltaslice.toolpath import Role, ToolpathBuilder

PRINT = "G21\nG90\nM83\nG1 Z0.3 F600\nG1 X5 Y0 E0.2 F1200\n"


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _one_line_error(result, code=1):
    """The CLI's refusal: the exit code and one ``error:`` line, no Python exception name."""
    assert result.exit_code == code, result.output
    lines = [ln for ln in result.output.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    assert "Error" not in lines[0] and "Traceback" not in result.output
    return lines[0]


# --------------------------------------------------------------------------- the work envelope


@pytest.mark.parametrize("dive", ["G91\nG1 Z-5 F600\n", "G1 Z-5\n"])
def test_a_move_into_the_bed_is_refused_naming_its_line(tmp_path, dive):
    part = tmp_path / "dive.gcode"
    part.write_text(PRINT + dive)
    out = tmp_path / "dive.csv"
    line = _one_line_error(_run(part, "--printer", "delta_etitc", "-o", out, "--quiet"))
    n = len((PRINT + dive).splitlines())
    assert f"dive.gcode:{n}:" in line and "below the bed" in line and "z = -" in line
    assert not out.exists()


def test_the_envelope_is_checked_on_every_toolpath_by_layer():
    """A toolpath from any front end (here built from arrays) is held to the bed's volume where
    it is planned: below the bed, above max_height and off the bed, each named with its layer."""
    p = printer("delta_etitc")
    for point, words in (([0, 0, -0.5], "below the bed"), ([0, 0, p.bed.max_height + 1], "max_height"),
                         ([p.bed.radius + 2, 0, 1], "off the bed")):
        b = ToolpathBuilder()
        b.new_layer(0.3)
        b.add([[0, 0, 0.3], point], 20.0, 0.0, [1.0, 0.0], [Role.PERIMETER, Role.TRAVEL])
        with pytest.raises(UnreachableError, match=rf"layer 0: .*outside the work envelope .*{words}"):
            check_reachable(b.build(), p)


def test_points_inside_the_envelope_pass():
    p = printer("delta_etitc")
    tp = parse_gcode(PRINT + "G1 X0 Y5 E0.2\n", printer=p)
    check_reachable(tp, p)
    assert p.bed.contains(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, p.bed.max_height]])).all()


# --------------------------------------------------------------------------- the tool's kind


def test_extrusion_words_on_a_laser_printer_are_refused_naming_the_first(tmp_path):
    """Extruder G-code (E words, no M3) on the laser printer fired the laser on 98 % of its samples."""
    part = tmp_path / "ext.gcode"
    part.write_text(PRINT + "G1 X5 Y5 E0.2\nG1 X0 Y5 E0.2\n")
    out = tmp_path / "ext.csv"
    line = _one_line_error(_run(part, "--printer", "delta_espe_laser", "-o", out, "--quiet"))
    assert "ext.gcode:5:" in line and "E0.2" in line and "laser" in line
    assert not out.exists()
    with pytest.raises(GcodeError, match=r"t.gcode:2: 'G1 X1 2.0' extrudes filament"):  # Slic3r's bare E numbers too
        parse_gcode("G1 Z1 F600\nG1 X1 2.0\n", name="t.gcode", printer=printer("delta_espe_laser"))


def test_laser_commands_on_an_extruder_printer_are_refused_naming_the_first(tmp_path):
    part = tmp_path / "m3.gcode"
    part.write_text(PRINT + "M3 S99999\nG1 X5 Y5 E0.2\nM4 S10\n")
    out = tmp_path / "m3.csv"
    line = _one_line_error(_run(part, "--printer", "delta_etitc", "-o", out, "--quiet"))
    assert "m3.gcode:6: 'M3 S99999' is a laser command" in line and "extruder" in line
    assert not out.exists()
    # M5 (laser off) asks nothing of an extruder; a laser's G-code stays a laser's
    tp = parse_gcode(PRINT + "M5\n", printer=printer("delta_etitc"))
    assert tp.e.sum() > 0
    laser = parse_gcode("G21\nG90\nG1 Z0 F600\nM3 S500\nG1 X5 Y0\nM5\n", printer=printer("delta_espe_laser"))
    assert laser.tool.max() == pytest.approx(0.5 * 1000 / printer("delta_espe_laser").tool.s_max)


# --------------------------------------------------------------------------- outputs and inputs


def _printer_copy(tmp_path):
    from deltaslice.printers import shipped_path

    p = tmp_path / "P.toml"
    p.write_bytes(shipped_path("delta_etitc").read_bytes())
    return p


@pytest.mark.parametrize("command", ["slice", "firmware-config", "compile"])
def test_no_command_writes_over_the_printer_file(tmp_path, command):
    p = _printer_copy(tmp_path)
    before = p.read_bytes()
    part = tmp_path / "part.gcode"
    part.write_text(PRINT)
    args = {"slice": ["slice", part], "firmware-config": ["firmware-config"], "compile": [part, "--format", "csv"]}[command]
    line = _one_line_error(_run(*args, "--printer", p, "-o", p))
    assert "refusing to overwrite it" in line and "P.toml" in line
    assert p.read_bytes() == before


def _cli(*args, cwd):
    """The command in a process of its own (``-o -`` writes to its descriptor 1), run from ``cwd``
    with this checkout's package."""
    import os
    import subprocess
    import sys

    from conftest import ROOT

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "deltaslice", *map(str, args)], capture_output=True, cwd=cwd,
                          env=env, timeout=300)


def test_dash_writes_to_standard_output(tmp_path):
    """``-o -`` is standard output for every command that writes a file (it wrote a file named -);
    the command's own lines go to stderr, out of the data's way."""
    part = tmp_path / "part.gcode"
    part.write_text(PRINT + "G1 X5 Y5 E0.2\n")
    out = _cli("slice", part, "--printer", "delta_etitc", "-o", "-", "--quiet", cwd=tmp_path)
    assert out.returncode == 0 and out.stdout.startswith(b"; generated by deltaslice"), out.stderr
    out = _cli(part, "--printer", "delta_etitc", "-o", "-", "--format", "csv", "--quiet", cwd=tmp_path)
    assert out.returncode == 0 and out.stdout.startswith(b"# deltaslice setpoints v1"), out.stderr
    assert b"print time" in out.stderr
    out = _cli(part, "--printer", "delta_etitc", "-o", "-", "--quiet", cwd=tmp_path)  # the default format, a stream
    assert out.returncode == 0 and out.stdout.startswith(STREAM_MAGIC), out.stderr
    out = _cli("firmware-config", "--printer", "delta_etitc", "-o", "-", cwd=tmp_path)
    assert out.returncode == 0 and b"#define DSL_CONFIG_H" in out.stdout
    out = _cli("preview", part, "--printer", "delta_etitc", "-o", "-", cwd=tmp_path)
    assert out.returncode == 0 and out.stdout.startswith(b"\x89PNG"), out.stderr
    assert not (tmp_path / "-").exists()


# --------------------------------------------------------------------------- verify confirms the printer


def test_verify_refuses_a_file_that_cannot_name_its_printer_unless_assumed(tmp_path):
    """A CSV whose '#' header lines were removed was reported OK against any printer: a rotary
    delta's radians checked as a linear delta's millimetres."""
    part = tmp_path / "part.gcode"
    part.write_text(PRINT + "G1 X5 Y5 E0.2\n")
    out = tmp_path / "part.csv"
    assert _run(part, "--printer", "delta_etitc", "-o", out, "--quiet").exit_code == 0
    bare = tmp_path / "bare.csv"
    bare.write_text("".join(ln for ln in out.read_text().splitlines(keepends=True) if not ln.startswith("#")))
    for name in ("linear_kossel", "delta_etitc"):
        line = _one_line_error(_run("verify", bare, "--printer", name))
        assert "does not say which printer" in line and name in line and "--assume-printer" in line
    assumed = _run("verify", bare, "--printer", "delta_etitc", "--assume-printer")
    assert assumed.exit_code == 0, assumed.output
    assert "printer delta_etitc (assumed" in assumed.output and "note: the printer was assumed" in assumed.output
    as_json = _run("verify", bare, "--printer", "delta_etitc", "--assume-printer", "--json")
    assert json.loads(as_json.output)["printer_assumed"] is True
    # a file that names its printer is confirmed from the file, flag or not
    confirmed = _run("verify", out, "--printer", "delta_etitc", "--assume-printer")
    assert confirmed.exit_code == 0 and "assumed" not in confirmed.output
    assert _run("verify", out, "--printer", "linear_kossel", "--assume-printer").exit_code != 0


# --------------------------------------------------------------------------- retractions


RETRACT = "G21\nG90\nM82\nG92 E0\nG1 Z0.3 F600\nG1 X5 Y0 E4 F1200\n"


def test_a_retraction_longer_than_the_bound_is_refused_naming_its_line(tmp_path):
    """``E-50`` after ``E4`` under M82 (54 mm pulled back; retract_length is 1 mm) was accepted."""
    part = tmp_path / "r.gcode"
    part.write_text(RETRACT + "G1 E-50 F1800\nG1 X0 Y5 F3000\n")
    out = tmp_path / "r.csv"
    line = _one_line_error(_run(part, "--printer", "delta_etitc", "-o", out, "--quiet"))
    assert "r.gcode:7: 'G1 E-50 F1800' retracts the filament 54.00 mm" in line
    assert "max_retract_length = 10 mm" in line and not out.exists()
    # retractions in a row add up; pushed back, the filament may be pulled again
    p = printer("delta_etitc")
    with pytest.raises(GcodeError, match=r":8: .* 12.00 mm"):
        parse_gcode(RETRACT + "G1 E-2 F1800\nG1 E-8\n", printer=p)
    cycles = "".join(f"G1 E-5 F1800\nG1 X{k} Y1 F3000\nG1 E4 F1800\n" for k in range(5))  # 9 mm each
    assert parse_gcode(RETRACT + cycles, printer=p).e.min() == pytest.approx(-9.0)
    # the bound is the printer's: raised, the same file reads
    raised = parse_gcode(RETRACT + "G1 E-50 F1800\n", printer=_with(p, max_retract_length=60.0))
    assert raised.e.min() == pytest.approx(-54.0)


def test_a_toolpath_from_arrays_is_held_to_the_same_bound():
    """Another slicer's arrays (docs/library.md) meet the bound where they are planned."""
    from deltaslice.errors import DeltasliceError
    from deltaslice.planning import plan

    b = ToolpathBuilder()
    b.new_layer(0.3)
    b.add([[0, 0, 0.3], [5, 0, 0.3], [5, 0, 0.3], [5, 5, 0.3]], 20.0, [0.0, 4.0, -54.0, 0.0], [0.0, 1.0, 0.0, 0.0],
          [Role.TRAVEL, Role.PERIMETER, Role.RETRACT, Role.TRAVEL])
    with pytest.raises(DeltasliceError, match=r"layer 0: the toolpath retracts the filament 54.00 mm .*max_retract_length"):
        plan(b.build(), printer("delta_etitc"), workers=1)


def _with(p, **tool):
    import dataclasses

    return dataclasses.replace(p, tool=dataclasses.replace(p.tool, **tool))


def test_max_retract_length_is_validated_like_the_other_keys(tmp_path):
    from deltaslice.errors import PrinterFileError
    from deltaslice.machine import load_printer

    assert printer("delta_etitc").tool.max_retract_length == 10.0
    for value, expected in ((0.0, "> 0"), (0.5, ">= [tool] retract_length (1 mm)"), ("long", "number")):
        with pytest.raises(PrinterFileError, match=rf"max_retract_length = .*expected .*{re.escape(expected)}"):
            load_printer("delta_etitc", overrides={"tool.max_retract_length": value})
    path = _printer_copy(tmp_path)
    path.write_text(path.read_text().replace("retract_length = 1.0", "retract_length = 1.0\nmax_retract_length = 0.5"))
    with pytest.raises(PrinterFileError, match=r"P.toml: \[tool\] max_retract_length = 0.5: expected a length >="):
        load_printer(path)
