"""verify: a valid trajectory passes; damaged ones are caught, with the right kind and place."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from trajectories import ROOT, blocks, printer, realistic

from deltaslice.cli import main
from deltaslice.machine import load_printer, printer_from_dict
from deltaslice.pipeline import read_output, write_samples
from deltaslice.samples import Samples
from deltaslice.pipeline import verify_output
from deltaslice.verify import MARGIN, verify_samples


@pytest.fixture(scope="module")
def good():
    s, tp = realistic("delta_etitc", layers=1)
    return printer("delta_etitc"), s, tp


def _write(tmp_path, p, s, fmt, name="x"):
    path = tmp_path / f"{name}.{'dsl' if fmt == 'stream' else 'csv'}"
    write_samples(blocks(s), p, path, fmt=fmt, rate=p.planning.output_rate, metadata={"planner": "synthetic"})
    return path


def kinds(report):
    return {v.kind for v in report.violations}


@pytest.mark.parametrize("fmt", ["csv", "stream"])
def test_valid_trajectory_passes(good, tmp_path, fmt):
    p, s, tp = good
    path = _write(tmp_path, p, s, fmt)
    rep = verify_output(path, p)
    assert rep.ok, rep.text()
    assert rep.n_samples == len(s) and rep.format == fmt
    meta, back = read_output(path)
    rep = verify_samples(back, p, rate=1000.0, fmt=fmt, meta=meta, toolpath=tp)
    assert rep.ok, rep.text()
    assert rep.max_deviation is not None and rep.max_deviation <= rep.deviation_tolerance
    text = rep.text()
    assert "OK" in text and "path deviation" in text and "q1/theta1" in text
    if fmt == "stream":
        # windows from the quantisation step: 1/636.6 rad per count
        assert all(c.acceleration_window > 10 for c in rep.channels)
        assert rep.max_deviation > 0.01
    else:
        assert all(c.velocity_window == 1 and c.acceleration_window == 1 for c in rep.channels)
        assert rep.max_deviation < 1e-3


@pytest.mark.parametrize("name", ["linear_kossel", "fivebar_atlas", "delta_espe_laser"])
def test_valid_trajectory_passes_other_machines(name, tmp_path):
    p = printer(name)
    s, tp = realistic(name, layers=1)
    for fmt in ("csv", "stream"):
        meta, back = read_output(_write(tmp_path, p, s, fmt))
        rep = verify_samples(back, p, rate=p.planning.output_rate, fmt=fmt, meta=meta, toolpath=tp)
        assert rep.ok, rep.text()


def test_one_sample_moved(good, tmp_path):
    p, s, tp = good
    i = 12000
    q = s.q.copy()
    q[i, 0] += 0.03  # 1.7 deg, 19 servo counts: a glitch of ~2 mm at the tool
    bad = Samples(s.t, q, s.e, s.tool)
    rep = verify_output(_write(tmp_path, p, bad, "csv"), p)
    assert not rep.ok and "acceleration" in kinds(rep)
    acc = [v for v in rep.violations if v.kind == "acceleration"]
    assert all(v.channel.startswith("q1") and abs(v.index - i) <= 1 for v in acc)
    assert "FAIL" in rep.text() and f"sample {acc[0].index}" in rep.text()
    # the path check sees it in either format, quantised or not
    for fmt in ("csv", "stream"):
        meta, back = read_output(_write(tmp_path, p, bad, fmt, "dev"))
        rep = verify_samples(back, p, rate=1000.0, fmt=fmt, meta=meta, toolpath=tp)
        dev = [v for v in rep.violations if v.kind == "deviation"]
        assert dev and dev[0].index == i and dev[0].value > 1.0, rep.text()


def test_squeezed_time_step(good, tmp_path):
    p, s, _ = good
    i = 5000
    t = s.t.copy()
    t[i:] -= 0.0004  # one step of 0.6 ms instead of 1 ms
    rep = verify_output(_write(tmp_path, p, Samples(t, s.q, s.e, s.tool), "csv"), p)
    steps = [v for v in rep.violations if v.kind == "time_step"]
    assert len(steps) == 1 and steps[0].index == i and abs(steps[0].value - 0.0006) < 1e-8, rep.text()


@pytest.mark.parametrize("fmt", ["csv", "stream"])
def test_time_compression_exceeds_velocity(good, tmp_path, fmt):
    p, s, _ = good
    k = 20  # play the same motion 20 times faster: joint speeds x20 (~120 % of the limit), accelerations x400
    q = s.q[::k]
    n = len(q)
    fast = Samples(np.arange(n) / 1000.0, q, s.e[::k], s.tool[::k])
    rep = verify_output(_write(tmp_path, p, fast, fmt), p)
    assert "velocity" in kinds(rep), rep.text()
    if fmt == "csv":
        assert "acceleration" in kinds(rep), rep.text()
    # (the stream's 33 ms acceleration window averages the compressed motion's short bursts: windowed
    # differences are lower bounds of the peaks; velocities still show it)
    vmax = p.joints[0].velocity_max
    assert max(abs(v.value) for v in rep.violations if v.kind == "velocity") > vmax * (1 + MARGIN)


def test_uniformly_faster_but_within_limits_passes(good, tmp_path):
    p, s, _ = good
    q = s.q[::2]  # twice as fast: 12 % of the velocity limit, ~80 % of the acceleration limit
    n = len(q)
    rep = verify_output(_write(tmp_path, p, Samples(np.arange(n) / 1000.0, q, s.e[::2] * 0.5, s.tool[::2]), "csv"), p)
    assert rep.ok, rep.text()


@pytest.mark.parametrize("fmt", ["csv", "stream"])
def test_position_beyond_joint_limit(good, tmp_path, fmt):
    p, s, _ = good
    j, hi = 1, p.joints[1].position_max
    q = s.q.copy()
    i0, i1 = 8000, 10000  # a smooth 2 s excursion 0.03 rad past the limit
    bump = np.sin(np.linspace(0, np.pi, i1 - i0)) ** 2
    q[i0:i1, j] += bump * (hi + 0.03 - q[i0:i1, j].max())
    rep = verify_output(_write(tmp_path, p, Samples(s.t, q, s.e, s.tool), fmt), p)
    assert kinds(rep) == {"position"}, rep.text()
    v = rep.violations[0]
    assert v.channel.startswith("q2") and i0 < v.index < i1 and v.value > hi and v.limit == hi


def test_filament_too_fast_and_laser_power(good, tmp_path):
    p, s, _ = good
    e = s.e.copy()
    e[15000:] += np.clip(np.arange(len(e) - 15000) / 1000.0, 0, 1) * 2.0  # +2 mm/s for a second while extruding
    rep = verify_output(_write(tmp_path, p, Samples(s.t, s.q, e, s.tool), "csv"), p)
    assert "filament_speed" in kinds(rep), rep.text()

    pl = printer("delta_espe_laser")
    sl, _ = realistic("delta_espe_laser", layers=1)
    tool = sl.tool.copy()
    tool[3000:3100] = 1.3
    for fmt in ("csv", "stream"):
        rep = verify_output(_write(tmp_path, pl, Samples(sl.t, sl.q, sl.e, tool), fmt, "laser"), pl)
        assert kinds(rep) == {"laser_power"}, rep.text()


def test_other_printer_is_a_violation(good, tmp_path):
    p, s, _ = good
    path = _write(tmp_path, p, s, "csv")
    rep = verify_output(path, ROOT / "printers" / "delta_uady.toml")
    assert "fingerprint" in kinds(rep)


def test_cli_exit_status(good, tmp_path):
    p, s, _ = good
    ok = _write(tmp_path, p, s, "stream", "ok")
    q = s.q.copy()
    q[4000, 2] += 0.05
    bad = _write(tmp_path, p, Samples(s.t, q, s.e, s.tool), "csv", "bad")
    runner = CliRunner()
    printer_file = str(ROOT / "printers" / "delta_etitc.toml")
    r = runner.invoke(main, ["verify", str(ok), "--printer", printer_file])
    assert r.exit_code == 0 and "OK" in r.output
    r = runner.invoke(main, ["verify", str(bad), "--printer", printer_file])
    assert r.exit_code == 3 and "FAIL" in r.output and "acceleration q3" in r.output
    r = runner.invoke(main, ["verify", str(tmp_path / "missing.csv"), "--printer", printer_file])
    assert r.exit_code == 1 and "error:" in r.output


def test_verify_against_gcode(good, tmp_path):
    p, s, tp = good
    lines = ["G21", "G90", "M82", "G92 E0", f"G0 X{tp.start[0]:.4f} Y{tp.start[1]:.4f} Z{tp.start[2]:.4f} F7800"]
    e = 0.0
    for xyz, feed, de, tool in zip(tp.xyz, tp.feed, tp.e, tp.tool):
        e += de
        word = "G1" if tool > 0 else "G0"
        lines.append(f"{word} X{xyz[0]:.4f} Y{xyz[1]:.4f} Z{xyz[2]:.4f}" + (f" E{e:.5f}" if tool > 0 else "") + f" F{feed * 60:.0f}")
    gcode = tmp_path / "part.gcode"
    gcode.write_text("\n".join(lines) + "\n")
    rep = verify_output(_write(tmp_path, p, s, "stream"), p, toolpath=gcode)
    assert rep.max_deviation is not None and rep.ok, rep.text()


def test_the_limits_own_the_sampled_thresholds():
    """Limits.sampled_check and sampled_tool_velocity: the windows, thresholds and working-or-idle
    limit verify holds samples to (verify's output is unchanged by their move into machine/)."""
    from deltaslice.machine.limits import TOLERANCE, acceleration_window, velocity_window

    p = printer("delta_etitc")
    lim = p.limits
    res, rate = 1.0 / abs(lim.counts_per_unit[0]), 1000.0
    check = lim.sampled_check(0, res, rate)
    wv, nv = velocity_window(lim.velocity[0], res, rate, 0.05)
    wa, na = acceleration_window(lim.acceleration[0], res, rate, 0.05)
    assert (check.velocity_window, check.acceleration_window) == (wv, wa)
    assert check.velocity_threshold() == pytest.approx(lim.velocity[0] * (1 + TOLERANCE) + nv)
    assert check.acceleration_threshold() == pytest.approx(lim.acceleration[0] * (1 + TOLERANCE) + na)
    working, idle = lim.tool_velocity_limits()
    assert (working, idle) == (lim.velocity[-1], lim.idle_velocity[-1]) and idle > working
    assert lim.sampled_tool_velocity(None, 0.01, rate) == (idle, None)  # a stream: no tool state
    tool = np.r_[np.ones(500), np.zeros(100), np.ones(500)]
    vmax, per_window = lim.sampled_tool_velocity(tool, 1e-10, rate)
    assert vmax == working and len(per_window) == len(tool) - 1
    assert per_window[0] == working and per_window[500] == idle and per_window[-1] == working


def test_torque_use_is_reported_not_enforced(good, tmp_path):
    """With a [dynamics] table, one INFO row per joint (its peak model torque against its stall
    torque) and a note; a plan over stall still verifies (the planner does not plan to torque yet);
    without the table, no torque rows."""
    p, s, tp = good
    meta, back = read_output(_write(tmp_path, p, s, "csv"))
    heavy = load_printer(p.path, {"dynamics.tool_mass": 50.0})  # 50 kg: far over the servos' stall
    rep = verify_samples(back, heavy, rate=1000.0, fmt="csv", meta=meta)
    rows = [r for r in rep.rows if r.check == "torque (model)"]
    assert [r.channel for r in rows] == ["q1/theta1", "q2/theta2", "q3/theta3"]
    assert all(r.informational and r.unit == "N m" and r.percent > 100 for r in rows)
    assert rep.ok and "INFO" in rep.text() and any("torque (model)" in n for n in rep.notes)
    light = verify_samples(back, p, rate=1000.0, fmt="csv", meta=meta)
    assert max(r.peak for r in light.rows if r.check == "torque (model)") < min(r.peak for r in rows)
    data = tomllib.loads(Path(p.path).read_text())
    del data["dynamics"]
    bare = printer_from_dict(data, p.path)
    assert not [r for r in verify_samples(back, bare, rate=1000.0, fmt="csv", meta=meta).rows if r.check == "torque (model)"]
