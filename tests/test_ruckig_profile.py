"""Vectorised sampling of ruckig moves from their phases, against ruckig's own at_time; travels
planned in worker processes equal those planned in one."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest
import ruckig
from hypothesis import given, settings
from hypothesis import strategies as st

from deltaslice import load_printer
from deltaslice.planning import plan
from deltaslice.planning.ruckig_profile import RuckigProfile, positions_many
from deltaslice.planning.travel import JointMovePiece
from deltaslice.toolpath import Role, ToolpathBuilder

ROOT = Path(__file__).resolve().parents[1]


def _move(q0, q1, vmax, amax, jmax):
    n = len(q0)
    otg, inp, traj = ruckig.Ruckig(n), ruckig.InputParameter(n), ruckig.Trajectory(n)
    inp.current_position, inp.target_position = list(q0), list(q1)
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = list(vmax), list(amax), list(jmax)
    assert otg.calculate(inp, traj) in (ruckig.Result.Working, ruckig.Result.Finished)
    return traj


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 4),
    seed=st.integers(0, 2**32 - 1),
)
def test_profile_samples_equal_at_time(n, seed):
    rng = np.random.default_rng(seed)
    traj = _move(rng.normal(0, 1, n), rng.normal(0, 1, n), rng.uniform(0.1, 5, n), rng.uniform(0.1, 50, n), rng.uniform(1, 2000, n))
    prof = RuckigProfile.from_trajectory(traj)
    assert prof is not None and prof.duration == traj.duration
    # Every phase boundary, points inside the phases, and times outside [0, duration].
    tau = np.concatenate([np.linspace(-0.1, traj.duration * 1.1, 300), prof.t_end.ravel()])
    ref = np.array([traj.at_time(float(np.clip(t, 0, traj.duration)))[0] for t in tau]).reshape(len(tau), n)
    np.testing.assert_allclose(prof.positions(tau), ref, rtol=0, atol=1e-12)


def test_many_profiles_sample_as_each_alone():
    """positions_many (the clearance check of a batch of travels) gives each move the samples its
    own at_time gives, each at its own times: its phase ends, inside its phases, outside
    [0, duration] (clipped to it), moves of different durations side by side."""
    rng = np.random.default_rng(7)
    trajs = [_move(rng.normal(0, 1, 3), rng.normal(0, 1, 3), rng.uniform(0.1, 5, 3), rng.uniform(0.1, 50, 3),
                   rng.uniform(1, 2000, 3)) for _ in range(12)]
    trajs.sort(key=lambda t: t.duration)  # the shortest first: each row is clipped to its own duration
    profs = [RuckigProfile.from_trajectory(t) for t in trajs]
    tau = np.stack([np.concatenate([np.linspace(-0.1, t.duration * 1.1, 100), p.t_end.ravel()]) for t, p in zip(trajs, profs)])
    many = positions_many(profs, tau)
    assert many.shape == (12, tau.shape[1], 3)
    for traj, row, q in zip(trajs, tau, many):
        ref = np.array([traj.at_time(float(np.clip(t, 0, traj.duration)))[0] for t in row])
        np.testing.assert_allclose(q, ref, rtol=0, atol=1e-12)


def _numpy_positions(prof, tau):
    """The profile's positions in numpy, as ruckig evaluates them: the phase holding each time by
    searchsorted (side right; NaN after every end) on the cumulative ends, its cubic from the
    phase's start state, the final position past the last phase; times clipped to [0, duration]."""
    tau = np.clip(tau, 0.0, prof.duration)
    q = np.empty((len(tau), len(prof.pf)))
    for d in range(len(prof.pf)):
        k = np.searchsorted(prof.t_end[d], tau, side="right")
        done = k >= prof.t_end.shape[1]
        k = np.minimum(k, prof.t_end.shape[1] - 1)
        dt = tau - np.where(k > 0, prof.t_end[d, np.maximum(k - 1, 0)], 0.0)
        p, v, a, j = prof.p[d, k], prof.v[d, k], prof.a[d, k], prof.j[d, k]
        q[:, d] = np.where(done, prof.pf[d], p + dt * (v + dt * (0.5 * a + dt * j / 6.0)))
    return q


@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 4), seed=st.integers(0, 2**32 - 1))
def test_compiled_positions_equal_numpys(n, seed):
    """positions (one compiled pass, what the sampler calls per travel) and positions_many (the
    clearance check's, compiled too) give bit for bit what numpy gives the same profile: at its
    phase ends, inside its phases, outside [0, duration], at a NaN time (the final position); into
    out when given; positions_many each of several profiles as its own positions."""
    rng = np.random.default_rng(seed)
    traj = _move(rng.normal(0, 1, n), rng.normal(0, 1, n), rng.uniform(0.1, 5, n), rng.uniform(0.1, 50, n), rng.uniform(1, 2000, n))
    prof = RuckigProfile.from_trajectory(traj)
    tau = np.concatenate([np.linspace(-0.1, traj.duration * 1.1, 200), prof.t_end.ravel(), [np.nan, -np.inf, np.inf]])
    ref = _numpy_positions(prof, tau)
    np.testing.assert_array_equal(prof.positions(tau), ref)
    np.testing.assert_array_equal(positions_many([prof], tau[None])[0], ref)
    out = np.full((len(tau), n), -7.0)
    assert prof.positions(tau, out=out) is out
    np.testing.assert_array_equal(out, ref)
    with pytest.raises(ValueError, match="out"):
        prof.positions(tau, out=np.empty((len(tau), n + 1)))
    other = RuckigProfile.from_trajectory(_move(rng.normal(0, 1, n), rng.normal(0, 1, n), rng.uniform(0.1, 5, n),
                                                rng.uniform(0.1, 50, n), rng.uniform(1, 2000, n)))
    later = tau[::-1] * 0.5  # its own times, not the first's
    many = positions_many([prof, other, prof], np.stack([tau, later, later]))
    for got, pr, t in zip(many, (prof, other, prof), (tau, later, later)):
        np.testing.assert_array_equal(got, _numpy_positions(pr, t))


def test_joint_move_piece_is_picklable_and_exact():
    traj = _move([0.1, -0.2, 0.3], [0.5, 0.2, -0.1], [2, 2, 2], [20, 20, 20], [500, 500, 500])
    piece = JointMovePiece(RuckigProfile.from_trajectory(traj), None, np.zeros(3), np.ones(3), 0)
    back = pickle.loads(pickle.dumps(piece))
    tau = np.linspace(0, traj.duration, 50)
    ref = np.array([traj.at_time(float(t))[0] for t in tau])
    np.testing.assert_allclose(back.sample(None, tau)[0], ref, atol=1e-12)
    assert back.duration == pytest.approx(traj.duration)


def _islands(printer):
    """Four small squares far apart on two layers: long lifted travels between them."""
    b = ToolpathBuilder((0.0, 0.0, 5.0))
    ratio = printer.slicing.perimeter_width * printer.slicing.layer_height / printer.tool.filament_area
    for layer, z in enumerate((0.5, 0.9)):
        b.new_layer(z)
        for cx, cy in ((-30, -30), (30, -30), (30, 30), (-30, 30)):
            sq = np.array([[-3, -3], [3, -3], [3, 3], [-3, 3], [-3, -3]], float) + (cx, cy)
            b.add([[sq[0, 0], sq[0, 1], z]], printer.slicing.travel_speed, -1.0, 0, Role.TRAVEL)
            b.add([[sq[0, 0], sq[0, 1], z]], printer.slicing.travel_speed, 1.0, 0, Role.TRAVEL)
            b.add(np.c_[sq[1:], np.full(4, z)], printer.slicing.perimeter_speed, np.full(4, 6 * ratio), 1, Role.PERIMETER)
    return b.build()


def test_travels_in_workers_equal_one_process():
    printer = load_printer(ROOT / "printers" / "delta_etitc.toml")
    tp = _islands(printer)
    one = plan(tp, printer, workers=1)
    two = plan(tp, printer, workers=2)
    assert [p.kind for p in one.pieces] == [p.kind for p in two.pieces]
    runs = [k for k, p in enumerate(one.pieces) if p.kind == "run"]
    between = one.pieces[runs[0]:runs[-1]]  # the moves from and to rest are travels too
    assert sum(p.kind == "travel" for p in between) == 7
    np.testing.assert_array_equal(one.durations, two.durations)
    t = np.linspace(0, one.duration, 2000)
    np.testing.assert_array_equal(one.sample_at(t).q, two.sample_at(t).q)
