"""Another slicer hands deltaslice its moves as arrays and gets a trajectory back (docs/library.md).

    python examples/from_arrays.py [OUT_DIR]

Builds three layers of a 20 mm square (one perimeter each, a travel between layers) as flat
arrays, plans them for the shipped ETITC delta, checks the samples against the printer's
limits and the path, and writes the binary stream OUT_DIR/square.dsl.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from deltaslice import DeltasliceError, Role, Toolpath, load_printer
from deltaslice.pipeline import write_output
from deltaslice.planning import plan
from deltaslice.verify import verify_samples


def square_moves(side=20.0, layers=3, layer_height=0.4, feed=30.0, filament_per_mm=0.033):
    """Flat per-move arrays, one row per straight move (mm, mm/s, mm of filament, 0..1, Role, layer)."""
    h = side / 2
    corners = np.array([[h, -h], [h, h], [-h, h], [-h, -h]])
    xyz, feeds, e, tool, role, layer = [], [], [], [], [], []
    for k in range(layers):
        z = layer_height * (k + 1)
        # a travel to the layer's first corner (tool off, no filament)
        xyz.append([-h, -h, z]); feeds.append(120.0); e.append(0.0); tool.append(0.0); role.append(Role.OTHER); layer.append(k)
        for x, y in corners:  # the perimeter: four printing moves
            xyz.append([x, y, z]); feeds.append(feed); e.append(side * filament_per_mm); tool.append(1.0)
            role.append(Role.EXTERNAL_PERIMETER); layer.append(k)
    layer_z = layer_height * (np.arange(layers) + 1)
    return np.array(xyz), np.array(feeds), np.array(e), np.array(tool), np.array(role), np.array(layer), layer_z


def main(out_dir: Path) -> int:
    printer = load_printer("delta_etitc")  # a shipped printer by name, or a path to your file
    xyz, feed, e, tool, role, layer, layer_z = square_moves()
    toolpath = Toolpath(start=np.array([0.0, 0.0, 5.0]), xyz=xyz, feed=feed, e=e, tool=tool, role=role, layer=layer,
                        layer_z=layer_z)
    trajectory = plan(toolpath, printer, workers=1)
    samples = trajectory.samples()  # Samples: t (n,), q (n, 3) rad, e (n,) mm, tool (n,)
    report = verify_samples(samples, printer, rate=printer.planning.output_rate, fmt="csv", toolpath=toolpath)
    size = write_output(trajectory, out_dir / "square.dsl")
    print(f"{len(toolpath)} moves -> {trajectory.duration:.2f} s, {len(samples)} samples, "
          f"verify {'PASS' if report.ok else 'FAIL'}, {size} bytes in {out_dir / 'square.dsl'}")
    return 0 if report.ok else 1


if __name__ == "__main__":
    try:
        sys.exit(main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(".")))
    except DeltasliceError as exc:
        sys.exit(f"error: {exc}")
