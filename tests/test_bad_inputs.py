"""Every bad input ends with one line in the user's words (issue 50): the exit status, an
``error:`` line naming the file and the problem, no traceback and no Python exception name;
readers of untrusted files bounded in time and memory."""

from __future__ import annotations

import re
import resource
import struct
import subprocess
import sys
import time
import zipfile
import zlib

import numpy as np
import pytest
from click.testing import CliRunner

from deltaslice.cli import main
from deltaslice.emit import stream

from conftest import ROOT, printer

LASER = "delta_espe_laser"
STROKE = 'stroke="black" fill="none"'
# a Python exception's name (ValueError, StopIteration, BadZipFile, ...) in a message
PYTHON_NAMES = re.compile(r"\b[A-Z]\w*(Error|Exception|Warning)\b|StopIteration|BadZipFile|Traceback")


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def one_line_error(result, code=1) -> str:
    """The error line of a CLI run that must end with one error line and ``code``."""
    assert not (result.exception and not isinstance(result.exception, SystemExit)), result.exception
    assert result.exit_code == code, result.output
    errors = [line for line in result.output.splitlines() if line.startswith(("error:", "Error:"))]
    assert len(errors) == 1, result.output
    assert not PYTHON_NAMES.search(result.output), result.output
    return errors[0]


def _svg(tmp_path, body, root='<svg xmlns="http://www.w3.org/2000/svg" width="100" height="100">', name="a.svg"):
    path = tmp_path / name
    path.write_text(f"{root}{body}</svg>")
    return path


# ----------------------------------------------------------------------------------- printer files

BIG = "1" + "0" * 309  # an integer of 310 digits: no float holds it


def test_a_printer_number_of_310_digits_is_one_line(tmp_path):
    text = (ROOT / "printers" / "delta_etitc.toml").read_text()
    path = tmp_path / "big.toml"
    path.write_text(re.sub(r"(?m)^forearm = .*$", f"forearm = {BIG}", text, count=1))
    line = one_line_error(_run("firmware-config", "--printer", path))
    assert "[kinematics] forearm = 100... (an integer of 310 digits)" in line and "magnitude <= 1e+12" in line


def test_a_sensor_table_number_of_310_digits_is_one_line(tmp_path):
    text = (ROOT / "printers" / "delta_ucb.toml").read_text()
    path = tmp_path / "big.toml"
    table = f"sensor_table = [[[0, 0], [{BIG}, 1]], [[0, 0], [1, 1]], [[0, 0], [1, 1]]]"
    path.write_text(re.sub(r"(?m)^sensor_table = .*$", table, text, count=1))
    line = one_line_error(_run("firmware-config", "--printer", path))
    assert "[joints] sensor_table" in line and len(line) < 600


# ----------------------------------------------------------------------------------- SVG and images


def test_an_svg_in_another_namespace_is_one_line(tmp_path):
    path = _svg(tmp_path, f'<path d="M 10 10 L 50 50" {STROKE}/>',
                root='<svg xmlns="http://example.com/other" width="100" height="100">')
    line = one_line_error(_run(path, "--printer", LASER, "-o", tmp_path / "o.dsl"))
    assert "not an SVG drawing" in line and "http://www.w3.org/2000/svg" in line


@pytest.mark.parametrize("root", [
    '<svg xmlns="http://www.w3.org/2000/svg" width="100" height="1e308" viewBox="0 0 100 100">',
    '<svg xmlns="http://www.w3.org/2000/svg" width="1e308" height="1e308" viewBox="0 0 100 100">',
])
def test_an_svg_width_or_height_of_1e308_is_one_line(tmp_path, root):
    path = _svg(tmp_path, f'<path d="M 10 10 L 50 50" {STROKE}/>', root=root)
    line = one_line_error(_run(path, "--printer", LASER, "-o", tmp_path / "o.dsl"))
    assert "SVG coordinate" in line and "no drawing is that large" in line


@pytest.mark.parametrize("body", [
    f'<path d="M 10 10 L {"9" * 320} 50" {STROKE}/>',
    f'<path d="M 10 10 Q 50 1{"0" * 320} 90 50" {STROKE}/>',
    f'<circle cx="50" cy="50" r="1{"0" * 320}" {STROKE}/>',
    f'<path d="M 10 10 L 1e308 50 L -1e308 50" {STROKE}/>',
])
def test_an_svg_coordinate_of_320_digits_is_one_line(tmp_path, body):
    line = one_line_error(_run(_svg(tmp_path, body), "--printer", LASER, "-o", tmp_path / "o.dsl"))
    assert "SVG coordinate" in line


def test_an_svg_that_is_not_xml_says_so_without_parseerror(tmp_path):
    path = tmp_path / "a.svg"
    path.write_text('<svg xmlns="http://www.w3.org/2000/svg"><path d="M 0 0 L 1 1"')
    line = one_line_error(_run(path, "--printer", LASER, "-o", tmp_path / "o.dsl"))
    assert "not well-formed XML" in line and "line 1" in line


def _png(shape=(64, 64)) -> bytes:
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray((np.random.default_rng(0).random(shape) * 255).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def test_a_file_that_is_not_an_image_is_one_line(tmp_path):
    path = tmp_path / "a.png"
    path.write_text("hello, not an image")
    line = one_line_error(_run(path, "--printer", LASER, "-o", tmp_path / "o.dsl"))
    assert "not an image file" in line


def test_a_truncated_image_is_one_line(tmp_path):
    path = tmp_path / "a.png"
    data = _png()
    path.write_bytes(data[: len(data) // 2])
    line = one_line_error(_run(path, "--printer", LASER, "-o", tmp_path / "o.dsl"))
    assert "damaged or truncated" in line


def test_a_raster_line_pitch_of_a_nanometre_is_refused_before_allocating(tmp_path):
    path = tmp_path / "a.png"
    path.write_bytes(_png())
    line = one_line_error(_run(path, "--printer", LASER, "--mode", "raster", "--line-pitch", "1e-6",
                               "-o", tmp_path / "o.dsl"))
    assert "line pitch of 1e-06 mm" in line and "at least" in line


def test_an_engraving_too_wide_says_what_fits(tmp_path):
    path = tmp_path / "a.png"
    path.write_bytes(_png())
    line = one_line_error(_run(path, "--printer", LASER, "--width", "1e6", "-o", tmp_path / "o.dsl"))
    assert "does not fit" in line and "the largest that fits" in line and "no part of the work area" not in line


# ----------------------------------------------------------------------------------- meshes


def _zip(path, parts):
    with zipfile.ZipFile(path, "w") as z:
        for name, text in parts.items():
            z.writestr(name, text)
    return path


@pytest.mark.parametrize("name, make, words", [
    ("empty.3mf", lambda p: _zip(p, {}), "without a 3D model"),
    ("bad.3mf", lambda p: p.write_bytes(b"PK\x03\x04 not a zip"), "a 3MF is a zip archive"),
    ("bad.ply", lambda p: p.write_text("plx\nformat ascii 1.0\nend_header\n"), "not a PLY file"),
    ("short.ply", lambda p: p.write_text("not a ply at all\n"), "not a readable PLY file"),
    ("short.off", lambda p: p.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n"), "not a readable OFF file"),
])
def test_a_damaged_mesh_is_one_line(tmp_path, name, make, words):
    path = tmp_path / name
    make(path)
    line = one_line_error(_run(path, "--printer", "delta_etitc", "-o", tmp_path / "o.dsl"))
    assert words in line


# ----------------------------------------------------------------------------------- planning


def test_a_joint_velocity_too_low_for_any_travel_is_one_line(tmp_path):
    line = one_line_error(_run(ROOT / "examples" / "parts" / "calibration_cube.stl", "--printer", "delta_etitc",
                               "--set", "joints.velocity_max=1e-9", "-o", tmp_path / "o.dsl", "--quiet"))
    assert "velocity_max = 1e-09 deg/s" in line and "7600 s" in line


# ----------------------------------------------------------------------------------- streams


def hostile_stream(blocks=1000, n=65535) -> bytes:
    """A stream with valid CRCs and delta_etitc's fingerprint whose blocks of width 0 each declare
    n samples: 17 bytes a block."""
    p = printer("delta_etitc")
    data = bytearray(stream.StreamHeader.for_printer(p, p.planning.output_rate).encode())
    body = bytes([0x40, 0]) * (p.n_joints + 1)  # order 1, width 0, first count 0
    for _ in range(blocks):
        rec = struct.pack("<BHH", stream.REC_BLOCK, 5 + len(body) + 4, n) + body
        data += rec + struct.pack("<I", zlib.crc32(rec))
    end = struct.pack("<BHII", stream.REC_END, stream.END_LEN, blocks * n, zlib.crc32(bytes(data)))
    return bytes(data + end + struct.pack("<I", zlib.crc32(end)))


def _limited(limit_bytes):
    def set_limit():
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    return set_limit


@pytest.mark.parametrize("command", [["verify", "{f}", "--printer", "delta_etitc"], ["decode", "{f}", "--units"]])
def test_a_17_kb_stream_declaring_65_million_samples_is_refused_fast_in_little_memory(tmp_path, command):
    """17 KB with valid CRCs: verify asked for gigabytes (MemoryError under 2 GB), decode --units ran past 20 s."""
    path = tmp_path / "hostile.dsl"
    path.write_bytes(hostile_stream())
    assert path.stat().st_size < 18_000
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-m", "deltaslice", *[a.format(f=path) for a in command]], cwd=ROOT,
                         capture_output=True, text=True, timeout=60, preexec_fn=_limited(1 << 30))
    assert time.monotonic() - t0 < 20
    assert out.returncode == 1, out.stderr[-2000:]
    assert out.stderr.strip().splitlines()[-1].startswith("error:") and "Traceback" not in out.stderr
    assert "declares 65535 samples, more than the 512" in out.stderr


def test_the_stream_reader_takes_blocks_of_up_to_512_samples():
    import io

    assert len(stream.read_counts(io.BytesIO(hostile_stream(blocks=3, n=512)), "s")[1]) == 3 * 512


def test_verify_refuses_a_stream_whose_samples_would_not_fit_before_reading_it(tmp_path):
    """65,000 resting blocks of 512 samples: 1.1 MB holding 33 million samples (4.7 GB to verify).
    Under a 1 GB address-space limit verify says so at once instead of running out of memory."""
    path = tmp_path / "long.dsl"
    path.write_bytes(hostile_stream(blocks=65_000, n=512))
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-m", "deltaslice", "verify", str(path), "--printer", "delta_etitc"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60, preexec_fn=_limited(1 << 30))
    assert time.monotonic() - t0 < 20
    assert out.returncode == 1, out.stderr[-2000:]
    assert "33.3 million samples" in out.stderr and "GB to verify at once" in out.stderr
    assert "Traceback" not in out.stderr


def test_verify_reads_a_dsl_with_a_damaged_magic_number_as_a_stream(tmp_path):
    data = bytearray(hostile_stream(blocks=2, n=4))
    data[1] ^= 0xFF
    path = tmp_path / "a.dsl"
    path.write_bytes(bytes(data))
    line = one_line_error(_run("verify", path, "--printer", "delta_etitc"))
    assert "not a deltaslice stream (bad magic" in line and "CSV" not in line


# ----------------------------------------------------------------------------------- G-code and job bounds

START = "G21\nG90\nM82\nG92 E0\n;LAYER:0\nG1 Z0.4 F600\nG1 X-10 Y-10 F3000\n"


@pytest.mark.parametrize("moves, line_no", [
    ("G1 E1e6 F1200\n", 8),  # compiled, then verify ran out of memory
    ("G1 E200000 F1200\n", 8),
    ("G1 X5 Y-10 E0.5 F1200\nG1 X5 Y5 E1e9\n", 9),  # a filament limit reported at the wrong place
])
def test_a_move_of_kilometres_of_filament_is_refused_naming_its_line(tmp_path, moves, line_no):
    path = tmp_path / "a.gcode"
    path.write_text(START + moves)
    line = one_line_error(_run(path, "--printer", "delta_etitc", "-o", tmp_path / "o.dsl", "--quiet"))
    assert f"a.gcode:{line_no}:" in line and "more than 10 m" in line and "M83" in line


SQUARE = START + "G1 X5 Y-10 E0.5 F1200\nG1 X5 Y5 E1.0\nG1 X-10 Y5 E1.5\nG1 X-10 Y-10 E2.0\n"


@pytest.mark.parametrize("value", ["nan", "inf", "-1", "ten"])
def test_max_time_nan_is_a_usage_error_that_says_why(tmp_path, value):
    path = tmp_path / "a.gcode"
    path.write_text(SQUARE)
    result = _run(path, "--printer", "delta_etitc", "--max-time", value, "-o", tmp_path / "o.dsl")
    assert result.exit_code == 2, result.output
    assert "--max-time" in result.output and "hours" in result.output and "exceeds" not in result.output


def test_a_small_size_bound_is_shown_with_its_digits(tmp_path):
    path = tmp_path / "a.gcode"
    path.write_text(SQUARE)
    line = one_line_error(_run(path, "--printer", "delta_etitc", "--max-size", "0.001", "-o", tmp_path / "o.dsl"))
    assert "over the bound 0.001 MiB" in line and "about 0 MiB" not in line


def test_the_library_refuses_a_nan_bound_by_name(tmp_path):
    from deltaslice import DeltasliceError
    from deltaslice.pipeline import compile_part

    path = tmp_path / "a.gcode"
    path.write_text(SQUARE)
    with pytest.raises(DeltasliceError, match=r"max_duration_s = nan: expected a finite number of seconds > 0"):
        compile_part(path, "delta_etitc", output=tmp_path / "o.dsl", max_duration_s=float("nan"))


# ----------------------------------------------------------------------------------- Ctrl-C


@pytest.mark.parametrize("delay", [1.5, 3.0, 4.5])
def test_ctrl_c_to_the_process_group_leaves_no_worker_traceback(tmp_path, delay):
    """A terminal's Ctrl-C signals every process of the group: the pool's workers printed
    "Process ForkProcess-1: Traceback ... KeyboardInterrupt" in 6 interrupts of 10. A worker that
    leaves halfway through sending a result must not hang the parent (it did, at 4.5 s, once the
    workers left silently: the pool's shutdown waited for the rest of the result)."""
    import os
    import signal

    proc = subprocess.Popen([sys.executable, "-m", "deltaslice", str(ROOT / "examples" / "parts" / "calibration_cube.stl"),
                             "--printer", "delta_etitc", "-o", str(tmp_path / "c.dsl"), "--quiet", "--scale", "3",
                             "--workers", "2"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    time.sleep(delay)
    os.killpg(proc.pid, signal.SIGINT)
    _out, err = proc.communicate(timeout=60)
    if proc.returncode == 0:
        pytest.skip("the compile finished before the signal")
    lines = [line for line in err.splitlines() if not line.startswith("mesh: ")]
    assert proc.returncode == 130 and len(lines) == 1 and lines[0].startswith("interrupted"), err


# ----------------------------------------------------------------------------------- small surprises


def test_workspace_json_writes_no_picture(tmp_path, monkeypatch):
    import json

    monkeypatch.chdir(tmp_path)
    result = _run("workspace", "--printer", "delta_etitc", "--json")
    assert result.exit_code == 0, result.output
    assert list(tmp_path.iterdir()) == []
    assert json.loads(result.stdout)["plot"] is None
    result = _run("workspace", "--printer", "delta_etitc", "--json", "--plot", tmp_path / "ws.png")
    assert result.exit_code == 0 and (tmp_path / "ws.png").stat().st_size > 0


def test_decode_into_head_ends_quietly(tmp_path):
    """decode's own help example, `deltaslice decode cube.dsl | head`: it exited 1 (click's broken-pipe exit)."""
    path = tmp_path / "a.dsl"
    path.write_bytes(hostile_stream(blocks=400, n=512))  # 200,000 lines: far more than a pipe holds
    for extra in ([], ["--units"]):
        out = subprocess.run(f"'{sys.executable}' -m deltaslice decode '{path}' {' '.join(extra)} | head -1; "
                             "exit ${PIPESTATUS[0]}", shell=True, executable="/bin/bash", cwd=ROOT,
                             capture_output=True, text=True, timeout=120)
        assert out.returncode == 0 and out.stderr == "" and len(out.stdout.splitlines()) == 1, (out.returncode, out.stderr)


def _filament_limit_lines(fig):
    """The red dashed lines of the filament panel: [(x, y)] arrays."""
    ax = next(a for a in fig.axes if a.get_title().startswith("filament speed"))
    return ax, [(np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)) for line in ax.get_lines()
                if line.get_linestyle() == "--"]


def test_preview_draws_the_limit_a_retraction_is_held_to():
    """A retraction at 25 mm/s (tool off) under a melt-flow limit of 2.1 mm/s: the panel drew the
    melt-flow limit as the only upper line, which every unretraction crossed."""
    from deltaslice.preview import trajectory_figure
    from deltaslice.samples import Samples

    p = printer("delta_etitc")
    working, idle = p.limits.tool_velocity_limits()
    t = np.arange(3000) / 1000.0
    e = np.where(t < 1.0, 0.0, np.where(t < 1.1, -25.0 * (t - 1.0), np.where(t < 1.2, -2.5 + 25.0 * (t - 1.1), 1.0 * (t - 1.2))))
    tool = (t >= 1.2).astype(float)
    q = np.tile(np.radians([40.0, 40.0, 40.0]), (len(t), 1))
    fig = trajectory_figure(Samples(t, q, e, tool), p)
    ax, lines = _filament_limit_lines(fig)
    top = max(y.max() for _x, y in lines)
    bottom = min(y.min() for _x, y in lines)
    assert top >= 25.0 and bottom <= -25.0 and idle >= 25.0
    # where the tool extrudes throughout, the melt-flow limit is what is drawn
    x, y = max(lines, key=lambda xy: xy[1].max())
    assert np.isclose(y[x > 1.5].max(), working)
    fig = trajectory_figure(Samples(t, q, e, tool), p, tool_state=False)  # a stream's: the larger limit throughout
    ax, lines = _filament_limit_lines(fig)
    assert sorted(float(y[0]) for _x, y in lines) == [-max(working, idle), max(working, idle)]


def test_slice_says_its_time_is_wall_time(tmp_path):
    result = _run("slice", ROOT / "examples" / "parts" / "calibration_cube.stl", "--printer", "delta_etitc",
                  "-o", tmp_path / "c.gcode", "--quiet", "--scale", "0.3")
    assert result.exit_code == 0, result.output
    assert re.search(r"wall time \d+\.\d\d s$", result.stdout.strip())


def test_the_verify_rate_row_says_its_limit_is_a_minimum(tmp_path):
    import io

    from deltaslice.emit.stream import read_stream
    from deltaslice.verify import verify_samples

    meta, samples = read_stream(io.BytesIO(hostile_stream(blocks=3, n=8)), "s")
    report = verify_samples(samples, printer("delta_etitc"), rate=1000.0, fmt="stream", meta=meta)
    row = next(line for line in report.text().splitlines() if "Hz" in line and "50" in line)
    assert row.startswith("sample rate, at least")


# ----------------------------------------------------------------------------------- the library


@pytest.mark.parametrize("kwargs, words", [
    (dict(overrides=[1, 2]), "overrides = [1, 2]: expected a dict"),
    (dict(overrides="slicing.layer_height=0.3"), "expected a dict"),
    (dict(overrides={1: 2}), "overrides: key 1: expected a 'section.key' string"),
    (dict(reach_checks="no"), "reach_checks = 'no': expected True or False"),
])
def test_load_printer_refuses_bad_arguments_in_the_family(kwargs, words):
    from deltaslice import PrinterFileError, load_printer

    with pytest.raises(PrinterFileError, match=re.escape(words)):
        load_printer("delta_etitc", **kwargs)


def _square(side=20.0, z=0.4, feed=30.0):
    from deltaslice import Role, Toolpath

    h = side / 2
    xyz = np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z], [-h, -h, z]])
    n = len(xyz)
    return Toolpath(start=np.array([0.0, 0.0, 5.0 * side / 20.0 if side < 1 else 5.0]), xyz=xyz,
                    feed=np.r_[120.0 if feed < 1000 else feed, np.full(n - 1, feed)],
                    e=np.r_[0.0, np.full(n - 1, 0.033 * side)], tool=np.r_[0.0, np.ones(n - 1)],
                    role=np.r_[Role.OTHER, np.full(n - 1, Role.EXTERNAL_PERIMETER)], layer=np.zeros(n, int),
                    layer_z=np.array([z]))


@pytest.mark.parametrize("make, words", [
    (lambda: _square(side=0.02, z=0.0004), "coordinates in metres?"),  # a 20 mm square given in metres
    (lambda: _square(z=-0.4), "below the bed surface"),
    (lambda: _square(feed=1800.0), "in mm/min?"),
])
def test_plan_notes_a_toolpath_probably_in_other_units(make, words):
    from deltaslice import DeltasliceError, ToolpathWarning
    from deltaslice.planning import plan

    with pytest.warns(ToolpathWarning, match=re.escape(words)):
        try:
            plan(make(), printer("delta_etitc"), workers=1)
        except DeltasliceError:
            pass  # the note comes first, whatever planning then finds (a square below the bed is out of reach)


def test_plan_notes_nothing_for_a_plain_square():
    import warnings

    from deltaslice import ToolpathWarning
    from deltaslice.planning import plan

    with warnings.catch_warnings():
        warnings.simplefilter("error", ToolpathWarning)
        plan(_square(), printer("delta_etitc"), workers=1)


def test_a_filament_limit_the_planner_cannot_meet_names_the_move_and_its_extrusion(tmp_path):
    """9,000 mm of filament over a 20 mm edge (under the 10 m bound): the line said only "between
    grid points at" a point, a grid stage's start, which on a straight stretch may be moves away."""
    path = tmp_path / "a.gcode"
    path.write_text(START + "G1 X10 Y-10 E0.6 F1200\nG1 X10 Y10 E1.2\nG1 X-10 Y10 E9000\nG1 X-10 Y-10 E9000.6\n")
    line = one_line_error(_run(path, "--printer", "delta_etitc", "-o", tmp_path / "o.dsl", "--quiet"))
    assert "where the extrusion becomes 449.9 mm of filament per mm of path, at x = 10.00, y = 10.00" in line


def test_verify_counts_a_csv_by_its_lines_against_the_memory_it_may_use(tmp_path, monkeypatch):
    from deltaslice import StreamError, pipeline
    from deltaslice.emit import csv as csvfmt

    t = np.arange(5000) / 1000.0
    path = tmp_path / "a.csv"
    path.write_text(csvfmt.comment_lines("delta_etitc", 1, 1000.0, ["rad"] * 3, {})
                    + csvfmt.format_rows(t, np.full((5000, 3), 0.5), 0.1 * t, np.ones(5000)))
    lines = path.read_bytes().count(b"\n")
    need = lines * pipeline.VERIFY_BYTES_PER_VALUE * 7
    monkeypatch.setattr(pipeline, "_memory_budget", lambda: need - 1)
    with pytest.raises(StreamError, match=rf"its {lines / 1e6:.3g} million samples .* more than the"):
        pipeline.verify_output(path, "delta_etitc")
    monkeypatch.setattr(pipeline, "_memory_budget", lambda: need)  # counted, not guessed from the size: it fits
    pipeline.verify_output(path, "delta_etitc")


def test_a_few_arcs_of_a_billion_mm_are_refused_before_their_points_are_made(tmp_path):
    """A 959-byte G-code of 40 full circles of radius 1e9 mm asked for 28 million points: a
    MemoryError traceback after 70 s under a 3 GB cap."""
    path = tmp_path / "a.gcode"
    path.write_text("G21\nG90\nM82\nG92 E0\nG1 X0 Y0 Z0.4 F3000\n" + "G2 X0 Y0 I1e9 J0 F3000\n" * 40)
    t0 = time.monotonic()
    line = one_line_error(_run(path, "--printer", "delta_etitc", "-o", tmp_path / "o.dsl", "--quiet"))
    assert time.monotonic() - t0 < 20
    assert "a.gcode:7: the arcs up to this line would be" in line and "are I, J and R in mm?" in line


def test_an_svg_of_long_curves_is_refused_before_its_points_are_made(tmp_path, monkeypatch):
    """Each curve becomes up to 2,000 points: 250 KB of them asked for 2 GB (38 s). Here with the
    bound made small, so the test is quick."""
    from deltaslice import engrave

    monkeypatch.setattr(engrave, "MAX_SVG_POINTS", 10_000)
    segs = " ".join(f"Q 5 5 {100000 if i % 2 == 0 else 0} 0" for i in range(20))
    path = _svg(tmp_path, f'<path d="M 0 0 {segs}" {STROKE}/>')
    line = one_line_error(_run(path, "--printer", LASER, "-o", tmp_path / "o.dsl"))
    assert "more than 10,000 points once curves are flattened" in line


def test_a_3mf_that_unpacks_to_more_than_a_part_holds_is_refused_unread(tmp_path, monkeypatch):
    """612 KB of compressed spaces unpacked to 600 MB, read in 1.4 GB; with the bound made small here."""
    from deltaslice import mesh

    monkeypatch.setattr(mesh, "MAX_3MF_UNPACKED", 1 << 20)
    path = tmp_path / "bomb.3mf"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("3D/3dmodel.model", "<model><!--" + " " * (2 << 20) + "--></model>")
    assert path.stat().st_size < 20_000
    line = one_line_error(_run(path, "--printer", "delta_etitc", "-o", tmp_path / "o.dsl"))
    assert "its parts unpack to 2 MiB, more than the 1 MiB" in line


def _png_file(tmp_path):
    path = tmp_path / "a.png"
    path.write_bytes(_png())
    return path


@pytest.mark.parametrize("call, words", [
    (lambda d: ("compile", _png_file(d), LASER, dict(engrave="x")), "engraving options = 'x': expected a dict"),
    (lambda d: ("compile", _png_file(d), LASER, dict(engrave={"widht": 1})), "unknown engraving option 'widht' (did you mean 'width'?)"),
    (lambda d: ("compile", _png_file(d), LASER, dict(engrave={"width": "x"})), "engraving option width = 'x': expected a number"),
    (lambda d: ("compile", _png_file(d), LASER, dict(engrave={"dither": "x"})), "engraving option dither = 'x': expected True or False"),
    (lambda d: ("compile", d / "a.gcode", "delta_etitc", dict(center="y")), "center = 'y': expected True or False"),
    (lambda d: ("decode", None, None, dict(out=None)), "out = None: expected a text file object"),
    (lambda d: ("decode", None, None, dict(units="x")), "units = 'x': expected True or False"),
    (lambda d: ("preview", d / "a.gcode", "delta_etitc", dict(layer="x")), "layer = 'x': expected a layer index"),
])
def test_the_library_refuses_arguments_of_the_wrong_kind_in_the_family(tmp_path, call, words):
    """Each raised a raw TypeError, AttributeError or numpy UFuncTypeError."""
    import io

    from deltaslice import DeltasliceError, pipeline

    (tmp_path / "a.gcode").write_text(SQUARE)
    stream_path = tmp_path / "s.dsl"
    stream_path.write_bytes(hostile_stream(blocks=2, n=4))
    what, part, printer_name, kwargs = call(tmp_path)
    with pytest.raises(DeltasliceError, match=re.escape(words)):
        if what == "compile":
            pipeline.compile_part(part, printer_name, output=tmp_path / "o.dsl", **kwargs)
        elif what == "decode":
            pipeline.decode_stream(stream_path, **{"out": io.StringIO(), **kwargs})
        else:
            pipeline.preview(part, printer_name, tmp_path / "p.png", **kwargs)
