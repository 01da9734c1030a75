"""Regenerate the golden trajectories after an intended change:

    python tests/golden/regenerate.py

Each file holds the trajectory of one small part (tests/golden/parts.py) planned for one printer
with the default settings, decimated to 50 Hz: ``t,q1..qJ,e,tool``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE))

from parts import CASES, GOLDEN_RATE  # noqa: E402

from deltaslice import load_printer  # noqa: E402
from deltaslice.planning import plan  # noqa: E402


def compute(name: str) -> tuple[list[str], np.ndarray]:
    printer = load_printer(HERE.parents[1] / "printers" / f"{name}.toml")
    traj = plan(CASES[name](), printer, workers=1)
    s = traj.samples(GOLDEN_RATE)
    cols = ["t"] + [f"q{j + 1}" for j in range(s.n_joints)] + ["e", "tool"]
    return cols, np.column_stack([s.t, s.q, s.e, s.tool])


def main() -> None:
    for name in CASES:
        cols, data = compute(name)
        path = HERE / f"{name}.csv"
        np.savetxt(path, data, delimiter=",", header=",".join(cols), comments="", fmt="%.9g")
        print(f"{path.name}: {len(data)} samples, {path.stat().st_size / 1024:.1f} KiB")


if __name__ == "__main__":
    main()
