"""Printer files: the six shipped ones load and source every number; every kind of
bad file is refused with a message naming the file, the [section] key and the
bound; the CLI turns that into one `error:` line, never a traceback."""

from __future__ import annotations

import math
import re
import subprocess
import sys
import tomllib

import numpy as np
import pytest
from click.testing import CliRunner

from deltaslice.cli import main
from deltaslice.errors import PrinterFileError
from deltaslice.kinematics.five_bar import FiveBarGeometry
from deltaslice.kinematics.linear_delta import LinearDeltaGeometry
from deltaslice.kinematics.rotary_delta import RotaryDeltaGeometry
from deltaslice.machine import Extruder, Laser, load_printer

from conftest import PRINTER_DIR, PRINTER_NAMES, printer

GOOD = PRINTER_DIR / "delta_etitc.toml"


def test_six_printers_ship():
    assert PRINTER_NAMES == [
        "delta_espe_laser",
        "delta_etitc",
        "delta_uady",
        "delta_ucb",
        "fivebar_atlas",
        "linear_kossel",
    ]


@pytest.mark.parametrize("name", PRINTER_NAMES)
def test_shipped_printer_loads(name):
    p = printer(name)
    assert p.name == name
    assert p.n_joints == len(p.joints) == 3
    for j in p.joints:
        assert j.position_min < j.position_max and j.velocity_max > 0 and j.acceleration_max > 0
    kinds = {
        "rotary_delta": RotaryDeltaGeometry,
        "linear_delta": LinearDeltaGeometry,
        "five_bar": FiveBarGeometry,
    }
    assert isinstance(p.geometry, kinds[p.family])
    assert isinstance(p.tool, Laser if name == "delta_espe_laser" else Extruder)


def test_units_are_converted_at_the_edge():
    p = printer("delta_etitc")
    j = p.joints[0]
    assert j.unit == "rad"
    assert j.position_min == pytest.approx(math.radians(-45.0))
    assert j.velocity_max == pytest.approx(math.radians(300.0))
    assert j.counts_per_unit == pytest.approx(11.111 / math.radians(1.0))
    assert p.geometry.ball_joint_tilt_max == pytest.approx(math.radians(13.0))
    assert printer("linear_kossel").joints[0].unit == "mm"


def _numeric_leaves(data, prefix=""):
    """Dotted keys of every number (or list of numbers) outside [sources]."""
    for key, value in data.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, dict):
            if dotted != "sources":
                yield from _numeric_leaves(value, dotted + ".")
        elif isinstance(value, bool):
            continue
        elif isinstance(value, (int, float)) or (isinstance(value, list) and value and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        )):
            yield dotted


@pytest.mark.parametrize("name", PRINTER_NAMES)
def test_every_number_has_a_source(name):
    data = tomllib.loads((PRINTER_DIR / f"{name}.toml").read_text())
    sources = data["sources"]
    leaves = list(_numeric_leaves(data))
    assert len(leaves) >= 25
    missing = [k for k in leaves if k not in sources]
    assert not missing, f"{name}: numbers with no [sources] entry: {missing}"
    # No stale entries, and an "assumed" number always says why.
    all_keys = {f"{s}.{k}" for s, t in data.items() if isinstance(t, dict) for k in t} | set(data)
    assert not [k for k in sources if k not in all_keys], "sources for keys that do not exist"
    for key, text in sources.items():
        if text.lower().startswith("assumed"):
            assert re.match(r"assumed: \S.{8,}", text), f"{name}: {key}: an assumption needs its reason"


# --------------------------------------------------------------------------- bad files


def _bad_file(tmp_path, edit):
    text = GOOD.read_text()
    new = edit(text)
    assert new != text, "the edit did not apply"
    path = tmp_path / "bad.toml"
    path.write_text(new)
    return path


def _sub(old, new):
    return lambda text: text.replace(old, new, 1)


BAD = {
    # name: (edit, the key the message must name, the bound it must state)
    "missing key": (_sub("upper_arm = 176.0\n", ""), "[kinematics] upper_arm", "required key"),
    "string for a number": (_sub("upper_arm = 176.0", 'upper_arm = "176"'), "[kinematics] upper_arm", "a number"),
    "negative length": (_sub("forearm = 360.0", "forearm = -360.0"), "[kinematics] forearm", "> 0"),
    "position_min >= position_max": (
        _sub("position_min = -45.0", "position_min = 95.0"),
        "[joints] position_min",
        "position_min < position_max",
    ),
    "unknown key (typo)": (
        _sub("tool_offset = 40.0", "tool_offset = 40.0\nshoulder_hieght = 527.0"),
        "[kinematics] unknown key 'shoulder_hieght'",
        "expected one of",
    ),
    "unknown family": (_sub('family = "rotary_delta"', 'family = "scara"'), "[kinematics] family", "one of cartesian, five_bar, linear_delta, rotary_delta"),
    "bad TOML syntax": (_sub("upper_arm = 176.0", "upper_arm = 176.0.0"), "not valid TOML", "line"),
    "wrong list length": (
        _sub("velocity_max = 300.0", "velocity_max = [300.0, 300.0]"),
        "[joints] velocity_max",
        "a list of 3 numbers",
    ),
    "geometry reaches nothing": (
        _sub("shoulder_height = 527.0", "shoulder_height = 5000.0"),
        "[kinematics]",
        "max_height = 120",
    ),
    "missing section": (lambda t: t.replace("[bed]", "[bedd]", 1), "unknown key 'bedd'", "did you mean 'bed'"),
    "zero count scale": (_sub("counts_per_unit = 11.111", "counts_per_unit = 0"), "[joints] counts_per_unit", "non-zero"),
    # 1e-300 passed "> 0" and its cross-section underflowed to zero: a ZeroDivisionError (hypothesis)
    "tiny filament": (_sub("filament_diameter = 3.0", "filament_diameter = 1e-300"), "[tool] filament_diameter", ">= 0.1"),
    "tilt over 90": (_sub("ball_joint_tilt_max = 13.0", "ball_joint_tilt_max = 100.0"), "[kinematics] ball_joint_tilt_max", "<= 90"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_file_message_names_file_key_and_bound(tmp_path, case):
    edit, key, bound = BAD[case]
    path = _bad_file(tmp_path, edit)
    with pytest.raises(PrinterFileError) as err:
        load_printer(path)
    msg = str(err.value)
    assert msg.startswith(str(path) + ":")
    assert key in msg, msg
    assert bound in msg, msg
    assert "\n" not in msg.strip() or case == "bad TOML syntax"


def test_bad_values_are_shown(tmp_path):
    with pytest.raises(PrinterFileError, match=r"forearm = -360\.0: expected a number > 0"):
        load_printer(_bad_file(tmp_path, BAD["negative length"][0]))
    with pytest.raises(PrinterFileError, match=r"upper_arm = '176': expected a number"):
        load_printer(_bad_file(tmp_path, BAD["string for a number"][0]))


def test_missing_file(tmp_path):
    path = tmp_path / "nope.toml"
    with pytest.raises(PrinterFileError, match=r"nope\.toml: no such printer file"):
        load_printer(path)


def test_every_family_checks_unknown_keys(tmp_path):
    for name in PRINTER_NAMES:
        text = (PRINTER_DIR / f"{name}.toml").read_text().replace("[joints]\n", "[joints]\nacceleration_mx = 1.0\n", 1)
        path = tmp_path / f"{name}.toml"
        path.write_text(text)
        with pytest.raises(PrinterFileError, match=r"\[joints\] unknown key 'acceleration_mx'"):
            load_printer(path)


# --------------------------------------------------------------------------- the CLI


@pytest.mark.parametrize("case", ["missing key", "bad TOML syntax", "geometry reaches nothing", "unknown family"])
def test_cli_prints_one_error_line_and_no_traceback(tmp_path, case):
    path = _bad_file(tmp_path, BAD[case][0])
    result = CliRunner().invoke(main, ["workspace", "--printer", str(path), "--plot", str(tmp_path / "ws.png")])
    assert result.exit_code == 1
    assert result.stderr.startswith("error: "), result.stderr
    assert str(path) in result.stderr
    assert "Traceback" not in result.output and result.exc_info[0] is SystemExit
    assert not (tmp_path / "ws.png").exists()


def test_cli_missing_printer_file(tmp_path):
    result = CliRunner().invoke(main, ["workspace", "--printer", str(tmp_path / "none.toml")])
    assert result.exit_code == 1
    assert result.stderr.startswith("error: ") and "no such printer file" in result.stderr


# --------------------------------------------------------------------------- reach checks after loading


@pytest.mark.parametrize("name", PRINTER_NAMES)
def test_reach_checks_done_after_loading_give_the_same_printer(name):
    """load_printer(reach_checks=False) then check_reach is load_printer: the same rest pose (bit
    for bit), fingerprint and fields; check_reach of a checked printer is that printer."""
    from deltaslice.machine import check_reach

    full = printer(name)
    later = load_printer(PRINTER_DIR / f"{name}.toml", reach_checks=False)
    assert full.reach_checked and not later.reach_checked
    checked = check_reach(later)
    assert checked.reach_checked and not later.reach_checked  # a new printer; the unchecked one stays so
    assert checked.rest_pose.tobytes() == full.rest_pose.tobytes()
    assert checked == full and checked.fingerprint() == full.fingerprint()
    assert check_reach(checked) is checked and check_reach(full) is full


def test_check_reach_sets_the_default_rest_pose(tmp_path):
    """A file without [joints] rest: the unchecked printer has no rest pose; check_reach gives the
    one load_printer gives (the highest reachable point above the bed centre)."""
    from deltaslice.machine import check_reach

    path = _bad_file(tmp_path, _sub("rest = 22.5\n", ""))
    full = load_printer(path)
    later = load_printer(path, reach_checks=False)
    assert later.rest_pose is None
    assert check_reach(later).rest_pose.tobytes() == full.rest_pose.tobytes()
    assert np.isfinite(full.rest_pose).all() and not np.allclose(full.rest_pose, math.radians(22.5))


def test_check_reach_refuses_a_geometry_that_reaches_nothing(tmp_path):
    """The check left out of an unchecked load is check_reach's, with load_printer's message."""
    from deltaslice.machine import check_reach

    path = _bad_file(tmp_path, BAD["geometry reaches nothing"][0])
    with pytest.raises(PrinterFileError) as full:
        load_printer(path)
    later = load_printer(path, reach_checks=False)
    with pytest.raises(PrinterFileError) as err:
        check_reach(later)
    assert str(err.value) == str(full.value) and "max_height = 120" in str(err.value)


def test_planning_refuses_a_printer_without_its_reach_checks():
    """Nothing plans with an unchecked printer (its rest pose may be unset): plan says what to do."""
    from deltaslice.errors import DeltasliceError
    from deltaslice.planning import plan
    from deltaslice.toolpath import Role, ToolpathBuilder

    later = load_printer(GOOD, reach_checks=False)
    b = ToolpathBuilder(start=(0.0, 0.0, 1.0))
    b.add((5.0, 0.0, 1.0), 20.0, 0.2, 1.0, Role.PERIMETER)
    tp = b.build()
    for planner in ("toppra", "trapezoid"):
        with pytest.raises(DeltasliceError, match=r"reach_checks=False.*check_reach"):
            plan(tp, later, planner=planner, workers=1)


def test_a_load_without_reach_checks_does_not_load_numba():
    """What reach_checks=False is for: the printer is read without numba imported or a kernel
    loaded (a compile's slicing workers fork before this process loads them), and check_reach is
    what loads them."""
    code = (
        "import sys\n"
        "from deltaslice import jit\n"
        "from deltaslice.machine import check_reach, load_printer\n"
        "for name in ('delta_etitc', 'linear_kossel', 'fivebar_atlas', 'delta_espe_laser'):\n"
        "    p = load_printer(name, reach_checks=False)\n"
        "assert 'numba' not in sys.modules and not jit.loaded()\n"
        "check_reach(load_printer('delta_etitc', reach_checks=False))\n"
        "assert 'numba' in sys.modules and jit.loaded()\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr[-2000:]
