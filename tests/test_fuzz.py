"""Hypothesis over the library API and the readers: whatever the input, the only exceptions
are the DeltasliceError family (issue 15)."""

from __future__ import annotations

import copy
import tomllib

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from deltaslice import DeltasliceError
from deltaslice.emit import read_output
from deltaslice.emit.stream import MAGIC, parse_header
from deltaslice.gcode import read_gcode
from deltaslice.machine import printer_from_dict
from deltaslice.toolpath import Toolpath, ToolpathBuilder

from conftest import PRINTER_DIR

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

anything = st.one_of(
    st.none(), st.booleans(), st.integers(-(10**20), 10**20), st.floats(allow_nan=True, allow_infinity=True),
    st.complex_numbers(), st.text(max_size=8), st.lists(st.floats(), max_size=4),
    st.lists(st.lists(st.floats(-1e3, 1e3), min_size=0, max_size=4), max_size=3),
)


def _only_family(fn, *args, **kwargs):
    try:
        fn(*args, **kwargs)
    except DeltasliceError:
        pass


@SETTINGS
@given(xyz=anything, feed=anything, e=anything, tool=anything, role=anything)
def test_builder_add_raises_only_the_family(xyz, feed, e, tool, role):
    def go():
        b = ToolpathBuilder()
        b.new_layer(0.4)
        b.add(xyz, feed, e, tool, role)
        b.build()

    _only_family(go)


@SETTINGS
@given(st.data())
def test_toolpath_fields_raise_only_the_family(data):
    n = data.draw(st.integers(0, 4))
    fields = dict(start=np.zeros(3), xyz=np.ones((n, 3)), feed=np.full(n, 10.0), e=np.zeros(n), tool=np.zeros(n),
                  role=np.full(n, 2), layer=np.zeros(n, int), layer_z=np.array([0.4]))
    name = data.draw(st.sampled_from(sorted(fields)))
    fields[name] = data.draw(anything)
    _only_family(Toolpath, **fields)


def _shipped(name):
    return tomllib.loads((PRINTER_DIR / f"{name}.toml").read_text())


SHIPPED = {p.stem: _shipped(p.stem) for p in PRINTER_DIR.glob("*.toml")}


@settings(max_examples=120, deadline=None)
@given(st.sampled_from(sorted(SHIPPED)), st.data())
def test_printer_reader_raises_only_the_family(name, data):
    d = copy.deepcopy(SHIPPED[name])
    section = data.draw(st.sampled_from([s for s in d if isinstance(d[s], dict) and s != "sources"]))
    key = data.draw(st.sampled_from(sorted(d[section]) + ["uper_arm", "extra"]))
    d[section][key] = data.draw(anything)
    _only_family(printer_from_dict, d, f"{name}.toml")


@SETTINGS
@given(st.binary(max_size=300))
def test_output_reader_raises_only_the_family(data):
    _only_family(read_output, data, "fuzz")
    _only_family(read_output, MAGIC + data, "fuzz")
    _only_family(parse_header, MAGIC + data, "fuzz")


@SETTINGS
@given(st.lists(st.sampled_from(["G1", "G0", "X", "Y", "Z", "E", "F", "1", "-", ".", "e9", "nan", " ", ";", "\n", "G92",
                                 "M82", "M83", "G91", "G90", "0.0001", "1e400", "inf", "T1", "G28"]), max_size=60))
def test_gcode_reader_raises_only_the_family(tmp_path_factory, tokens):
    path = tmp_path_factory.mktemp("g") / "f.gcode"
    path.write_text("".join(tokens))
    _only_family(read_gcode, path)


@settings(max_examples=60, deadline=None)
@given(scale=anything, rotate=anything, keep=anything)
def test_mesh_placement_arguments_raise_only_the_family(scale, rotate, keep):
    from deltaslice.mesh import load_mesh

    from conftest import ROOT

    _only_family(load_mesh, ROOT / "examples" / "parts" / "calibration_cube.stl", scale=scale, rotate_z=rotate,
                 keep_position=keep)


@settings(max_examples=80, deadline=None)
@given(rate=anything, fmt=anything, n=st.integers(0, 5), fill=st.floats(allow_nan=True, allow_infinity=True))
def test_verify_arguments_raise_only_the_family(rate, fmt, n, fill):
    from deltaslice.samples import Samples
    from deltaslice.verify import verify_samples

    from conftest import printer

    s = Samples(np.arange(n) / 1000.0, np.full((n, 3), fill), np.full(n, fill), np.full(n, fill))
    _only_family(verify_samples, s, printer("delta_etitc"), rate=rate, fmt=fmt)
    _only_family(verify_samples, s, printer("delta_etitc"), rate=1000.0, fmt="csv")
