"""The trajectory preview's torque panels: one per actuator where the printer has dynamics, drawn
against the limits the planner keeps to (``planning.torque.torque_limits``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from deltaslice import load_printer
from deltaslice.machine.dynamics import sampled_torques
from deltaslice.planning.torque import torque_limits
from deltaslice.preview import trajectory_figure
from deltaslice.samples import Samples

RATE = 1000.0


def _samples(printer):
    """Two seconds of a circle of 10 mm radius and 3 mm rise, 30 mm over the bed's centre, at 1 kHz."""
    t = np.arange(int(2 * RATE)) / RATE
    a = 2 * np.pi * 1.5 * t
    q = printer.kinematics().inverse(np.c_[10 * np.cos(a), 10 * np.sin(a), 30 + 3 * np.sin(2 * a)])
    assert np.all(np.isfinite(q))
    return Samples(t, q, np.zeros_like(t), np.zeros_like(t))


def _torque_axes(fig):
    return [a for a in fig.axes if " torque (" in a.get_title() or " force (" in a.get_title()]


@pytest.mark.parametrize("name", ["delta_etitc", "delta_ucb", "fivebar_atlas"])
def test_torque_panels_draw_the_planned_limits(name):
    """Per actuator: the red dashed lines at +-stall and the orange line at stall (1 - |qd| / w), w the
    line speed the planner uses (a stepper's pull-out curve puts it under the no-load speed: drawing
    the no-load speed would show a limit the plan does not keep to)."""
    printer = load_printer(name)
    samples = _samples(printer)
    fig = trajectory_figure(samples, printer)
    axes = _torque_axes(fig)
    J = printer.n_joints
    assert len(axes) == J
    tq = torque_limits(printer)
    tau, qd = sampled_torques(printer, samples.q, RATE)
    for j, ax in enumerate(axes):
        lines = ax.get_lines()
        dashed = sorted(float(np.asarray(line.get_ydata(), float)[0]) for line in lines if line.get_linestyle() == "--")
        np.testing.assert_allclose(dashed, [-tq.stall[j], tq.stall[j]], rtol=1e-12)
        drawn = [np.asarray(line.get_ydata(), float) for line in lines if line.get_linestyle() == "-"]
        top = max(drawn, key=lambda y: y.max())
        expected = tq.stall[j] * np.clip(1 - np.abs(qd[:, j]) / tq.line_speed[j], 0, 1)
        np.testing.assert_allclose(top, expected, rtol=1e-12)  # 2000 samples: drawn as they are
        assert top.min() < tq.stall[j] * (1 - 1e-3), "the joints never move: the line tests nothing"
        # the series drawn is the read-back torque
        body = ax.collections[0].get_paths()[0].vertices[:, 1]
        assert np.isclose(body.max(), tau[:, j].max()) and np.isclose(body.min(), tau[:, j].min())
    if name == "fivebar_atlas":
        assert np.all(tq.line_speed < np.array(printer.dynamics.actuators.no_load_speed))


def test_no_torque_panels_without_dynamics():
    printer = load_printer("delta_etitc")
    bare = dataclasses.replace(printer, dynamics=None)
    fig = trajectory_figure(_samples(bare), bare)
    assert _torque_axes(fig) == []
    assert len(_torque_axes(trajectory_figure(_samples(printer), printer))) == printer.n_joints
