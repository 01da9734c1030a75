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
