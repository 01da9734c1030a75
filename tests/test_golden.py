"""Golden trajectories: recompile small parts and compare with the stored samples.

Tolerance: 1e-6 in every channel (rad, mm, s) and the same number of samples. After an intended
change of the planner, kinematics or printer files, regenerate with
``python tests/golden/regenerate.py`` and review the diff.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

GOLDEN = Path(__file__).resolve().parent / "golden"
sys.path.insert(0, str(GOLDEN))

from parts import CASES  # noqa: E402
from regenerate import compute  # noqa: E402

TOL = 1e-6


def diff_summary(cols, got, want) -> str:
    if got.shape != want.shape:
        return f"{len(got)} samples now, {len(want)} stored (duration {got[-1, 0]:.4f} s vs {want[-1, 0]:.4f} s)"
    err = np.abs(got - want)
    lines = []
    for c, name in enumerate(cols):
        if err[:, c].max() > TOL:
            i = int(np.argmax(err[:, c]))
            n = int((err[:, c] > TOL).sum())
            lines.append(f"{name}: {n} samples differ, worst at t = {want[i, 0]:.3f} s: {got[i, c]:.9g} vs {want[i, c]:.9g} stored ({err[i, c]:.3g})")
    return "; ".join(lines)


@pytest.mark.parametrize("name", sorted(CASES))
def test_golden_trajectory(name):
    path = GOLDEN / f"{name}.csv"
    assert path.stat().st_size < 64 * 1024, "golden files stay small"
    want = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    cols, got = compute(name)
    summary = diff_summary(cols, got, want)
    assert not summary, f"{name} trajectory changed (regenerate with python tests/golden/regenerate.py if intended): {summary}"


def test_diff_summary_names_channel_time_and_size():
    cols = ["t", "q1", "e"]
    want = np.array([[0.0, 1.0, 0.0], [0.02, 1.0, 0.1]])
    got = want.copy()
    got[1, 1] += 0.5
    s = diff_summary(cols, got, want)
    assert "q1: 1 samples differ" in s and "t = 0.020 s" in s and "0.5" in s
