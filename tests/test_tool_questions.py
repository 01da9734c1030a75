"""The tool's meaning asked of the Tool object (deltaslice/machine/tool.py), not of its kind's name:
what a stream's tool channel decodes to, what verify says of a laser's full power."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import printer

from deltaslice.machine.tool import Extruder, Laser, tool_class
from deltaslice.samples import Samples
from deltaslice.verify import verify_samples


def test_a_streams_tool_kind_names_its_class_and_a_joint_kind_reads_as_a_count():
    assert tool_class("laser") is Laser and tool_class("extruder") is Extruder
    assert tool_class("revolute") is Extruder  # a damaged header's last channel: decoded as before, a rising count
    assert Laser.channel_is_power and not Extruder.channel_is_power


def test_an_extruders_channel_works_where_it_rises_past_the_value_before():
    values = np.array([1.0, 1.0, 2.0, 1.5, 3.0])
    e, tool = Extruder.from_channel(values)
    assert e is values and tool.tolist() == [0.0, 0.0, 1.0, 0.0, 1.0]
    # the value before the first (the previous block's last) decides the first sample
    assert Extruder.from_channel(values, 0.5)[1].tolist() == [1.0, 0.0, 1.0, 0.0, 1.0]
    assert Extruder.from_channel(values, 1.0)[1][0] == 0.0
    assert Extruder.from_channel(np.zeros(0))[1].shape == (0,)
    e, tool = Laser.from_channel(np.array([0.0, 0.5, 1.0]), 0.25)
    assert e.tolist() == [0.0, 0.0, 0.0] and tool.tolist() == [0.0, 0.5, 1.0]


@pytest.mark.parametrize("name", ["delta_espe_laser", "delta_etitc"])
def test_verify_says_what_a_lasers_peak_power_burns_in_watts(name):
    p = printer(name)
    n = 200
    rate = p.planning.output_rate
    t = np.arange(n) / rate
    q = np.tile(p.kinematics().inverse(np.array([[0.0, 0.0, 5.0]])), (n, 1))
    tool = np.where(np.arange(n) > 50, 0.5, 0.0)
    rep = verify_samples(Samples(t, q, np.zeros(n), tool), p, rate=rate, fmt="csv")
    notes = [s for s in rep.notes if "of full power" in s]
    if p.tool.full_power_w is None:
        assert not notes  # an extruder burns nothing
    else:
        assert notes == [f"peak power 0.5 of full power: {0.5 * p.tool.max_power:.3g} W of the tool's max_power "
                         f"{p.tool.max_power:g} W"]
