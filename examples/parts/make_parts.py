"""Generate the example parts.

    python examples/parts/make_parts.py            # writes calibration_cube.stl here
    python examples/parts/make_parts.py --bench DIR  # also the ~4,000-triangle benchmark vase in DIR

calibration_cube.stl: a 20 mm cube (12 triangles), the part of the README's main command.
twisted_vase.stl: a 10-point star with an 8-sided bore, extruded 76 mm with a 90 deg
twist and a 0.8 top scale (about 4,000 triangles; 190 layers at 0.4 mm).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))


def calibration_cube(size: float = 20.0):
    import trimesh

    box = trimesh.creation.box((size, size, size))
    box.apply_translation((0, 0, size / 2))
    return np.asarray(box.vertices), np.asarray(box.faces)


def twisted_vase(height: float = 76.0, radius: float = 30.0, points: int = 10, divisions: int = 70):
    """A twisted star with a bore: vertices, faces (manifold3d extrusion)."""
    from manifold3d import CrossSection

    a = np.arange(2 * points) * math.pi / points
    r = np.where(np.arange(2 * points) % 2 == 0, radius, radius * 0.72)
    star = np.column_stack([r * np.cos(a), r * np.sin(a)])
    b = np.arange(8) * 2 * math.pi / 8
    bore = np.column_stack([8 * np.cos(b), 8 * np.sin(b)])[::-1]
    section = CrossSection([star, bore])
    solid = section.extrude(height, n_divisions=divisions, twist_degrees=90.0, scale_top=(0.8, 0.8))
    mesh = solid.to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], float), np.asarray(mesh.tri_verts, np.int64)


def main(argv=None):
    from deltaslice.mesh import write_stl

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bench", type=Path, help="also write twisted_vase.stl into this directory")
    args = ap.parse_args(argv)
    write_stl(HERE / "calibration_cube.stl", *calibration_cube())
    print(HERE / "calibration_cube.stl")
    if args.bench:
        args.bench.mkdir(parents=True, exist_ok=True)
        v, f = twisted_vase()
        write_stl(args.bench / "twisted_vase.stl", v, f)
        print(args.bench / "twisted_vase.stl", f"{len(f)} triangles")


if __name__ == "__main__":
    main()
