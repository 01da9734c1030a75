"""A joint mounted the other way round: a negative ``counts_per_unit`` reverses its counts and
nothing else (same trajectory in joint values, counts mirrored about the zero count)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from meshes import write
from trajectories import PRINTERS

from deltaslice import load_printer
from deltaslice.errors import PrinterFileError
from deltaslice.pipeline import compile_part, read_counts, verify_output


def test_reversed_joint_mirrors_counts_end_to_end(tmp_path):
    part = tmp_path / "plate.stl"
    write(trimesh.creation.box((10, 10, 0.8)), part)
    base = load_printer(PRINTERS / "delta_etitc.toml")
    cpu = base.limits.counts_per_unit[:3]
    reversed_ = load_printer(PRINTERS / "delta_etitc.toml",
                             {"joints.counts_per_unit": [-11.111, 11.111, 11.111]})
    assert reversed_.limits.counts_per_unit[0] == pytest.approx(-cpu[0])
    out = {}
    for name, p in (("base", base), ("reversed", reversed_)):
        out[name] = tmp_path / f"{name}.dsl"
        compile_part(part, p, output=out[name], workers=1)
        assert verify_output(out[name], p, part).ok
    h0, c0 = read_counts(out["base"])
    h1, c1 = read_counts(out["reversed"])
    assert h0.channels[0].counts_per_unit == pytest.approx(-h1.channels[0].counts_per_unit)
    assert c0.shape == c1.shape
    zero = base.limits.zero_count[0]
    assert np.abs((c0[:, 0] - zero) + (c1[:, 0] - zero)).max() <= 1  # mirrored, within rounding
    assert np.array_equal(c0[:, 1:], c1[:, 1:])
    # the stream's own decoding gives the same joint angles
    v0 = (c0[:, 0] - zero) / h0.channels[0].counts_per_unit
    v1 = (c1[:, 0] - zero) / h1.channels[0].counts_per_unit
    assert np.abs(v0 - v1).max() <= 1.0 / abs(h0.channels[0].counts_per_unit)


def test_zero_counts_per_unit_is_refused_by_name():
    with pytest.raises(PrinterFileError, match=r"counts_per_unit.*non-zero"):
        load_printer(PRINTERS / "delta_etitc.toml", {"joints.counts_per_unit": [0.0, 11.111, 11.111]})
