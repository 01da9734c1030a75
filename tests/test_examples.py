"""The examples in examples/ run as documented (docs/library.md, docs/quickstart.md)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from conftest import ROOT


@pytest.mark.parametrize("script, outputs", [
    ("from_arrays.py", ["square.dsl"]),
    ("compile_and_preview.py", ["cube.dsl", "cube_layer.png", "cube_joints.png"]),
])
def test_example_runs(tmp_path, script, outputs):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, str(ROOT / "examples" / script), str(tmp_path)], capture_output=True, text=True,
                       env=env, cwd=tmp_path, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "PASS" in r.stdout
    for name in outputs:
        assert (tmp_path / name).stat().st_size > 1000, name


def test_the_quickstart_shows_the_summary_a_compile_prints():
    """docs/quickstart.md's sample summary has the lines ``compile_summary`` writes, in its order, with
    the compile's own fields (a real run's numbers; they drift with the planner, the labels must not)."""
    import re

    from deltaslice.report import CompileResult, compile_summary

    text = (ROOT / "docs" / "quickstart.md").read_text()
    block = text.split("    printer: delta_etitc\n", 1)[1].split("\n\n", 1)[0]
    shown = ["printer: delta_etitc"] + [line[4:] for line in block.splitlines()]
    result = CompileResult(printer="delta_etitc", output="examples/parts/calibration_cube.dsl", fmt="stream",
                           size_bytes=1, layers=1, moves=1, pieces={"run": 1}, planner="toppra", speed_limit="feed",
                           duration_s=1.0, peak_percent={"theta1 vel": 1.0}, active_fraction=0.5,
                           times={"slice": 1.0, "plan": 1.0, "total": 2.0})
    expected = compile_summary(result).splitlines()
    label = lambda line: re.sub(r"[\d.]+", "N", line.split(":", 1)[0])  # noqa: E731
    assert [label(l) for l in shown] == [label(l) for l in expected], shown
    assert "output: examples/parts/calibration_cube.dsl (stream," in block and "planner: toppra, speed limit: feed" in block
    assert "..." not in block
