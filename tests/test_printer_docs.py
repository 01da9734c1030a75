"""Printer files for people (issue 15): all problems of a file at once, unknown keys named with
the nearest valid key, the generated key reference in sync with the reader, the guide, sources
cited by title, and the numbers read again against the documents."""

from __future__ import annotations

import importlib.util
import math
import re
import tomllib

import numpy as np
import pytest

from deltaslice.errors import PrinterFileError
from deltaslice.machine import load_printer

from conftest import PRINTER_DIR, PRINTER_NAMES, ROOT, printer

ETITC_TEXT = (PRINTER_DIR / "delta_etitc.toml").read_text()


def _load_text(tmp_path, text):
    path = tmp_path / "p.toml"
    path.write_text(text)
    return load_printer(path)


def test_a_misspelt_key_is_named_with_the_valid_one(tmp_path):
    with pytest.raises(PrinterFileError) as err:
        _load_text(tmp_path, ETITC_TEXT.replace("upper_arm = 176.0", "uper_arm = 176.0"))
    msg = str(err.value)
    assert "unknown key 'uper_arm': did you mean 'upper_arm'?" in msg
    assert "upper_arm missing" not in msg and "[kinematics] upper_arm" not in msg


def test_every_problem_of_a_file_is_reported_at_once(tmp_path):
    text = (ETITC_TEXT.replace("forearm = 360.0", "forearm = -360.0")
            .replace("velocity_max = 300.0", "velocity_max = \"fast\"")
            .replace("nozzle_diameter = 0.5", "nozle_diameter = 0.5")
            .replace("infill_speed = 60.0\n", "infill_speed = 0\n", 1)
            .replace("output_rate = 1000.0", "output_rate = 10"))
    with pytest.raises(PrinterFileError) as err:
        _load_text(tmp_path, text)
    msg = str(err.value)
    assert msg.splitlines()[0].endswith("5 problems:"), msg
    for part in ("[kinematics] forearm = -360.0", "[joints] velocity_max = 'fast'", "did you mean 'nozzle_diameter'",
                 "[slicing] infill_speed = 0", "[planning] output_rate = 10"):
        assert part in msg, msg
    assert "nozzle_diameter missing" not in msg


def _docs_script(name):
    """A generator script of docs/ (not a package module) loaded by its path."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "docs" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _generator():
    return _docs_script("gen_printer_file")


def test_the_printer_file_reference_is_generated_from_the_reader():
    gen = _generator()
    assert (ROOT / "docs" / "printer-file.md").read_text() == gen.render(), (
        "docs/printer-file.md is stale: python docs/gen_printer_file.py > docs/printer-file.md")
    found = gen.collect()
    assert set(gen.DOCS) == set(found), "DOCS explains keys the reader never asks for, or misses some"
    text = gen.render()
    for name in PRINTER_NAMES:  # every key of every shipped file is in the reference
        data = tomllib.loads((PRINTER_DIR / f"{name}.toml").read_text())
        for section, table in data.items():
            if isinstance(table, dict) and section != "sources":
                for key in table:
                    assert f"| `{key}` |" in text, (name, section, key)


def _sources_generator():
    return _docs_script("gen_printers")


def test_the_printer_sources_table_is_generated_from_the_files():
    text = _sources_generator().render()
    assert (ROOT / "docs" / "printer-sources.md").read_text() == text, (
        "docs/printer-sources.md is stale: python docs/gen_printers.py > docs/printer-sources.md")


def test_the_printers_page_agrees_with_the_sources_and_cites_documents_by_title():
    """docs/printers.md (written by hand) quotes the generated counts, names no local path, and says
    what the documents do not: the ESPE servo model and the Atlas working mode are assumed."""
    page = (ROOT / "docs" / "printers.md").read_text()
    assert "/work/" not in page and "seeds" not in page and "reference/machines.md" not in page
    summary = _sources_generator().render().split("## Summary", 1)[1]
    for name, source, _derived, fitted, _chosen, assumed in re.findall(
            r"^\| (\w+) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \| (\d+) \|$", summary, re.M):
        m = re.search(rf"^- \*\*{name}\*\* \((\d+) assumed", page, re.M)
        assert m and m.group(1) == assumed, (name, assumed)
        if name == "delta_etitc":
            assert f"{source} from the thesis" in page
        if int(fitted):
            assert f"{assumed} assumed, {fitted} fitted" in page
    rows = {}  # the first table's row per printer: the summary
    for r in page.splitlines():
        if r.startswith("| delta_") or r.startswith("| fivebar"):
            rows.setdefault(r.split("|")[1].strip(), r)
    assert "AX-12 assumed" in rows["delta_espe_laser"] and "Dynamixel AX-12," not in rows["delta_espe_laser"]
    atlas = rows["fivebar_atlas"]
    assert "working mode assumed" in atlas and "paper's CODO2 = +1" in atlas and "CODO2 = -1" not in atlas


def test_the_custom_delta_guide_covers_the_rotary_delta_keys():
    guide = (ROOT / "docs" / "custom-delta.md").read_text()
    for key in ("base_radius", "platform_radius", "upper_arm", "forearm", "shoulder_height", "tool_offset",
                "ball_joint_tilt_max", "position_min", "position_max", "counts_per_unit", "zero_count", "velocity_max",
                "acceleration_max", "deltaslice workspace", "deltaslice verify", "--set"):
        assert key in guide, key


@pytest.mark.parametrize("name", PRINTER_NAMES)
def test_sources_cite_documents_by_title_not_by_a_path_users_lack(name):
    text = (PRINTER_DIR / f"{name}.toml").read_text()
    assert "../shared" not in text and "seeds/" not in text and ".txt" not in text


# ---------------------------------------------------------------------------- the numbers, read again


def test_fivebar_working_modes_are_labelled_assumed():
    src = printer("fivebar_atlas").sources
    assert src["kinematics.codo1"].startswith("assumed") and src["kinematics.codo2"].startswith("assumed")
    assert "CODO2 = +1" in src["kinematics.codo2"]


def test_etitc_first_layer_speed_and_multiplier_are_the_thesis_gcode():
    p = printer("delta_etitc")
    assert p.slicing.first_layer_speed == pytest.approx(540.0 / 60.0)
    assert "F540" in p.sources["slicing.first_layer_speed"]
    assert not p.sources["slicing.extrusion_multiplier"].startswith("assumed")
    assert "7 deg" in p.sources["kinematics.ball_joint_tilt_max"] and "Choice" in p.sources["kinematics.ball_joint_tilt_max"]


def test_ucb_bed_is_inside_the_documents_effective_workspace():
    """The hexagon (+-50, 0), (+-25, +-40) holds a disk of radius 40 (its edges at y = +-40)."""
    v = np.array([[50, 0], [25, 40], [-25, 40], [-50, 0], [-25, -40], [25, -40]], float)
    dist = []
    for a, b in zip(v, np.roll(v, -1, axis=0)):
        n = np.array([b[1] - a[1], a[0] - b[0]])
        dist.append(abs(n @ a) / np.linalg.norm(n))
    p = printer("delta_ucb")
    assert p.bed.radius <= min(dist) + 1e-9 and min(dist) == pytest.approx(40.0)
    assert "94 mm" in p.sources["kinematics.forearm"] and "follows the code" in p.sources["kinematics.forearm"]


def test_espe_servo_counts_are_labelled_assumed():
    assert printer("delta_espe_laser").sources["joints.counts_per_unit"].startswith("assumed")


def test_uady_fit_residual_is_what_the_file_says():
    """Table 1 (SolidWorks column) against the symmetric pose of the file's geometry: 0.8 mm RMS."""
    d = np.array([140, 160, 180, 200, 220, 240, 260, 280, 300, 320.0])
    th = np.radians([-29.36, -16.91, -8.01, 0.02, 7.22, 13.81, 21.13, 26.90, 34.00, 41.11])
    g = printer("delta_uady").geometry
    gap = g.base_radius - g.platform_radius + g.upper_arm * np.cos(th)
    model = g.upper_arm * np.sin(th) + np.sqrt(g.forearm**2 - gap**2)
    rms = math.sqrt(np.mean((model - d) ** 2))
    assert rms < 0.85
    assert "0.8 mm RMS" in printer("delta_uady").sources["kinematics.base_radius"]
    assert re.search(r"1\.02 mm", printer("delta_uady").sources["kinematics.base_radius"])
