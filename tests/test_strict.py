"""Strict checks (issue 15): verify fails what it should fail, the stream decoder stays in the
error family, every public library call refuses bad input with a DeltasliceError naming the
argument, and placement is checked (skirt on the bed, verify --toolpath placement)."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from trajectories import blocks, realistic

from deltaslice import DeltasliceError
from deltaslice.cli import main
from deltaslice.emit.stream import MAGIC, parse_header
from deltaslice.errors import PrinterFileError, StreamError, UnreachableError
from deltaslice.machine import load_printer
from deltaslice.emit import write_trajectory
from deltaslice.gcode import read_gcode
from deltaslice.pipeline import compile_part, load_toolpath, read_output, verify_output, write_output, write_samples
from deltaslice.planning import plan
from deltaslice.samples import Samples
from deltaslice.toolpath import Role, Toolpath, ToolpathBuilder
from deltaslice.verify import verify_samples

from conftest import PRINTER_DIR, ROOT, printer

ETITC = str(PRINTER_DIR / "delta_etitc.toml")
CUBE = ROOT / "examples" / "parts" / "calibration_cube.stl"


@pytest.fixture(scope="module")
def good():
    s, tp = realistic("delta_etitc", layers=1)
    return printer("delta_etitc"), s, tp


def _csv(tmp_path, p, s, name="x"):
    path = tmp_path / f"{name}.csv"
    write_samples(blocks(s), p, path, fmt="csv", rate=p.planning.output_rate)
    return path


def _raw_csv(tmp_path, p, s, name="raw"):
    """A CSV whose values are written as they are (the writer refuses non-finite values)."""
    path = tmp_path / f"{name}.csv"
    header = (f"# printer: {p.name}\n# fingerprint: 0x{p.fingerprint():08x}\n# rate_hz: {p.planning.output_rate:g}\n"
              "t,q1,q2,q3,e,tool\n")
    rows = np.column_stack([s.t, s.q, s.e, s.tool])
    buf = io.StringIO()
    np.savetxt(buf, rows, delimiter=",", fmt="%.10g")
    path.write_text(header + buf.getvalue())
    return path


def _verify_cli(path, *extra):
    return CliRunner().invoke(main, ["verify", str(path), "--printer", ETITC, *extra])


# ---------------------------------------------------------------------------- verify fails what it should


@pytest.mark.parametrize("where", ["q rows", "t", "tool", "e"])
def test_verify_fails_on_non_finite_values(good, tmp_path, where):
    p, s, _ = good
    t, q, e, tool = s.t.copy(), s.q.copy(), s.e.copy(), s.tool.copy()
    {"q rows": lambda: q.__setitem__(slice(100, 200), np.nan), "t": lambda: t.__setitem__(50, np.nan),
     "tool": lambda: tool.__setitem__(70, np.nan), "e": lambda: e.__setitem__(90, np.inf)}[where]()
    rep = verify_samples(Samples(t, q, e, tool), p, rate=p.planning.output_rate, fmt="csv")
    assert not rep.ok and any(v.kind == "non_finite" for v in rep.violations), rep.text()
    r = _verify_cli(_raw_csv(tmp_path, p, Samples(t, q, e, tool)))
    assert r.exit_code == 3 and "FAIL" in r.output and "non-finite" in r.output


def test_verify_fails_on_an_all_nan_file(good, tmp_path):
    p, s, _ = good
    n = 500
    nan = np.full(n, np.nan)
    r = _verify_cli(_raw_csv(tmp_path, p, Samples(np.arange(n) / 1000.0, np.full((n, 3), np.nan), nan, nan)))
    assert r.exit_code == 3 and "FAIL" in r.output


def test_verify_fails_on_a_header_only_file(tmp_path):
    path = tmp_path / "empty.csv"
    fingerprint = printer("delta_etitc").fingerprint()
    path.write_text(f"# printer: delta_etitc\n# fingerprint: 0x{fingerprint:08x}\n# rate_hz: 1000\nt,q1,q2,q3,e,tool\n")
    r = _verify_cli(path)
    assert r.exit_code == 3 and "FAIL" in r.output and "samples" in r.output


@pytest.mark.parametrize("rate", ["0", "-5", "nan", "inf", "fast"])
def test_verify_refuses_a_file_rate_that_is_not_a_rate(good, tmp_path, rate):
    p, s, _ = good
    path = _csv(tmp_path, p, s)
    text = path.read_text().replace("# rate_hz: 1000", f"# rate_hz: {rate}")
    path.write_text(text)
    r = _verify_cli(path)
    assert r.exit_code == 1 and r.stderr.startswith("error: ") and "rate" in r.stderr and "Traceback" not in r.output


def test_verify_fails_a_one_hertz_file_and_the_reader_refuses_output_rate_1(good, tmp_path):
    p, s, _ = good
    k = 1000
    slow = Samples(s.t[::k] * k / 1.0 / 1000.0 * 1000.0, s.q[::k], s.e[::k], s.tool[::k])
    slow = Samples(np.arange(len(slow)) * 1.0, slow.q, slow.e, slow.tool)
    rep = verify_samples(slow, p, rate=1.0, fmt="csv")
    assert not rep.ok and any(v.kind == "rate" for v in rep.violations)
    text = (PRINTER_DIR / "delta_etitc.toml").read_text().replace("output_rate = 1000.0", "output_rate = 1")
    bad = tmp_path / "slow.toml"
    bad.write_text(text)
    with pytest.raises(PrinterFileError, match=r"output_rate = 1.*>= 50"):
        load_printer(bad)


def test_verify_table_compares_the_filament_with_the_limit_that_applies(good, tmp_path):
    """Retracts move at the retract speed (idle limit), prints at the melt-flow limit: a
    row must never show the retract speed as a share of the melt-flow limit (1047.8 %)."""
    p, s, _ = good
    rep = verify_output(_csv(tmp_path, p, s), p)
    assert rep.ok, rep.text()
    row = next(r for r in rep.rows if r.check == "filament speed")
    assert row.percent is not None and row.percent <= 100.0 * 1.03, rep.text()
    assert row.limit in (p.limits.velocity[-1], p.limits.idle_velocity[-1])
    for r in rep.rows:
        assert r.ok and (r.percent is None or r.percent <= 103.0), r
    text = rep.text()
    assert "PASS" in text and "FAIL" not in text and "use" in text and "worst at" in text


def test_verify_table_marks_the_failing_row(good, tmp_path):
    p, s, _ = good
    q = s.q.copy()
    q[4000, 2] += 0.05
    rep = verify_output(_csv(tmp_path, p, Samples(s.t, q, s.e, s.tool)), p)
    failing = [r for r in rep.rows if not r.ok]
    assert failing and {r.channel for r in failing} == {"q3/theta3"}
    assert all(r.place is not None for r in failing)
    line = next(l for l in rep.table() if l.startswith("acceleration") and "q3" in l)
    assert line.endswith("FAIL") and "%" in line and "deg/s^2" in line


# ---------------------------------------------------------------------------- the stream header


def test_stream_header_length_smaller_than_its_contents_is_a_stream_error(good, tmp_path):
    p, s, _ = good
    path = tmp_path / "x.dsl"
    write_samples(blocks(s), p, path, fmt="stream", rate=p.planning.output_rate)
    data = bytearray(path.read_bytes())
    for hlen in (0, 3, 10, 30, 40):
        bad = bytearray(data)
        struct.pack_into("<H", bad, 10, hlen)
        with pytest.raises(StreamError):
            parse_header(bytes(bad), "x.dsl")
        with pytest.raises(StreamError):
            from deltaslice.emit import read_output

            read_output(bytes(bad), "x.dsl")
    assert data[:8] == MAGIC


# ---------------------------------------------------------------------------- library calls


def _builder():
    b = ToolpathBuilder((0.0, 0.0, 0.4))
    b.new_layer(0.4)
    return b


def _add(**kw):
    args = dict(xyz=[[5.0, 0.0, 0.4], [5.0, 5.0, 0.4]], feed=20.0, e=0.1, tool=1.0, role=Role.PERIMETER)
    args.update(kw)
    b = _builder()
    b.add(**args)
    return b.build()


def _tp(**kw):
    t = _add()
    fields = dict(start=t.start, xyz=t.xyz, feed=t.feed, e=t.e, tool=t.tool, role=t.role, layer=t.layer, layer_z=t.layer_z)
    fields.update(kw)
    return Toolpath(**fields)


BAD_CALLS = {
    "load_printer(None)": lambda: load_printer(None),
    "load_printer(42)": lambda: load_printer(42),
    "load_printer('no_such_printer')": lambda: load_printer("no_such_printer"),
    "role=300": lambda: _add(role=300),
    "role=200": lambda: _add(role=200),
    "scalar xyz": lambda: _add(xyz=5.0),
    "xyz (2, 2)": lambda: _add(xyz=[[1.0, 2.0], [3.0, 4.0]]),
    "complex xyz": lambda: _add(xyz=np.array([[5.0 + 1j, 0, 0.4]])),
    "string xyz": lambda: _add(xyz="abc"),
    "None xyz": lambda: _add(xyz=None),
    "tool nan": lambda: _add(tool=np.nan),
    "tool 5": lambda: _add(tool=5.0),
    "tool -1": lambda: _add(tool=-1.0),
    "feed 1e-12": lambda: _add(feed=1e-12),
    "feed nan": lambda: _add(feed=np.nan),
    "feed per move, wrong count": lambda: _add(feed=[1.0, 2.0, 3.0]),
    "layer beyond layer_z": lambda: _tp(layer=np.array([0, 5])),
    "negative layer": lambda: _tp(layer=np.array([-1, 0])),
    "new_layer(None)": lambda: _builder().new_layer(None),
    "new_layer(nan)": lambda: _builder().new_layer(float("nan")),
    "plan(tp, 'file.toml')": lambda: plan(_add(), ETITC),
    "plan(None, printer)": lambda: plan(None, printer("delta_etitc")),
    "plan workers=0": lambda: plan(_add(), printer("delta_etitc"), workers=0),
    "load_toolpath workers=0": lambda: load_toolpath(CUBE, printer("delta_etitc"), workers=0),
    "load_toolpath workers='2'": lambda: load_toolpath(CUBE, printer("delta_etitc"), workers="2"),
    "write_output workers=1.5": lambda: write_output(_planned(), "/tmp/x.dsl", workers=1.5),
    "compile_part workers=0": lambda: compile_part(CUBE, printer("delta_etitc"), output="/tmp/x.dsl", workers=0),
    "plan(extruding toolpath, laser printer)": lambda: plan(_add(), printer("delta_espe_laser")),
    "plan(laser toolpath, extruder printer)": lambda: plan(_add(e=0.0, role=Role.LASER), printer("delta_etitc")),
    "plan spool='yes'": lambda: plan(_add(), printer("delta_etitc"), spool="yes"),
    "plan planner='x'": lambda: plan(_add(), printer("delta_etitc"), planner="x"),
    "single zero-length move, trapezoid": lambda: plan(
        _add(xyz=[[0.0, 0.0, 0.4]], e=0.0), printer("delta_etitc"), planner="trapezoid"),
    "compile into a missing directory": lambda: compile_part(CUBE, printer("delta_etitc"), output="/nonexistent_dir/x.dsl"),
    "compile_part(None, ...)": lambda: compile_part(None, printer("delta_etitc")),
    "load_toolpath(None, ...)": lambda: load_toolpath(None, printer("delta_etitc")),
    "write_output of a toolpath": lambda: write_output(_add(), "/tmp/x.dsl"),
    "write_output to None": lambda: write_output(_add(), None),
    "verify_output(None, ...)": lambda: verify_output(None, printer("delta_etitc")),
    "verify_samples(rate=0)": lambda: verify_samples(
        Samples(np.zeros(2), np.zeros((2, 3)), np.zeros(2), np.zeros(2)), printer("delta_etitc"), rate=0, fmt="csv"),
    "verify_samples(printer=path)": lambda: verify_samples(
        Samples(np.zeros(2), np.zeros((2, 3)), np.zeros(2), np.zeros(2)), ETITC, rate=1000, fmt="csv"),
    # the readers, Samples, writers and starts (what each message must name after the colon)
    "read_gcode(None)": lambda: read_gcode(None),
    "read_gcode(123)": lambda: read_gcode(123),
    "read_output(None)": lambda: read_output(None),
    "write_trajectory(traj, None, 'csv')": lambda: write_trajectory(_planned(), None, "csv"),
    "write_trajectory(traj, text file, 'csv')": lambda: write_trajectory(_planned(), io.StringIO(), "csv"),
    "write_trajectory(None, f, 'csv')": lambda: write_trajectory(None, io.BytesIO(), "csv"),
    "Samples(None, ...)": lambda: Samples(None, None, None, None),
    "Samples e shorter than t": lambda: Samples(np.zeros(3), np.zeros((3, 3)), np.zeros(2), np.zeros(3)),
    "Samples q rows not t": lambda: Samples(np.zeros(3), np.zeros((2, 3)), np.zeros(3), np.zeros(3)),
    "Samples tool strings": lambda: Samples(np.zeros(2), np.zeros((2, 3)), np.zeros(2), ["a", "b"]),
    "Toolpath(start=[nan, 0, 0])": lambda: _tp(start=np.array([np.nan, 0.0, 0.0])),
    "empty Toolpath(start=[nan, 0, 0])": lambda: Toolpath.empty(start=(np.nan, 0.0, 0.0)),
    "ToolpathBuilder((nan, 0, 0))": lambda: ToolpathBuilder((np.nan, 0.0, 0.0)),
    "ToolpathBuilder((1, 2))": lambda: ToolpathBuilder((1.0, 2.0)),
    "write_samples(etitc trajectory, ucb)": lambda: write_samples(
        _planned(), printer("delta_ucb"), "/tmp/deltaslice_strict_never.dsl", fmt="stream", rate=1000.0),
    "write_samples(2-joint blocks, etitc)": lambda: write_samples(
        [Samples(np.zeros(2), np.zeros((2, 2)), np.zeros(2), np.zeros(2))], printer("delta_etitc"),
        "/tmp/deltaslice_strict_never.dsl", fmt="stream", rate=1000.0),
    "write_samples(None, etitc)": lambda: write_samples(
        None, printer("delta_etitc"), "/tmp/deltaslice_strict_never.csv", fmt="csv", rate=1000.0),
}

# the argument each message names (the rest name theirs too; these are checked word for word)
NAMED = {
    "read_gcode(None)": "path", "read_gcode(123)": "path", "read_output(None)": "path",
    "write_trajectory(traj, None, 'csv')": "f:", "write_trajectory(traj, text file, 'csv')": "f:",
    "write_trajectory(None, f, 'csv')": "trajectory", "Samples(None, ...)": "Samples.t",
    "Samples e shorter than t": "Samples.e", "Samples q rows not t": "Samples.q", "Samples tool strings": "Samples.tool",
    "Toolpath(start=[nan, 0, 0])": "start", "empty Toolpath(start=[nan, 0, 0])": "start",
    "ToolpathBuilder((nan, 0, 0))": "start", "ToolpathBuilder((1, 2))": "start",
    "write_samples(etitc trajectory, ucb)": "delta_ucb", "write_samples(2-joint blocks, etitc)": "joints",
    "write_samples(None, etitc)": "blocks",
    "plan(extruding toolpath, laser printer)": "has a laser", "plan(laser toolpath, extruder printer)": "has an extruder",
    "plan spool='yes'": "spool",
}


_PLANNED = {}


def _planned():
    """A trajectory planned for delta_etitc (planned once)."""
    if "t" not in _PLANNED:
        _PLANNED["t"] = plan(_add(), printer("delta_etitc"), workers=1)
    return _PLANNED["t"]


@pytest.mark.parametrize("case", list(BAD_CALLS))
def test_bad_library_calls_raise_the_family_naming_the_argument(case):
    with pytest.raises(DeltasliceError) as err:
        BAD_CALLS[case]()
    assert str(err.value), case
    if case in NAMED:
        assert NAMED[case] in str(err.value), str(err.value)
    assert not list(Path("/tmp").glob("deltaslice_strict_never*")), "a refused call wrote its output"


def test_numpy_scalars_are_numbers(tmp_path):
    tp = load_toolpath(CUBE, printer("delta_etitc"), scale=np.float32(2), rotate=np.float64(10.0))
    assert tp.n_layers > 40


def test_absurd_geometry_number_is_refused(tmp_path):
    text = (PRINTER_DIR / "delta_etitc.toml").read_text().replace("forearm = 360.0", "forearm = 1e160")
    bad = tmp_path / "big.toml"
    bad.write_text(text)
    with pytest.raises(PrinterFileError, match=r"forearm = 1e\+160"):
        load_printer(bad)


# ---------------------------------------------------------------------------- placement


def _cube_at(tmp_path, x):
    import trimesh

    mesh = trimesh.creation.box((20.0, 20.0, 10.0))
    mesh.apply_translation((x, 0.0, 5.0))
    path = tmp_path / f"cube_{x:g}.stl"
    mesh.export(path)
    return path


def test_keep_position_refuses_a_skirt_off_the_bed(tmp_path):
    """A 20 mm cube at x = 68 fits the 80 mm bed (to 78 mm) but its skirt (6 mm out) does not."""
    part = _cube_at(tmp_path, 68.0)
    with pytest.raises(UnreachableError, match="leave the bed"):
        load_toolpath(part, printer("delta_etitc"), keep_position=True)
    r = CliRunner().invoke(main, ["slice", str(part), "--printer", ETITC, "--keep-position", "-o", str(tmp_path / "x.gcode"),
                                  "--quiet"])
    assert r.exit_code == 1 and "leave the bed" in r.stderr
    assert load_toolpath(part, printer("delta_etitc")).n_layers > 0  # centred, it prints


def test_verify_toolpath_takes_the_placement_options(tmp_path):
    part = _cube_at(tmp_path, 30.0)
    out = tmp_path / "c.dsl"
    r = CliRunner().invoke(main, [str(part), "--printer", ETITC, "--keep-position", "--set", "slicing.layer_height=0.5",
                                  "--set", "slicing.first_layer_height=0.5", "-o", str(out), "--quiet", "--workers", "1"])
    assert r.exit_code == 0, r.output
    good = _verify_cli(out, "--toolpath", str(part), "--keep-position", "--set", "slicing.layer_height=0.5",
                       "--set", "slicing.first_layer_height=0.5")
    assert good.exit_code == 0, good.output
    centred = _verify_cli(out, "--toolpath", str(part), "--set", "slicing.layer_height=0.5",
                          "--set", "slicing.first_layer_height=0.5")
    assert centred.exit_code == 3 and "deviation" in centred.output


def test_write_samples_takes_a_trajectory_planned_for_the_printer(tmp_path):
    traj = _planned()
    out = tmp_path / "x.dsl"
    size = write_samples(traj, printer("delta_etitc"), out, fmt="stream", rate=1000.0)
    meta, back = read_output(out)
    assert size == out.stat().st_size and meta["printer"] == "delta_etitc"
    assert len(back) == int(np.ceil(traj.duration * 1000.0 - 1e-9)) + 1
