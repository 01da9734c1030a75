"""Real G-code from real slicers: parts built here, sliced by Slic3r 1.3 and PrusaSlicer (skipped
with a message when they are not installed: ``apt-get install slic3r prusa-slicer``; under CI,
env CI set, they fail instead: .ci/run installs them), read,
compiled and round-tripped. Nothing generated is kept."""

from __future__ import annotations

import os
import re
import shutil
import subprocess

import numpy as np
import pytest
from conftest import printer

from deltaslice.pipeline import read_output
from deltaslice.errors import UnreachableError
from deltaslice.gcode import read_gcode
from deltaslice.pipeline import write_gcode
from deltaslice.pipeline import compile_part
from deltaslice.toolpath import Role

SIDE = 12.0


def _need(binary: str):
    """The slicer's executable; a skip where it is missing, a failure under CI (env CI set, as
    .ci/run sets it), where .ci/run installs it and a skip would hide a broken set-up."""
    exe = shutil.which(binary)
    if exe is None:
        if os.environ.get("CI"):
            pytest.fail(f"{binary} missing under CI: .ci/run installs the Debian packages (slic3r prusa-slicer)")
        pytest.skip(f"{binary} is not installed (apt-get install -y slic3r prusa-slicer): real-slicer test skipped")
    return exe


def test_a_missing_slicer_skips_but_fails_under_ci(monkeypatch):
    def outcome(binary):
        try:
            _need(binary)
        except (pytest.skip.Exception, pytest.fail.Exception) as exc:  # caught here: a skip must not skip this test
            return type(exc) is pytest.fail.Exception, str(exc)
        return None

    monkeypatch.setattr(shutil, "which", lambda _name: None)
    monkeypatch.delenv("CI", raising=False)
    failed, msg = outcome("slic3r")
    assert not failed and "not installed" in msg
    monkeypatch.setenv("CI", "true")
    failed, msg = outcome("prusa-slicer")
    assert failed and "missing under CI" in msg


@pytest.fixture(scope="module")
def part(tmp_path_factory):
    import trimesh

    box = trimesh.creation.box((SIDE, SIDE, 0.7))
    box.apply_translation((0, 0, 0.35))
    path = tmp_path_factory.mktemp("part") / "plate.stl"
    box.export(path)
    return path


def _slice(cmd, out):
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0 and out.exists(), f"{cmd[0]} failed: {res.stdout[-500:]} {res.stderr[-500:]}"
    return out


@pytest.fixture(scope="module")
def slic3r_no_extrusion(part):
    exe = _need("slic3r")
    out = part.with_name("plate_s3.gcode")
    return _slice([exe, "--no-gui", "--gcode-flavor", "no-extrusion", str(part), "-o", str(out)], out)


@pytest.fixture(scope="module")
def prusa_defaults(part):
    exe = _need("prusa-slicer")
    out = part.with_name("plate_ps.gcode")
    return _slice([exe, "--export-gcode", str(part), "-o", str(out)], out)


def test_slic3r_no_extrusion_prints_the_whole_outline_on_etitc(slic3r_no_extrusion, tmp_path):
    text = slic3r_no_extrusion.read_text()
    bare = [ln for ln in text.splitlines() if ln.startswith("G1 X") and not ln.split(";")[0].rstrip().split()[-1][0].isalpha()]
    assert bare, "Slic3r no longer writes the no-extrusion quirk"
    etitc = printer("delta_etitc")
    notes = []
    tp = read_gcode(slic3r_no_extrusion, printer=etitc, echo=notes.append, center=True)
    assert any("no-extrusion" in n for n in notes)
    assert tp.working.sum() == len(bare)
    assert (tp.e[tp.working] > 0).all()
    # retractions and unretractions of the file's own length: Slic3r resets its register after each
    # retraction without a G92, so the first unretract is not 4 mm after a 2 mm retraction
    length = float(re.search(r"^; retract_length = ([\d.]+)", text, re.M).group(1))
    moves = tp.e[tp.role == Role.RETRACT]
    assert length > 0 and len(moves) >= 4
    assert np.allclose(np.abs(moves), length) and np.allclose(moves[::2], -length)
    assert np.cumsum(moves).max() <= 1e-9 and np.cumsum(moves).min() >= -length - 1e-9
    out = tmp_path / "s3.csv"
    compile_part(slic3r_no_extrusion, etitc, output=str(out), center=True, workers=1)
    _meta, s = read_output(out)
    on = s.tool > 0
    assert on.mean() > 0.3 and np.all(np.diff(s.e[on]) >= -1e-9)
    p = etitc.kinematics().forward(s.q[on])
    # the whole footprint is printed (the skirt's extent, as in the file) ...
    w = tp.working
    pts = np.concatenate([tp.starts[w], tp.xyz[w]])[:, :2]
    assert np.allclose(p[:, :2].min(axis=0), pts.min(axis=0), atol=0.05)
    assert np.allclose(p[:, :2].max(axis=0), pts.max(axis=0), atol=0.05)
    # ... and the plate's outline: the extruding tool runs along every side, just inside the edge
    half = SIDE / 2
    for axis in (0, 1):
        along = np.abs(p[:, 1 - axis]) < half - 1
        for sign in (-1, 1):
            edge = along & (np.abs(p[:, axis] - sign * half) < 0.5)
            assert np.ptp(p[edge, 1 - axis]) > SIDE - 3, f"side {sign:+d} of axis {axis} not printed"


def test_prusaslicer_defaults_filament_warning_and_centring(prusa_defaults, tmp_path):
    etitc = printer("delta_etitc")
    notes = []
    tp = read_gcode(prusa_defaults, printer=etitc, echo=notes.append)
    assert any("1.75 mm filament" in n and "rescaled" in n for n in notes)
    assert any("--center" in n for n in notes)
    with pytest.raises(UnreachableError, match="would fit centred on the bed: use --center"):
        compile_part(prusa_defaults, etitc, output=str(tmp_path / "x.csv"), workers=1)
    raw = read_gcode(prusa_defaults)  # no printer: E as written
    assert tp.e[tp.working].sum() == pytest.approx(raw.e[raw.working].sum() * (1.75 / 3.0) ** 2, rel=1e-9)
    # retractions keep their length (PrusaSlicer's retract_length), not rescaled as a volume
    length = float(re.search(r"^; retract_length = ([\d.]+)", prusa_defaults.read_text(), re.M).group(1))
    standing = tp.role == Role.RETRACT
    assert length > 0 and standing.sum() >= 4 and np.array_equal(tp.e[standing], raw.e[standing])
    assert np.allclose(np.abs(tp.e[standing]), length)
    assert any("kept at their length" in n for n in notes)
    # hot-end temperatures reach the CSV and the stream
    temps = [float(ln.split("S")[1].split()[0]) for ln in prusa_defaults.read_text().splitlines()
             if ln.startswith(("M104 S", "M109 S"))]
    for name in ("ps.csv", "ps.dsl"):
        out = tmp_path / name
        compile_part(prusa_defaults, etitc, output=str(out), center=True, workers=1)
        meta, s = read_output(out)
        got = [v for _i, k, v in meta["events"] if k in (1, 2)]
        assert got == temps + [0.0] and temps[0] > 150  # and every job's end sets the hot end to 0
        wait = [i for i, k, _v in meta["events"] if k == 2][0]
        assert wait < len(s) // 2  # the wait comes before the print, not at the end


def test_prusaslicer_output_round_trips(prusa_defaults, tmp_path):
    tp = read_gcode(prusa_defaults)
    write_gcode(tp, tmp_path / "back.gcode")
    back = read_gcode(tmp_path / "back.gcode")
    assert back.equals(tp) and np.array_equal(back.role, tp.role)


def test_grbl_laser_job_fires_the_laser(tmp_path):
    laser = printer("delta_espe_laser")
    lines = ["G21 G90", "M3 S0", "G0 X-15 Y-15 F3000"]
    for k, y in enumerate(np.linspace(-15, 15, 7)):
        x0, x1 = (-15, 15) if k % 2 == 0 else (15, -15)
        lines += [f"G0 X{x0} Y{y:.3f}", f"G1 X{x1} Y{y:.3f} S{300 + 100 * k} F1200"]
    lines += ["M5", "G0 X0 Y0"]
    job = tmp_path / "engrave.nc"
    job.write_text("\n".join(lines) + "\n")
    out = tmp_path / "engrave.csv"
    compile_part(job, laser, output=str(out), workers=1)
    meta, s = read_output(out)
    on = s.tool > 0
    assert on.mean() > 0.2
    # M3: constant power, S / s_max
    assert set(np.round(s.tool[on], 6)) == {round((300 + 100 * k) / 1000, 6) for k in range(7)}
    # M4: GRBL's dynamic power, S / s_max scaled by the tool speed over the feed: never above the
    # line's power, at it on the lines' constant-speed middles
    job.write_text(job.read_text().replace("M3 S0", "M4 S0"))
    compile_part(job, laser, output=str(out), workers=1)
    _meta, d = read_output(out)
    on = d.tool > 0
    assert d.tool.max() == pytest.approx(0.9, abs=1e-6) and (d.tool <= 0.9 + 1e-9).all()
    assert len(set(np.round(d.tool[on], 6))) > 7
    # laser mode M3, then M5, then every job's end: laser mode 0 and the fan off
    assert [(k, v) for _i, k, v in meta["events"]] == [(6, 3.0), (6, 0.0), (6, 0.0), (5, 0.0)]
