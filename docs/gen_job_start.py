"""Draw docs/job_start.png: how a job starts (docs/printers.md, "Rest pose"), read back through
forward kinematics.

    python docs/gen_job_start.py

The issue-48 fast square moved to start at (20, 10) (a Z move and a travel from the bed centre,
then a square at F65536) planned for delta_etitc under the feed speed limit: the tool's height and its horizontal
distance from the first working point against time, to the first extrusion and a little after.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from deltaslice import load_printer  # noqa: E402
from deltaslice.gcode import parse_gcode  # noqa: E402
from deltaslice.planning import plan  # noqa: E402

GCODE = "G90\nM83\nG1 Z0.4 F1200\nG1 X20 Y10 F3000\nG1 X25 Y10 E0.2 F65536\nG1 X25 Y15 E0\nG1 X20 Y15 E0.2\n"
FIRST = np.array([20.0, 10.0])


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    printer = load_printer("delta_etitc")
    traj = plan(parse_gcode(GCODE, printer=printer), printer, workers=1)
    rate = printer.planning.output_rate
    t = np.arange(int(traj.duration * rate)) / rate
    s = traj.sample_at(t)
    kin = printer.kinematics()
    xyz = kin.forward(s.q[:, : kin.n_joints])
    first = int(np.flatnonzero(np.diff(s.e) > 0)[0]) + 1  # the first sample that extrudes
    shown = slice(0, first + 60)
    dist = np.hypot(xyz[:, 0] - FIRST[0], xyz[:, 1] - FIRST[1])
    fig, axes = plt.subplots(1, 2, figsize=(7.2, 2.8), dpi=80)
    for ax, t0, top in ((axes[0], 0.0, None), (axes[1], t[first] - 1.8, 7.0)):
        keep = (t >= t0) & (np.arange(len(t)) < shown.stop)
        ax.plot(t[keep], xyz[keep, 2], label="tool height z")
        ax.plot(t[keep], dist[keep], label="xy distance from the first point")
        ax.axvline(t[first], color="grey", lw=0.8, ls="--")
        ax.axhline(0.4, color="grey", lw=0.8, ls=":")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("mm")
        if top:
            ax.set_ylim(0, top)
    axes[0].set_title("from the rest pose", fontsize=9)
    axes[1].set_title(f"down {printer.planning.approach_height:g} mm at {printer.planning.approach_speed:g} mm/s; "
                      "dashed: first extrusion", fontsize=9)
    axes[0].legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(ROOT / "docs" / "job_start.png")


if __name__ == "__main__":
    main()
