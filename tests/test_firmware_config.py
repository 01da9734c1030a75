"""The firmware players' configuration header: the committed ``examples/firmware/config/*.h``
equal what ``deltaslice firmware-config`` writes now (regenerate with
``for p in delta_espe_laser delta_etitc delta_uady delta_ucb fivebar_atlas linear_kossel; do
deltaslice firmware-config --printer $p -o examples/firmware/config/$p.h; done``), and the
UCB's potentiometer table reaches the header in counts."""

from __future__ import annotations

import re

import numpy as np
import pytest
from trajectories import ROOT

from deltaslice import load_printer
from deltaslice.errors import PrinterFileError
from deltaslice.machine.printer import Printer
from deltaslice.pipeline import write_firmware_config

CONFIG = ROOT / "examples" / "firmware" / "config"


@pytest.mark.parametrize("name", [p.stem for p in sorted((ROOT / "deltaslice" / "printers").glob("*.toml"))])
def test_committed_header_is_current(name):
    assert (CONFIG / f"{name}.h").read_text() == write_firmware_config(name)


def test_ucb_table_in_counts():
    p = load_printer("delta_ucb")
    text = write_firmware_config(p)
    assert "#define DSL_CFG_SENSOR_POINTS 2" in text
    assert "#define DSL_CFG_SENSOR_ADC {{1790, 3200}, {1810, 3160}, {2000, 3160}}" in text
    cpd = 3200 / 360  # microsteps per degree
    assert f"{{{{{round(90 * cpd)}, 0}}" in text
    assert np.allclose(np.degrees(p.joint_from_sensor(0, [3200, 1790, 2495])), [0, 90, 45])
    assert np.allclose(np.degrees(p.joint_from_sensor(2, [2000 - 116])), [90 + 116 * 90 / 1160])  # extrapolated
    fp = re.search(r"DSL_CFG_FINGERPRINT 0x([0-9A-F]{8})UL", text).group(1)
    assert int(fp, 16) == p.fingerprint()


@pytest.mark.parametrize("table, why", [
    ([[[3200, 0.0]], [[3160, 0.0], [1810, 90.0]], [[3160, 0.0], [2000, 90.0]]], "joint 1"),
    ([[[3200, 0.0], [3200, 90.0]], [[3160, 0.0], [1810, 90.0]], [[3160, 0.0], [2000, 90.0]]], "distinct"),
    ([[[3200, 0.0], [1790, 90.0]]], "a list of 3 tables"),
])
def test_bad_sensor_table_named(table, why):
    # given as an override, the problem is named as the override's (--set joints.sensor_table)
    with pytest.raises(PrinterFileError, match=r"--set joints\.sensor_table = .*" + why):
        load_printer("delta_ucb", {"joints.sensor_table": table})


def test_joint_without_sensor_refused():
    with pytest.raises(ValueError, match="no sensor_table"):
        Printer.joint_from_sensor(load_printer("delta_etitc"), 0, [1000])


def test_ucb_potentiometers_to_counts_end_to_end(tmp_path):
    """Printer file -> dsl_config.h -> the firmware's integer interpolation (dsl_sensor.h, built
    with the committed config/delta_ucb.h) -> the same counts as Printer.joint_from_sensor."""
    import os
    import shutil
    import subprocess

    if not shutil.which("make") or not (shutil.which("cc") or shutil.which("gcc")):
        if os.environ.get("CI"):
            pytest.fail("no C compiler or make under CI")
        pytest.skip("no C compiler or make")
    r = subprocess.run(["make", "-C", str(ROOT / "examples" / "firmware"), f"BUILD={tmp_path}", f"{tmp_path}/sensor_check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    p = load_printer("delta_ucb")
    rng = np.random.default_rng(7)
    readings = np.vstack([[3200, 3160, 3160], [1790, 1810, 2000], rng.integers(1500, 3400, size=(40, 3))])
    cpu, zero = p.limits.counts_per_unit[:3], p.limits.zero_count[:3]
    rest = np.rint(zero + cpu * p.rest_pose)
    for row in readings:
        out = subprocess.run([str(tmp_path / "sensor_check"), *map(str, row)], capture_output=True, text=True, check=True)
        got = np.array([[int(x) for x in ln.split()] for ln in out.stdout.splitlines()])
        expect = np.array([zero[j] + cpu[j] * p.joint_from_sensor(j, [row[j]])[0] for j in range(3)])
        assert np.all(np.abs(got[:, 2] - expect) <= 0.5 + 1e-9), (row, got[:, 2], expect)
        assert np.array_equal(got[:, 3], rest - got[:, 2])  # the steps to the rest pose
    # the document's calibration points: 0 deg and 90 deg exactly
    first = subprocess.run([str(tmp_path / "sensor_check"), "1790", "1810", "2000"], capture_output=True, text=True)
    assert [int(ln.split()[2]) for ln in first.stdout.splitlines()] == [800, 800, 800]


def test_safety_settings_reach_the_header():
    # Marlin 2.1's defaults (HEATER_0_MAXTEMP 275, THERMAL_PROTECTION_PERIOD 40 / HYSTERESIS 4, ...)
    text = write_firmware_config("fivebar_atlas")
    for line in ("DSL_CFG_HEATER_MIN_X10 {50, 50}", "DSL_CFG_HEATER_MAX_X10 {2750, 1500}",
                 "DSL_CFG_HEATING_PERIOD_DS {400, 600}", "DSL_CFG_HOLD_PERIOD_DS {400, 200}",
                 "DSL_CFG_HOLD_DROP_X10 {40, 20}", "DSL_CFG_HOST_TIMEOUT_DS 50"):
        assert f"#define {line}" in text
    p = load_printer("fivebar_atlas", {"safety.host_timeout": 8, "safety.bed_hold_drop": 3.5})
    text = write_firmware_config(p)
    assert "#define DSL_CFG_HOST_TIMEOUT_DS 80" in text and "#define DSL_CFG_HOLD_DROP_X10 {40, 35}" in text


@pytest.mark.parametrize("overrides, why", [
    ({"safety.hotend_max_temp": 210}, r"safety\.hotend_max_temp = 210.*hotend_temperature \+ 15 C = 215 C"),
    ({"safety.bed_min_temp": 90, "safety.bed_max_temp": 80}, r"safety\.bed_min_temp = 90.*below bed_max_temp = 80 C"),
    ({"safety.host_timeout": 0.5}, r"safety\.host_timeout = 0\.5.*>= 1"),
    ({"safety.hotend_hold_drop": 0}, r"safety\.hotend_hold_drop = 0.*> 0"),
])
def test_bad_safety_setting_named(overrides, why):
    with pytest.raises(PrinterFileError, match=why):
        load_printer("fivebar_atlas", overrides)


def test_homing_and_limits_reach_the_header():
    text = write_firmware_config("linear_kossel")
    # top end stops at 480 mm x 80 counts/mm, approached at 30 mm/s (2400 steps/s: 417 us)
    for line in ("DSL_CFG_HOME_DIR {1, 1, 1}", "DSL_CFG_HOME_COUNTS {38400, 38400, 38400}",
                 "DSL_CFG_HOME_STEP_US {417, 417, 417}", "DSL_CFG_RAMP_MS 200"):
        assert f"#define {line}" in text
    assert "#define DSL_CFG_HOME_DIR {0, 0, 0}" in write_firmware_config("delta_etitc")
    with pytest.raises(PrinterFileError, match=r"homing\.endstop_position = .*within the joint limits"):
        load_printer("linear_kossel", {"homing.endstop_position": 500})
    with pytest.raises(PrinterFileError, match=r"homing\.speed = .*at most \[joints\] velocity_max"):
        load_printer("linear_kossel", {"homing.speed": 400})
