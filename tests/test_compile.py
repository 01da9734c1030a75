"""End to end: part -> slice -> plan -> CSV and stream -> verify, for every printer in printers/."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from deltaslice.cli import main
from deltaslice.pipeline import read_output, verify_output

ROOT = Path(__file__).resolve().parents[1]
CUBE = ROOT / "examples" / "parts" / "calibration_cube.stl"
FDM = ["delta_etitc", "delta_ucb", "delta_uady", "fivebar_atlas", "linear_kossel"]


@pytest.mark.parametrize("name", FDM)
def test_compile_mesh_then_verify_csv_and_stream(name, tmp_path):
    printer = str(ROOT / "printers" / f"{name}.toml")
    runner = CliRunner()
    gcode = tmp_path / "cube.gcode"
    r = runner.invoke(main, ["slice", str(CUBE), "--printer", printer, "-o", str(gcode), "--scale", "0.3", "--quiet"])
    assert r.exit_code == 0, r.output
    outputs = {}
    for ext in ("csv", "dsl"):
        out = tmp_path / f"cube.{ext}"
        r = runner.invoke(main, [str(gcode), "--printer", printer, "-o", str(out), "--quiet", "--workers", "1"])
        assert r.exit_code == 0, r.output
        assert "print time" in r.output and "peak use of limits" in r.output
        # The path-deviation check needs the tool state, which only the CSV carries exactly
        # (a stream's is rebuilt from rising filament counts): streams are checked for limits.
        report = verify_output(str(out), printer, toolpath=str(gcode) if ext == "csv" else None)
        assert report.ok, report.text()
        outputs[ext] = read_output(str(out))[1]
    csv, stream = outputs["csv"], outputs["dsl"]
    assert len(csv) == len(stream)
    assert np.allclose(csv.q, stream.q, atol=0.01)  # within quantisation (the coarsest here: ~0.005 rad)


def test_compile_gcode_for_the_laser(tmp_path):
    gcode = tmp_path / "logo.gcode"
    gcode.write_text(
        "G90\nG0 X-10 Y-10 Z0 F4800\nG1 X10 Y-10 F900 S0.8\nG1 X10 Y10\nG1 X-10 Y10\nG1 X-10 Y-10\nG0 X0 Y0\nG1 X5 Y5 F600\n"
    )
    out = tmp_path / "logo.csv"
    printer = str(ROOT / "printers" / "delta_espe_laser.toml")
    r = CliRunner().invoke(main, [str(gcode), "--printer", printer, "-o", str(out), "--quiet", "--workers", "1"])
    assert r.exit_code == 0, r.output
    report = verify_output(str(out), printer)
    assert report.ok, report.text()


def test_part_that_does_not_fit_is_refused_without_output(tmp_path):
    out = tmp_path / "big.csv"
    r = CliRunner().invoke(
        main, [str(CUBE), "--printer", str(ROOT / "printers" / "delta_ucb.toml"), "-o", str(out), "--scale", "5", "--quiet"]
    )
    assert r.exit_code == 1
    assert r.output.startswith("error:") and "Traceback" not in r.output
    assert not out.exists()


def test_unknown_output_extension_fails_before_slicing(tmp_path):
    out = tmp_path / "cube.txt"
    r = CliRunner().invoke(main, [str(CUBE), "--printer", str(ROOT / "printers" / "delta_etitc.toml"), "-o", str(out)])
    assert r.exit_code == 1 and "cannot tell the output format" in r.output
    assert "slicing layers" not in r.output and not out.exists()


def test_an_output_beyond_a_limit_fails_the_compile_and_writes_nothing(tmp_path, monkeypatch):
    """The compile measures the samples it writes; if the planner ever plans beyond a limit
    (simulated: it plans to 1.5x the joint accelerations and its own stage-wise check is off)
    the compile exits non-zero naming the channel and the previous output stays as it was.
    verify agrees on what is allowed."""
    from deltaslice.machine import Printer
    from deltaslice.machine.limits import TOLERANCE
    from deltaslice.verify import MARGIN

    assert MARGIN == TOLERANCE
    out = tmp_path / "cube.dsl"
    out.write_bytes(b"previous output")
    import deltaslice.planning.solver as solver

    real = Printer.planned_limits
    monkeypatch.setattr(Printer, "planned_limits", lambda self: real(self).scaled(1.5))
    monkeypatch.setattr(solver, "CHECK_TOLERANCE", float("inf"))  # past the planner's own stage-wise check too
    r = CliRunner().invoke(main, [str(CUBE), "--printer", str(ROOT / "printers" / "delta_etitc.toml"), "-o", str(out),
                                  "--scale", "0.3", "--quiet", "--workers", "1",
                                  # the joint accelerations, not the servos' torque, must be what binds
                                  "--set", "planning.torque_limit=off"])
    assert r.exit_code == 1, r.output
    assert "beyond the limits" in r.output and "acc" in r.output and "Traceback" not in r.output
    assert out.read_bytes() == b"previous output"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cube.dsl"]


def test_compile_checks_the_printer_while_the_slicing_workers_run(tmp_path):
    """A compile of a mesh from a printer path (or an unchecked Printer, as the CLI gives it) forks
    its slicing workers before this process imports numba, checks the printer's reach (numba's
    first load) while they slice, and writes the bytes a compile from a checked printer writes."""
    import json
    import subprocess
    import sys

    marks, fast, checked = tmp_path / "marks.jsonl", tmp_path / "fast.dsl", tmp_path / "checked.dsl"
    printer = ROOT / "printers" / "delta_etitc.toml"
    code = f"""
import json, os, sys
import deltaslice.slicing.slicer as S
from deltaslice import jit
from deltaslice.machine import load_printer
from deltaslice.pipeline import compile_part

plan_range = S._plan_range
def recorded(a, b):
    out = plan_range(a, b)
    with open({str(marks)!r}, 'a') as f:
        f.write(json.dumps([os.getpid(), 'numba' in sys.modules or jit.loaded()]) + chr(10))
    return out
S._plan_range = recorded
assert 'numba' not in sys.modules
compile_part({str(CUBE)!r}, {str(printer)!r}, output={str(fast)!r}, workers=2, scale=0.5)
assert jit.loaded()  # the main process loaded it, for planning
S._plan_range = plan_range
compile_part({str(CUBE)!r}, load_printer({str(printer)!r}), output={str(checked)!r}, workers=2, scale=0.5)
print(os.getpid())
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-3000:]
    main_pid = int(out.stdout.split()[-1])
    rows = [json.loads(line) for line in marks.read_text().splitlines()]
    assert len(rows) >= 4 and all(pid != main_pid for pid, _ in rows)  # ranges planned by forked workers
    assert not any(numba for _, numba in rows), rows
    assert fast.read_bytes() == checked.read_bytes()


def test_a_printer_that_reaches_nothing_stops_a_compile_while_it_slices(tmp_path):
    """The reach check done while the workers slice still refuses the printer, with the
    printer file's message, and nothing is written."""
    from deltaslice.errors import PrinterFileError
    from deltaslice.pipeline import compile_part, load_toolpath

    text = (ROOT / "printers" / "delta_etitc.toml").read_text().replace("shoulder_height = 527.0", "shoulder_height = 5000.0")
    bad = tmp_path / "far.toml"
    bad.write_text(text)
    out = tmp_path / "cube.dsl"
    with pytest.raises(PrinterFileError, match=r"far\.toml: \[kinematics\] geometry reaches no point"):
        compile_part(str(CUBE), str(bad), output=str(out), workers=2, scale=0.5)
    assert not out.exists()
    with pytest.raises(PrinterFileError, match=r"far\.toml: \[kinematics\] geometry reaches no point"):
        load_toolpath(str(CUBE), str(bad), workers=2, scale=0.5)  # a path: read with its checks
    r = CliRunner().invoke(main, [str(CUBE), "--printer", str(bad), "-o", str(out), "--scale", "0.5", "--quiet"])
    assert r.exit_code == 1 and r.output.startswith("error:") and "geometry reaches no point" in r.output
    assert not out.exists()
