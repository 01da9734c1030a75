"""Issue 53's done-when through the command line: `deltaslice slice` with --set."""

import numpy as np
import shapely
from click.testing import CliRunner

from deltaslice.cli import main
from deltaslice.gcode import read_gcode
from deltaslice.toolpath import Role

from . import meshes
from .test_slicing_support import cantilever


def test_slice_writes_support_brim_and_fan(tmp_path):
    part = meshes.write(cantilever(), tmp_path / "cantilever.stl")
    out = tmp_path / "cantilever.gcode"
    r = CliRunner().invoke(main, ["slice", str(part), "--printer", "linear_kossel", "--set", "slicing.support=auto",
                                  "--set", "slicing.brim_width=5", "-o", str(out), "--quiet"])
    assert r.exit_code == 0, r.output
    text = out.read_text()
    assert "M106 S255" in text and ";TYPE:Support material" in text
    tp = read_gcode(out)
    assert np.any(tp.working & (tp.role == Role.SUPPORT))
    # the part is centred on the bed: its first layer (the post) is 4 x 10 mm; the brim reaches
    # 4.5 mm beyond it
    first = tp.working & (tp.layer == 0) & (tp.role != Role.SUPPORT) & (tp.role != Role.SUPPORT_INTERFACE)
    post = tp.working & (tp.layer == 0) & (tp.role == Role.EXTERNAL_PERIMETER)
    outline = shapely.MultiPoint(tp.xyz[post, :2]).convex_hull.buffer(0.25)  # the external bead's centre line + w/2
    d = shapely.distance(outline, shapely.points(tp.xyz[first, :2]))
    brim = d < 5.0 + 1.0  # the skirt is skirt_distance (3 mm) beyond the brim
    assert d[brim].max() + 0.25 >= 4.5 and d[~brim].min() >= 4.5 + 3.0 - 0.5
