"""Cooling (issue 53): minimum layer time and part-fan events on sliced parts."""

import numpy as np
import pytest

from deltaslice.errors import PrinterFileError
from deltaslice.gcode import gcode_text
from deltaslice.machine import load_printer
from deltaslice.slicing import slice_mesh
from deltaslice.slicing.cooling import layer_times, move_times
from deltaslice.toolpath import EventKind, Role

from . import meshes


@pytest.fixture(scope="module")
def kossel():
    return load_printer("linear_kossel")


@pytest.fixture(scope="module")
def tower_tp(kossel):
    return slice_mesh(meshes.box(6, 6, 10), kossel.slicing, kossel.tool)


def _fans(tp):
    ev = tp.events[tp.events["kind"] == EventKind.FAN]
    return ev["index"], ev["value"]


def test_tower_layers_take_the_minimum_layer_time(tower_tp, kossel):
    c = kossel.slicing.cooling
    times = layer_times(tower_tp)
    assert len(times) == 49
    assert times.min() >= 0.95 * c.slowdown_below_layer_time, times.min()
    # slowed, not below the minimum speed (travels keep theirs)
    work = tower_tp.working
    assert tower_tp.feed[work].min() >= c.min_print_speed - 1e-9
    # unslowed, the tower's layers are quicker: the slowdown is what makes them long enough
    unslowed = load_printer("linear_kossel", {"cooling.slowdown_below_layer_time": 0.0})
    quick = layer_times(slice_mesh(meshes.box(6, 6, 10), unslowed.slicing, unslowed.tool))
    assert np.median(quick) < 0.8 * c.slowdown_below_layer_time


def test_a_layer_that_cannot_be_slowed_enough_runs_at_the_minimum_speed(kossel):
    p = load_printer("linear_kossel", {"cooling.slowdown_below_layer_time": 600.0, "cooling.min_print_speed": 12.0})
    tp = slice_mesh(meshes.box(6, 6, 2), p.slicing, p.tool)
    work = tp.working & (tp.role != Role.RETRACT)
    assert np.allclose(tp.feed[work], np.minimum(12.0, tp.feed[work]))
    assert np.all(tp.feed[work] <= 12.0 + 1e-9)


def test_fan_turns_on_after_the_first_layers_and_is_full_on_quick_layers(tower_tp, kossel):
    c = kossel.slicing.cooling
    idx, val = _fans(tower_tp)
    assert len(idx), "no fan event"
    first_on = int(idx[np.argmax(val > 0)])
    assert tower_tp.layer[first_on] == c.disable_fan_first_layers
    assert not np.any(val[tower_tp.layer[np.minimum(idx, len(tower_tp) - 1)] < c.disable_fan_first_layers] > 0)
    # the tower's layers are quicker than slowdown_below_layer_time before the slowdown: full fan
    assert val.max() == round(c.max_fan_speed * 2.55)


def test_long_layers_run_the_minimum_fan_and_bridges_the_bridge_fan(kossel):
    p = load_printer("linear_kossel", {"cooling.bridge_fan_speed": 80.0, "cooling.min_fan_speed": 20.0,
                                       "cooling.fan_below_layer_time": 1.0, "cooling.slowdown_below_layer_time": 0.0})
    tp = slice_mesh(meshes.step(), p.slicing, p.tool)
    idx, val = _fans(tp)
    at = {int(i): float(v) for i, v in zip(idx, val)}
    # the fan value in force at every move
    order = np.searchsorted(idx, np.arange(len(tp)), side="right") - 1
    want = np.where(order >= 0, val[np.maximum(order, 0)], 0.0)
    bridge = tp.role == Role.BRIDGE_INFILL
    assert bridge.any() and set(want[bridge]) == {round(80 * 2.55)}
    others = tp.working & ~bridge & (tp.role != Role.OVERHANG_PERIMETER) & (tp.layer >= 3)
    assert set(want[others]) == {round(20 * 2.55)}
    assert all(v in (0.0, round(80 * 2.55), round(20 * 2.55), 255.0) for v in at.values())


def test_gcode_turns_the_fan_on_after_the_first_layers(tower_tp, kossel):
    lines = gcode_text(tower_tp, kossel).splitlines()
    fan = [i for i, ln in enumerate(lines) if ln.startswith("M106")]
    assert fan and lines[fan[0]] == "M106 S255"
    # written before the first move of the first layer with the fan on (its ;LAYER mark follows)
    assert lines[fan[0] + 1] == f";LAYER:{kossel.slicing.cooling.disable_fan_first_layers}"


def test_a_machine_without_a_fan_gets_no_fan_events():
    p = load_printer("delta_etitc")
    tp = slice_mesh(meshes.box(10, 10, 4), p.slicing, p.tool)
    assert not np.any(tp.events["kind"] == EventKind.FAN)


def test_move_times_count_retracts_by_their_filament(tower_tp):
    t = move_times(tower_tp)
    retract = (tower_tp.role == Role.RETRACT)
    assert retract.any() and np.all(t[retract] > 0)


@pytest.mark.parametrize("key,value,bound", [("min_fan_speed", 120.0, "<= 100"), ("min_print_speed", 0.0, "> 0"),
                                             ("disable_fan_first_layers", -1, ">= 0"), ("min_fan_speed", 90.0, "max_fan_speed")])
def test_cooling_keys_are_validated_at_load(key, value, bound):
    over = {f"cooling.{key}": value}
    if key == "min_fan_speed" and value == 90.0:
        over["cooling.max_fan_speed"] = 50.0
    with pytest.raises(PrinterFileError) as err:
        load_printer("linear_kossel", over)
    assert f"cooling.{key}" in str(err.value) and bound in str(err.value), str(err.value)
