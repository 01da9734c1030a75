"""Unit tests of the blocks the planner is built from, each against a brute-force evaluation:
the path-velocity constraint, the grid, RunPath's derivatives, the travel planner, and the
slicer's path ordering."""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
import ruckig
from hypothesis import given, settings
from hypothesis import strategies as st

from deltaslice.errors import UnreachableError
from deltaslice.planning import topp, travel
from deltaslice.planning import batch as batch_mod
from deltaslice.planning import constraints, runpath, stages
from deltaslice.planning import solver as solver_mod
from deltaslice.planning.context import PlanContext
from deltaslice.planning.blend import BlendedPath, blend_polyline, blend_runs
from deltaslice.planning.pieces import JointMovePiece, RunPiece
from deltaslice.planning.ruckig_profile import RuckigProfile
from deltaslice.planning.trajectory import Trajectory
from deltaslice.slicing.ordering import Path, nearest_order

from conftest import printer


def _zigzag(rng, n=6, z=1.0, span=30.0):
    xy = rng.uniform(-span / 2, span / 2, size=(n, 2))
    return np.column_stack([xy, np.full(n, z)])


def _run_path(name="delta_etitc", seed=0, extruder=True):
    p = printer(name)
    pts = _zigzag(np.random.default_rng(seed), z=min(5.0, p.bed.max_height / 2))
    path = blend_polyline(pts, p.planning.blend_tolerance)
    e_ratio = np.full(len(path.kind), 0.03) if extruder else None
    return p, path, runpath.RunPath(p.kinematics(), path, e_ratio, 0)


@pytest.mark.parametrize("name", ["delta_etitc", "fivebar_atlas", "linear_kossel", "delta_uady"])
def test_path_velocity_constraint_against_brute_force(name):
    p, path, rp = _run_path(name)
    x = stages.grid(path) / path.length
    vmax = p.planned_limits().velocity[: rp.dof]
    feed = np.random.default_rng(1).uniform(5, 80, len(x))
    c = constraints.PathVelocityConstraint(vmax, feed, path.length)
    xbound = c.compute_constraint_params(rp, x)[-1]
    # Brute force: per grid point, the largest x_dot that keeps every channel and the feed in bounds.
    dq = rp(x, 1)
    for i in range(0, len(x), max(1, len(x) // 40)):
        candidates = [feed[i] / path.length] + [vmax[j] / abs(dq[i, j]) for j in range(rp.dof) if dq[i, j] != 0]
        best = min(candidates)
        assert xbound[i, 1] == pytest.approx(best**2, rel=1e-12)
        assert xbound[i, 0] == 0.0
        # and it is tight: 0.1 % faster breaks one of the bounds
        xd = 1.001 * best
        assert (np.abs(dq[i]) * xd > vmax * (1 + 1e-12)).any() or xd * path.length > feed[i]


def test_grid_has_both_sides_of_every_join_and_bounded_steps():
    p, path, _ = _run_path()
    g = stages.grid(path)
    assert g[0] == 0.0 and g[-1] == path.length and np.all(np.diff(g) > 0)
    # Steps grow to MAX_STEP from each end of a piece; the two sequences stop 0.1 % short of
    # the middle, so the gap where they meet is at most 2 MAX_STEP + 0.1 % of the piece.
    joins = np.concatenate([[0.0], path.joins(), [path.length]])
    owner = np.clip(np.searchsorted(joins, g[:-1], side="right") - 1, 0, len(joins) - 2)
    assert np.all(np.diff(g) <= 2 * stages.MAX_STEP + 1e-3 * np.diff(joins)[owner] + 1e-12)
    for s in path.joins():
        i = np.searchsorted(g, s)
        assert abs(g[i] - s) < 1e-9, "every join is a grid point"
        if 0 < i < len(g) - 1:
            assert g[i] - g[i - 1] <= stages.MIN_STEP * 1.001 + 1e-9 or g[i] - g[i - 1] == pytest.approx(s - g[i - 1])
            assert g[i + 1] - g[i] <= stages.MIN_STEP * 1.001 or i + 1 == len(g) - 1
    arcs = np.flatnonzero(path.kind == 1)
    for k in arcs:
        a, b = path.piece_start[k], path.piece_start[k + 1]
        inside = g[(g >= a - 1e-12) & (g <= b + 1e-12)]
        assert np.diff(inside).max(initial=0) <= stages.ARC_STEP * path.radius[k] * (1 + 1e-9) + 1e-12


def _interior(g, path, k):
    """Grid points strictly inside piece k."""
    a, b = path.piece_start[k], path.piece_start[k + 1]
    return int(((g > a + 1e-12) & (g < b - 1e-12)).sum())


def test_grid_gives_a_short_piece_interior_points_only_between_rests():
    """A piece shorter than the geometric steps gets points at its quarters where it starts and
    stops at rest (a stage from rest to rest cannot move); elsewhere its joins are its grid.
    rest=None: rest may be anywhere (every short piece gets them)."""
    lengths = np.array([1.0, 0.03, 1.0, 0.03, 1.0])
    start = np.concatenate([[0.0], np.cumsum(lengths)])
    k = len(lengths)
    path = BlendedPath(start, np.zeros(k, dtype=np.int8), np.column_stack([start[:-1], np.zeros(k), np.ones(k)]),
                       np.tile([1.0, 0.0, 0.0], (k, 1)), np.zeros((k, 3)), np.full(k, np.inf), np.arange(k))
    for rest, want in [(None, [3, 3]), (start[[1, 2]], [3, 0]), (start[[1, 4]], [0, 0]), (np.zeros(0), [0, 0]),
                       (start[[3, 4]], [0, 3])]:
        g = stages.grid(path, rest)
        assert [_interior(g, path, 1), _interior(g, path, 3)] == want, rest
        assert all(_interior(g, path, i) > 0 for i in (0, 2, 4))  # long pieces keep their geometric steps
    # the path's ends are at rest: a short first or last piece between a stop and an end
    first = BlendedPath(start[1:4] - start[1], *(v[1:3] for v in (path.kind, path.p0, path.d0, path.normal,
                                                                   path.radius, path.segment)))
    assert _interior(stages.grid(first, first.piece_start[1:2]), first, 0) == 3
    assert _interior(stages.grid(first, np.zeros(0)), first, 0) == 0


def test_a_short_move_between_stops_is_planned_with_the_others(monkeypatch):
    """plan_lines lays moves end to end with a stop at every join: a 0.03 mm move between two
    others needs interior points there too, or the joint solve fails and every move is planned
    alone (the fallback, refused here)."""
    p = printer("delta_etitc")
    kin = p.kinematics()
    z = 0.5 * p.bed.max_height
    a = np.array([[0.0, 0.0, z], [5.0, 0.0, z], [5.03, 0.0, z]])
    b = np.array([[5.0, 0.0, z], [5.03, 0.0, z], [5.03, 5.0, z]])

    def alone(*args, **kwargs):
        raise AssertionError("a move was planned alone")

    monkeypatch.setattr(batch_mod, "plan_run", alone)
    out = batch_mod.plan_lines(PlanContext.of(p, "feed"), a, b, np.full(3, 100.0), np.zeros(3, dtype=int))
    assert [len(o) for o in out] == [1, 1, 1]
    assert len(out[1][0].x) == 5  # its ends and its quarters
    assert all(o[0].duration > 0 and np.isfinite(o[0].duration) for o in out)


def _inside_pieces(path):
    """Points at the middle of every path piece and a central-difference step (mm) small
    against the piece: blend arcs can be shorter than a micron."""
    mids = 0.5 * (path.piece_start[:-1] + path.piece_start[1:])
    return mids, np.minimum(1e-4, 1e-3 * np.diff(path.piece_start))


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), name=st.sampled_from(["delta_etitc", "fivebar_atlas", "linear_kossel"]))
def test_run_path_first_derivative_against_finite_differences(seed, name):
    p, path, rp = _run_path(name, seed)
    S = path.length
    mids, h_mm = _inside_pieces(path)
    x, h = mids / S, h_mm / S
    fd1 = (rp(x + h) - rp(x - h)) / (2 * h[:, None])
    d1 = rp(x, 1)
    J = p.n_joints
    err = np.abs(d1[:, :J] - fd1[:, :J]).max(axis=1) / np.abs(fd1[:, :J]).max(axis=1)
    assert err.max() < 1e-4, err
    assert np.allclose(d1[:, J], 0.03 * S)  # filament per unit x: e_ratio x run length


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_run_path_second_derivative_against_finite_differences(seed):
    """The second derivative (tangent, curvature and the inverse Jacobian's directional
    derivative) against central differences of the first: it was a one-sided difference with a
    1e-4 mm step, up to 25 % off on blend arcs shorter than a few microns."""
    p, path, rp = _run_path("delta_etitc", seed)
    S = path.length
    mids, h_mm = _inside_pieces(path)
    x, h = mids / S, h_mm / S
    fd2 = (rp(x + h, 1) - rp(x - h, 1)) / (2 * h[:, None])
    d2 = rp(x, 2)
    J = p.n_joints
    err = np.abs(d2[:, :J] - fd2[:, :J]).max(axis=1) / np.abs(fd2[:, :J]).max(axis=1)
    assert err.max() < 1e-3, err


def test_travel_planner_pieces_clear_the_part_and_join():
    p = printer("fivebar_atlas")
    kin = p.kinematics()
    a, b = np.array([-30.0, -20.0, 2.0]), np.array([35.0, 25.0, 2.0])
    for speed_limit in ("feed", "machine"):
        pieces = travel.plan_travel(PlanContext.of(p, speed_limit), a, b, layer=5, printed_top=2.0, retract=-1.0, unretract=1.0,
                                    feed=2.0)
        kinds = [type(x).__name__ for x in pieces]
        assert kinds[0] == "FilamentPiece" and kinds[-1] == "FilamentPiece", kinds
        for x, y in zip(pieces[:-1], pieces[1:]):
            assert np.abs(x.q_end - y.q_start).max() < 1e-9
        assert np.allclose(kin.forward(pieces[0].q_start[None])[0], a, atol=1e-9)
        assert np.allclose(kin.forward(pieces[-1].q_end[None])[0], b, atol=1e-9)
        lift = p.tool.travel_lift(p.planning)
        for m in pieces[1:-1]:  # densely: the planner's own check samples 48 points
            q, _, _ = m.sample(kin, np.linspace(0, m.duration, 4000))
            xyz = kin.forward(q)
            assert xyz[:, 2].min() >= 2.0 - 1e-6 and kin.reachable(xyz).all()
            if isinstance(m, JointMovePiece):
                assert xyz[:, 2].min() >= 2.0 + 0.5 * lift - 1e-6
        if speed_limit == "feed":  # a crawl: a joint-space move, whose tool speed follows the joints, is never taken
            assert not any(isinstance(x, JointMovePiece) for x in pieces), kinds
            q, _, _ = pieces[1].sample(kin, np.linspace(0, pieces[1].duration, 4000))
            speed = np.linalg.norm(np.diff(kin.forward(q), axis=0), axis=1) / (pieces[1].duration / 3999)
            assert speed.max() <= 2.0 * 1.001
    # Straight candidates are toppra runs of kind "travel", never relabelled copies.
    straight = travel.plan_travel(PlanContext.of(p, "feed"), a, b, layer=5, printed_top=2.0, retract=0.0, unretract=0.0,
                                  feed=500.0)
    assert straight and all(x.kind == "travel" for x in straight)
    assert all(isinstance(x, (RunPiece, JointMovePiece)) for x in straight)


def test_nearest_order_visits_every_path_once_from_the_nearest():
    rng = np.random.default_rng(3)
    paths = []
    for k in range(12):
        c = rng.uniform(-40, 40, 2)
        if k % 3 == 0:
            th = np.linspace(0, 2 * np.pi, 9)[:-1]
            paths.append(Path(c + 3 * np.c_[np.cos(th), np.sin(th)], 1, 0.45, closed=True))
        else:
            paths.append(Path(c + rng.uniform(-5, 5, (4, 2)), 3, 0.45))
    start = np.array([50.0, 50.0])
    out = nearest_order(paths, start, seam="nearest")
    assert len(out) == len(paths)

    def key(points):
        return frozenset(map(tuple, np.round(points, 9)))

    source = {key(p.points): k for k, p in enumerate(paths)}
    order = [source[key(pts)] for pts, _p in out]
    assert sorted(order) == list(range(len(paths)))  # every path once
    for (pts, _p), k in zip(out, order):
        p = paths[k]
        if p.closed:  # the same loop, rotated to its seam
            assert len(pts) in (len(p.points), len(p.points) + 1)
        else:
            assert np.array_equal(pts, p.points) or np.array_equal(pts, p.points[::-1])
    # greedy: each path is the nearest of those left, by its entry (the ends of an open path,
    # the centre of a loop whose seam is chosen on arrival)
    pos, left = start, set(range(len(paths)))
    for (pts, _p), k in zip(out, order):
        def entry(q):
            if q.closed:
                return np.linalg.norm(q.points.mean(axis=0) - pos)
            return min(np.linalg.norm(q.points[0] - pos), np.linalg.norm(q.points[-1] - pos))
        assert entry(paths[k]) <= min(entry(paths[m]) for m in left) + 1e-9
        left.remove(k)
        pos = pts[-1]


def test_nearest_order_breaks_ties_towards_a_head_and_the_first_path():
    """A path entered from its tail only when that tail is strictly nearer than every head;
    among equally near ends, the first path's (the toolpath must not depend on how the
    distances are searched)."""
    a = Path(np.array([[0.0, 5.0], [0.0, 9.0]]), 3, 0.45)  # head 5 mm from the origin
    b = Path(np.array([[9.0, 0.0], [5.0, 0.0]]), 3, 0.45)  # tail 5 mm from it
    c = Path(np.array([[-5.0, 0.0], [-9.0, 0.0]]), 3, 0.45)  # head 5 mm from it
    origin = np.zeros(2)
    first = nearest_order([b, a, c], origin)[0][0]
    assert np.array_equal(first, a.points)  # a head before the tail as near, the first head of two
    first = nearest_order([b, c, a], origin)[0][0]
    assert np.array_equal(first, c.points)
    nearer = Path(np.array([[9.0, 0.0], [4.0, 0.0]]), 3, 0.45)
    first = nearest_order([a, nearer, c], origin)[0][0]
    assert np.array_equal(first, nearer.points[::-1])  # a strictly nearer tail: entered reversed


@pytest.mark.parametrize("seed", [0, 3])
def test_frame_equals_evaluate_and_check_derivatives_hold_the_constraint_ones(seed):
    """The planner computes a grid's derivatives once, at the check's fractions, and hands the
    constraint every other one; the path's frame gives evaluate's three orders. Both must be the
    very values of the separate calls, bit for bit, on both sides of every join."""
    p, path, rp = _run_path("delta_etitc", seed)
    assert np.array_equal(constraints.CHECK[constraints.EVAL_IN_CHECK], constraints.EVAL)
    s = np.concatenate([np.linspace(0, path.length, 997), path.joins()])
    for piece in (path.locate(s), np.maximum(path.locate(s) - 1, 0)):
        frame = path.frame(s, piece)
        for order in range(3):
            assert np.array_equal(frame[order], path.evaluate(s, order, piece))
    x = stages.grid(path) / path.length
    dq_c, ddq_c = rp.stage_derivatives(x, constraints.CHECK)
    dq_e, ddq_e = rp.stage_derivatives(x, constraints.EVAL)
    assert np.array_equal(dq_c[:, constraints.EVAL_IN_CHECK], dq_e) and np.array_equal(ddq_c[:, constraints.EVAL_IN_CHECK], ddq_e)


@pytest.mark.parametrize("block", [runpath.DERIVATIVE_BLOCK, 50, 7])
def test_stage_frames_and_derivatives_are_those_at_each_stages_arc_lengths(block, monkeypatch):
    """The per-stage frames (and so the stage derivatives) are frame and derivatives at the arc
    lengths s_i + ds_i f in each stage's own piece, bit for bit, whatever the blocks of stages
    they are computed in (a block of 7 points holds no whole stage of 9)."""
    monkeypatch.setattr(runpath, "DERIVATIVE_BLOCK", block)
    p, path, rp = _run_path("delta_etitc", 0)
    # a filament rate of its own on every piece: the tool channel is filled block by block too
    rp = runpath.RunPath(rp.kin, path, np.random.default_rng(4).uniform(0.01, 0.05, len(path.kind)), 0)
    x = stages.grid(path) / path.length
    s = x * path.length
    ds = np.diff(s)
    owner = path.locate(0.5 * (s[:-1] + s[1:]))
    at = (s[:-1, None] + ds[:, None] * constraints.CHECK[None]).ravel()
    piece = np.repeat(owner, len(constraints.CHECK))
    for got, want in zip(path.stage_frame(s[:-1], ds, constraints.CHECK, owner), path.frame(at, piece)):
        assert np.array_equal(got, want)
    dq, ddq = rp.stage_derivatives(x, constraints.CHECK)
    wq, wqq = rp.derivatives(at, piece)
    assert np.array_equal(dq.reshape(wq.shape), wq) and np.array_equal(ddq.reshape(wqq.shape), wqq)
    assert rp.stage_derivatives(x, np.zeros(0))[0].shape == (len(x) - 1, 0, rp.dof)  # no fractions: nothing


@pytest.mark.parametrize("name", ["delta_etitc", "linear_kossel"])
def test_a_run_pieces_samples_are_its_profile_path_and_filament_bit_for_bit(name):
    """RunPiece.sample's compiled pass gives the very values of arc_length_at, locate, frame and
    filament_at composed in numpy, at times before, inside and after the piece, in any order,
    on exact grid times (a stage boundary belongs to the stage after it)."""
    p = printer(name)
    kin = p.kinematics()
    rng = np.random.default_rng(11)
    pieces = [x for spec in _runs(p, rng, 8) for x in topp.plan_run(PlanContext.of(p, "feed"), spec) if isinstance(x, RunPiece)]
    assert len(pieces) >= 6 and any((x.path.kind == 1).any() for x in pieces)
    for piece, shuffle in itertools.product(pieces, (True, False)):
        tau = np.concatenate([[-1.0, 0.0, piece.duration, piece.duration + 1.0], piece.t,
                              rng.uniform(0.0, piece.duration, 500)])
        if shuffle:
            rng.shuffle(tau)
        else:
            tau.sort()  # in time order, as the sampler walks them
        s = piece.arc_length_at(tau)
        k = piece.path.locate(s)
        q, de, tool = piece.sample(kin, tau)
        assert np.array_equal(q, kin.inverse(piece.path.frame(s, k)[0]), equal_nan=True)
        assert np.array_equal(de, piece.filament_at(s, k))
        assert np.array_equal(tool, np.full(len(tau), piece.tool))
    # a laser's power per path piece at NaN and infinite times: the piece searchsorted gives (the last)
    piece = max(pieces, key=lambda x: len(x.path.kind))
    piece = dataclasses.replace(piece, power=np.linspace(0.1, 1.0, len(piece.path.kind)))
    tau = np.array([np.nan, -np.inf, np.inf, -0.0, 0.5 * piece.duration])
    with np.errstate(invalid="ignore"):
        s = piece.arc_length_at(tau)
        k = piece.path.locate(s)
        q, de, tool = piece.sample(kin, tau)
    assert np.array_equal(tool, piece.power[k]) and tool[0] == 1.0
    assert np.array_equal(de, piece.filament_at(s, k), equal_nan=True)


def test_trajectory_piece_ranges_are_where_searchsorted_puts_each_time():
    """Trajectory.sample_at's split of a block of times among the pieces (from the pieces' starts
    found in the times, where they are in order) is numpy's searchsorted of every time among the
    starts, clipped to the first and last piece: with zero-length pieces, times on starts, before
    the start and past the end, in order and not."""
    rng = np.random.default_rng(4)
    for trial in range(300):
        durations = rng.choice([0.0, 0.001, 0.5, 2.0], size=int(rng.integers(1, 12)))
        traj = object.__new__(Trajectory)
        traj.pieces = [None] * len(durations)
        traj.starts = np.concatenate([[0.0], np.cumsum(durations)])
        end = traj.starts[-1]
        t = np.concatenate([rng.uniform(-0.5, end + 0.5, int(rng.integers(1, 40))), rng.choice(traj.starts, 3)])
        if trial % 3:
            t.sort()
        k = np.clip(np.searchsorted(traj.starts, t, side="right") - 1, 0, len(durations) - 1)
        got = np.full(len(t), -1)
        for i, lo, hi in traj._piece_ranges(t):
            assert hi > lo and (got[lo:hi] == -1).all()
            got[lo:hi] = i
        assert np.array_equal(got, k), trial


def _bed_points(p, rng, n):
    """n reachable points (n, 3) mm over the bed, the bottom half of the build height."""
    kin, bed = p.kinematics(), p.bed
    half = bed.radius if bed.shape == "circle" else 0.5 * min(bed.size_x, bed.size_y)
    pts = np.column_stack([rng.uniform(-0.7 * half, 0.7 * half, (4 * n, 2)),
                           rng.uniform(0.2, 0.5 * bed.max_height, 4 * n)])
    pts = pts[bed.contains_xy(pts[:, :2]) & kin.reachable(pts)]
    assert len(pts) >= n
    return pts[:n]


@pytest.mark.parametrize("name", ["delta_etitc", "fivebar_atlas", "linear_kossel", "delta_uady", "delta_espe_laser"])
def test_lines_planned_as_one_path_are_each_planned_alone(name):
    """plan_lines solves many straight travels laid end to end as one path, each in its own units:
    every move's pieces (grid, profile, duration, certificate) are what plan_run gives it alone,
    to rounding. Moves of a micron or less give no piece (dedupe's bound), as alone."""
    p = printer(name)
    kin = p.kinematics()
    rng = np.random.default_rng(7)
    pts = _bed_points(p, rng, 40)
    a, b = pts[:20], pts[20:].copy()
    b[3] = a[3] + [0.0005, 0.0, 0.0]  # shorter than dedupe's micron: nothing to plan
    b[4] = a[4] + [0.0, 0.004, 0.0]  # a few microns: planned
    b[5] = a[5] + [0.0, 0.0, 0.3]  # a lift
    feed = rng.uniform(20.0, 300.0, 20)
    layers = np.arange(20)
    batch = batch_mod.plan_lines(PlanContext.of(p, "feed"), a, b, feed, layers)
    for i in range(20):
        spec = runpath.RunSpec(np.array([a[i], b[i]]), feed[i : i + 1], np.zeros(1), 0.0, int(layers[i]))
        alone = topp.plan_run(PlanContext.of(p, "feed"), spec, kind="travel")
        assert len(batch[i]) == len(alone) == (0 if i == 3 else 1), i
        for got, want in zip(batch[i], alone):
            assert got.kind == "travel" and got.layer == i
            assert got.duration == pytest.approx(want.duration, rel=1e-9, abs=1e-12)
            assert got.active_time == pytest.approx(want.active_time, rel=1e-9, abs=1e-12)
            assert len(got.x) == len(want.x)
            assert np.allclose(got.x, want.x, rtol=0, atol=1e-9)
            assert np.allclose(got.xd, want.xd, rtol=1e-9, atol=1e-12)
            assert np.allclose(got.q_start, want.q_start, atol=1e-12) and np.allclose(got.q_end, want.q_end, atol=1e-12)
    # Trapezoid-style speed limit off: the joints alone bound the speed, still move by move.
    fast = batch_mod.plan_lines(PlanContext.of(p, "joints"), a[:6], b[:6], feed[:6], layers[:6])
    for i in (0, 4, 5):
        spec = runpath.RunSpec(np.array([a[i], b[i]]), feed[i : i + 1], np.zeros(1), 0.0, i)
        assert fast[i][0].duration == pytest.approx(topp.plan_run(PlanContext.of(p, "joints"), spec, kind="travel")[0].duration,
                                                    rel=1e-9)


def test_a_batch_of_lines_with_one_out_of_reach_raises_that_lines_error():
    """A move out of reach in a batch: each move is planned alone, so the error is the one that
    move's own plan raises (its layer and point), not a batch's."""
    p = printer("delta_etitc")
    kin = p.kinematics()
    pts = _bed_points(p, np.random.default_rng(3), 6)
    a, b = pts[:3], pts[3:].copy()
    b[1, 2] = 10 * p.bed.max_height
    with pytest.raises(UnreachableError, match="layer 11: point"):
        batch_mod.plan_lines(PlanContext.of(p, "feed"), a, b, np.full(3, 100.0), np.array([10, 11, 12]))


def _runs(p, rng, n):
    """n extrusion runs over the bed: zigzags of 3 to 30 segments with blended corners, feeds
    of 5 to 150 mm/s, an exact reversal (a stop), a width change (a stop on the filament),
    segments shorter than MERGE_LENGTH, one run without filament and one shorter than a micron."""
    specs = []
    anchors = _bed_points(p, rng, n)
    for k in range(n):
        m = int(rng.integers(3, 31))
        pts = anchors[k] + np.column_stack([np.cumsum(rng.uniform(-3, 3, (m + 1, 2)), axis=0), np.zeros(m + 1)])
        pts[0] = anchors[k]
        if k % 4 == 1:
            pts[3] = pts[1]  # back along the segment before: an exact reversal
        if k % 5 == 2:
            pts[2] = pts[1] + [0.005, 0.0, 0.0]  # shorter than MERGE_LENGTH
        e = 0.03 * np.linalg.norm(np.diff(pts, axis=0), axis=1)
        if k % 6 == 3:
            e[m // 2 :] *= 1.5  # a new extrusion width
        if k == 5:
            e[:] = 0.0  # a working move that pushes no filament
        feed = rng.choice([5.0, 40.0, 150.0], m)
        specs.append(runpath.RunSpec(pts, feed, e, 200.0, k))
    if n > 7:
        specs[7] = runpath.RunSpec(specs[7].points[:2].copy(), specs[7].feed[:1], np.array([0.4]), 200.0, 7)
        specs[7].points[1] = specs[7].points[0] + [0.0002, 0.0, 0.0]  # filament pushed at rest
    return specs


@pytest.mark.parametrize("name", ["delta_etitc", "fivebar_atlas", "linear_kossel", "delta_uady"])
def test_runs_planned_as_one_path_are_each_planned_alone(name):
    """plan_runs solves a chunk's runs laid end to end as one path, each in its own units and
    refined only within itself: every run's pieces (grid, profile, duration, certificate,
    filament, end poses) are what plan_run gives it alone, to rounding."""
    p = printer(name)
    kin = p.kinematics()
    specs = _runs(p, np.random.default_rng(5), 16)
    for speed_limit in ("feed", "machine"):
        batch = batch_mod.plan_runs(PlanContext.of(p, speed_limit), specs)
        for i, spec in enumerate(specs):
            alone = topp.plan_run(PlanContext.of(p, speed_limit), spec)
            assert [type(x).__name__ for x in batch[i]] == [type(x).__name__ for x in alone], i
            for got, want in zip(batch[i], alone):
                assert got.kind == want.kind and got.layer == i
                assert got.duration == pytest.approx(want.duration, rel=1e-9, abs=1e-12), i
                assert got.active_time == pytest.approx(want.active_time, rel=1e-9, abs=1e-12), i
                assert got.filament_total == pytest.approx(want.filament_total, rel=1e-12), i
                assert np.allclose(got.q_start, want.q_start, atol=1e-12) and np.allclose(got.q_end, want.q_end, atol=1e-12)
                if isinstance(want, RunPiece):
                    assert len(got.x) == len(want.x), i
                    assert np.allclose(got.x, want.x, rtol=0, atol=1e-9)
                    # the speeds to rounding (1e-9 where a limit switches), the durations to 1e-14
                    assert np.allclose(got.xd, want.xd, rtol=1e-7, atol=1e-12)
                    # xdd divides speed differences by a stage's width: rounding of the peak's order
                    assert np.allclose(got.xdd, want.xdd, rtol=0, atol=1e-6 * np.abs(want.xdd).max())
    kinds = {type(x).__name__ for pieces in batch for x in pieces}
    assert kinds == {"RunPiece", "FilamentPiece"}, kinds


def test_a_refined_run_in_a_batch_refines_only_itself(monkeypatch):
    """Refinement splits a failing stage and its neighbours; in a batch the neighbour across a
    join belongs to another run, which must keep the grid it has alone. The check is made to fail
    the first stage of the middle run (and nothing else): alone and in the batch, that run gets
    the same refined grid, and the run before it keeps its own."""
    p = printer("delta_etitc")
    kin = p.kinematics()
    specs = _runs(p, np.random.default_rng(5), 3)
    start = specs[1].points[0]
    real = stages.stage_maxima

    def failing_at_start(rp, x, *args, **kwargs):
        out = real(rp, x, *args, **kwargs)
        s = np.asarray(x) * rp.S
        first = np.linalg.norm(rp.path.evaluate(s[:-1]) - start, axis=1) < 1e-9
        first &= np.diff(s) > 0.75 * stages.MIN_STEP  # the grid's first stage (MIN_STEP), not its refined quarters
        per_stage = np.where(first, 2.0, out.per_stage)
        return stages.StageMaxima(out.velocity, out.acceleration, out.stage_v, out.stage_a, per_stage)

    monkeypatch.setattr(solver_mod, "stage_maxima", failing_at_start)
    alone = [topp.plan_run(PlanContext.of(p, "feed"), s) for s in specs]
    batch = batch_mod.plan_runs(PlanContext.of(p, "feed"), specs)
    inputs = [runpath._path_inputs(*topp._prepare(PlanContext.of(p), s, None), "feed") for s in specs]
    unrefined = [len(stages.grid(inp.path, inp.stop_at)) for inp in inputs]
    assert len(alone[1][0].x) == unrefined[1] + 6  # the first stage and the one after it, split in four
    assert [len(x[0].x) for x in alone] == [unrefined[0], unrefined[1] + 6, unrefined[2]]
    for got, want in zip(batch, alone):
        assert len(got[0].x) == len(want[0].x)
        assert got[0].duration == pytest.approx(want[0].duration, rel=1e-9)


def _segmented_arc(centre, r=1.0, m=20, turn=3.0):
    """An arc cut into m equal segments (a slicer's circle): its blend leaves lines of a few ulps."""
    th = np.linspace(0.0, turn, m + 1)
    return np.asarray(centre, float) + np.column_stack([r * np.cos(th), r * np.sin(th), np.zeros(m + 1)])


@pytest.mark.parametrize("speed_limit", ["feed", "machine"])
def test_a_width_change_on_a_finely_segmented_arc_is_taken_at_rest(speed_limit):
    """On an arc of equal segments each corner's blend takes half of every segment, leaving lines
    of a few ulps whose two joins are closer than the grid keeps apart: a width change (a stop)
    at the second join had no grid point, so the filament speed stepped by half at speed. The
    blend drops such lines; the run stops there, alone and wherever it sits in a batch."""
    p = printer("linear_kossel")
    kin = p.kinematics()
    pts = _segmented_arc([10.0, 0.0, 1.0])
    path = blend_polyline(pts, p.planning.blend_tolerance)
    assert np.all(np.diff(path.piece_start) > 1e-12)
    e = 0.03 * np.linalg.norm(np.diff(pts, axis=0), axis=1)
    e[10:] *= 1.5
    spec = runpath.RunSpec(pts, np.full(20, 40.0), e, 200.0, 0)
    other = runpath.RunSpec(_segmented_arc([-10.0, 5.0, 1.0], m=13), np.full(13, 40.0), np.full(13, 0.004), 200.0, 0)
    alone = topp.plan_run(PlanContext.of(p, speed_limit), spec)[0]
    jump = np.flatnonzero(np.abs(np.diff(alone.e_ratio)) > 0.01 * alone.e_ratio[1:])
    assert len(jump) == 1
    s_stop = alone.path.piece_start[jump[0] + 1]
    at = np.flatnonzero(np.abs(alone.x * alone.S - s_stop) < 1e-9)
    assert len(at) == 1 and alone.xd[at[0]] == 0.0
    batch = batch_mod.plan_runs(PlanContext.of(p, speed_limit), [other, spec])[1][0]
    assert batch.duration == pytest.approx(alone.duration, rel=1e-9)


def test_a_batch_of_runs_with_one_out_of_reach_raises_that_runs_error():
    """A run out of reach in a batch: each run then plans alone, so the error names that run's
    layer and point; of two such runs, the first in print order."""
    p = printer("delta_etitc")
    kin = p.kinematics()
    specs = _runs(p, np.random.default_rng(9), 6)
    bad = specs[4]
    pts = bad.points.copy()
    pts[2, 2] = 10 * p.bed.max_height
    specs[4] = runpath.RunSpec(pts, bad.feed, bad.e, bad.tool, 44)
    with pytest.raises(UnreachableError, match="layer 44: point"):
        batch_mod.plan_runs(PlanContext.of(p, "feed"), specs)
    # Two runs out of reach in different batches (one pushes no filament, so it is batched apart
    # and after the others): the first in print order is named, as planning each alone would.
    first = specs[1]
    pts = first.points.copy()
    pts[1, 2] = 10 * p.bed.max_height
    specs[1] = runpath.RunSpec(pts, first.feed, np.zeros(len(first.e)), first.tool, 41)
    specs.append(runpath.RunSpec(specs[0].points.copy(), specs[0].feed, np.zeros(len(specs[0].e)), 200.0, 50))
    with pytest.raises(UnreachableError, match="layer 41: point"):
        batch_mod.plan_runs(PlanContext.of(p, "feed"), specs)


def test_travels_planned_together_are_each_planned_alone():
    """plan_travels over many travels (lifts, joint-space moves, retracts, a z-hop, travels that
    do not move) gives every travel the pieces plan_travel gives it alone."""
    p = printer("delta_etitc")
    kin = p.kinematics()
    rng = np.random.default_rng(11)
    pts = _bed_points(p, rng, 40)
    pts[:, 2] = np.minimum(pts[:, 2], 8.0)
    jobs = []
    for k in range(20):
        a, b = pts[k], pts[20 + k]
        via = None
        if k % 5 == 1:
            via = np.array([a + [0, 0, 0.4], b + [0, 0, 0.4]])  # a slicer's z-hop
        if k % 7 == 3:
            b = a.copy()  # a retract and unretract in place
        if k % 6 == 2:
            b = a + [1.0, 0.5, 0.0]  # short: the straight move only
        jobs.append(dict(a=a, b=b, layer=k, printed_top=float(a[2]), retract=-0.8 * (k % 2), unretract=0.8 * (k % 2),
                         via=via, feed=float(rng.choice([5.0, 150.0]))))
    for speed_limit in ("feed", "machine"):
        together = travel.plan_travels(PlanContext.of(p, speed_limit), jobs)
        kinds = set()
        for job, got in zip(jobs, together):
            alone = travel.plan_travel(PlanContext.of(p, speed_limit), **job)
            assert [type(x).__name__ for x in got] == [type(x).__name__ for x in alone]
            kinds.update(type(x).__name__ for x in got)
            for x, y in zip(got, alone):
                assert x.duration == pytest.approx(y.duration, rel=1e-9, abs=1e-12)
                assert np.allclose(x.q_start, y.q_start, atol=1e-12) and np.allclose(x.q_end, y.q_end, atol=1e-12)
        # no joint-space travel under the feed limit; under the machine's, straight lines were faster here
        assert {"FilamentPiece", "RunPiece"} <= kinds and (speed_limit == "machine" or "JointMovePiece" not in kinds)
    # a travel that does not move has no motion piece: its retract and unretract, or nothing
    for k in (3, 10):
        assert [type(x).__name__ for x in together[k]] == (["FilamentPiece"] * 2 if k % 2 else []), k


def test_joint_moves_checked_together_are_each_checked_alone():
    """joint_moves_clear (one forward kinematics of every move's samples) agrees with
    joint_move_clear move by move, both ways: clear and not."""
    p = printer("delta_etitc")
    kin = p.kinematics()
    pts = _bed_points(p, np.random.default_rng(5), 16)
    moves = [travel._ruckig_move(PlanContext.of(p), *kin.inverse(np.array([pts[k], pts[8 + k]])), layer=0) for k in range(8)]
    z_min = np.array([0.0, 1e3, 0.0, 1e3, 0.0, 0.0, 1e3, 0.0]) + np.minimum(pts[:8, 2], pts[8:, 2]) - 0.1
    together = travel.joint_moves_clear(kin, moves, z_min)
    alone = [travel.joint_move_clear(kin, m, z) for m, z in zip(moves, z_min)]
    assert together.tolist() == alone
    assert True in alone and False in alone


def _ruckig_alone(p, q0, q1):
    """ruckig's rest-to-rest move q0 -> q1 from a calculator, input and output of its own (with the
    printer's torque limits, the move's own joint bounds and its joints in phase, as travel does)."""
    from deltaslice.planning.torque import travel_limits

    vel, acc, jerk = travel._ruckig_limits(PlanContext.of(p), 3)
    otg, inp, traj = ruckig.Ruckig(3), ruckig.InputParameter(3), ruckig.Trajectory(3)
    bounds = travel_limits(PlanContext.of(p), q0, q1)
    if bounds is not None:
        vel, acc = [float(v) for v in bounds[0][0]], [float(v) for v in bounds[1][0]]
        inp.synchronization = ruckig.Synchronization.Phase
    inp.current_position, inp.target_position = [float(v) for v in q0], [float(v) for v in q1]
    inp.current_velocity = inp.current_acceleration = inp.target_velocity = inp.target_acceleration = [0.0] * 3
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = vel, acc, jerk
    assert otg.calculate(inp, traj) in (ruckig.Result.Working, ruckig.Result.Finished)
    return traj


def test_joint_moves_made_one_after_another_are_each_made_alone(monkeypatch):
    """A batch's ruckig calculator, input and output, reused move after move, give every move
    exactly as ruckig plans it alone (a calculator, input and output of its own), down and up
    the bed; where a move keeps ruckig's object (no profile arrays), each keeps its own, not the
    one reused for the next move."""
    p = printer("delta_etitc")
    kin = p.kinematics()
    pts = _bed_points(p, np.random.default_rng(7), 16)
    ends = [kin.inverse(np.array([pts[k], pts[8 + k]])) for k in range(8)]
    batch = travel._JointMoves(PlanContext.of(p), 3)
    together = [batch.move(a, b, layer=k) for k, (a, b) in enumerate(ends)]
    alone = [_ruckig_alone(p, a, b) for a, b in ends]
    assert len({traj.duration for traj in alone}) == 8
    for k, (x, traj) in enumerate(zip(together, alone)):
        y = RuckigProfile.from_trajectory(traj)
        assert x.duration == traj.duration and x.layer == k
        for f in ("t_end", "p", "v", "a", "j", "pf"):
            np.testing.assert_array_equal(getattr(x.profile, f), getattr(y, f))
    monkeypatch.setattr(travel.RuckigProfile, "from_trajectory", classmethod(lambda cls, traj: None))
    kept = [batch.move(a, b, layer=0) for a, b in ends]
    assert [m.duration for m in kept] == [traj.duration for traj in alone]
    tau = np.linspace(0.0, alone[0].duration, 7)
    np.testing.assert_array_equal(kept[0].sample(kin, tau)[0], [alone[0].at_time(t)[0] for t in tau])


def test_stage_maxima_are_numpys_bounds_maxima_and_argmaxima():
    """The compiled stage-wise bounds, reduced in the same pass, against the bounds written in
    numpy and reduced by numpy (max, argmax: first of ties, first NaN; per stage max over the
    channels), bit for bit, with NaN derivatives and ties among them."""
    rng = np.random.default_rng(1)
    f = len(constraints.CHECK)
    for trial in range(200):
        n, dof = int(rng.integers(1, 50)), int(rng.integers(1, 5))
        dq, ddq = rng.normal(size=(n, f, dof)), rng.normal(size=(n, f, dof))
        xd, xdd = rng.uniform(0, 2, n + 1), rng.normal(size=n)
        if trial % 3 == 0:
            dq[rng.integers(0, n), rng.integers(0, f), rng.integers(0, dof)] = np.nan
        if trial % 5 == 0:
            dq = np.round(dq)  # equal bounds in several stages
        if trial % 7 == 0:
            dq[:, :, 0] = ddq[:, :, 0] = 0.0  # a channel that never moves: every stage ties at 0
        if trial % 11 == 0 and n > 2:
            dq[1], ddq[1], xd[1:3], xdd[1] = dq[0], ddq[0], xd[0:2], xdd[0]  # a stage the same as the first
        vmax, amax = rng.uniform(0.5, 2, dof), rng.uniform(0.5, 2, dof)
        w = np.maximum((xd[:-1] ** 2)[:, None] + ((xd[1:] ** 2) - (xd[:-1] ** 2))[:, None] * constraints.CHECK[None], 0.0)
        with np.errstate(invalid="ignore"):
            bounds = []
            for g in (np.abs(dq) * np.sqrt(w)[:, :, None] / vmax, np.abs(dq * xdd[:, None, None] + ddq * w[:, :, None]) / amax):
                bounds.append(g.max(axis=1) + 0.3125 * np.abs(g[:, 2:] - 2 * g[:, 1:-1] + g[:, :-2]).max(axis=1))
            bv, ba = bounds
            want = (bv.max(axis=0), ba.max(axis=0), bv.argmax(axis=0), ba.argmax(axis=0), np.maximum(bv, ba).max(axis=1))
        got = stages.stage_maxima(None, None, xd, xdd, vmax, amax, stage=(dq, ddq))
        for a, b in zip((got.velocity, got.acceleration, got.stage_v, got.stage_a, got.per_stage), want):
            assert np.array_equal(a, b, equal_nan=True), trial


def test_compiled_grid_quantities_are_their_numpy_forms():
    """The planner's small compiled passes against the numpy they replace, bit for bit, NaN
    derivatives included: the grid-point speed factor (|q'| over both sides of each grid point),
    the velocity cap on x_dot^2 from it, the stages with a limit active, and the rows in each move's own units (a / c, b / c^2)."""
    rng = np.random.default_rng(7)
    for trial in range(60):
        n, dof = int(rng.integers(0, 40)) if trial else 0, int(rng.integers(1, 5))
        dq, ddq = rng.normal(size=(n, 9, dof)), rng.normal(size=(n, 9, dof))
        if trial % 3 == 0 and n:
            dq[rng.integers(0, n), rng.choice([0, 4, 8]), rng.integers(0, dof)] = np.nan
        start, mid, end = (np.abs(dq[:, k]) for k in (0, 4, -1))
        want = np.zeros((n + 1, dof))
        want[:-1] = np.maximum(start, mid)
        want[1:] = np.maximum(want[1:], np.maximum(end, mid))
        assert np.array_equal(constraints.gridpoint_speed_factor(dq), want, equal_nan=True), trial
        # the velocity cap from it: zero factors (inf), NaN ones, feeds of zero, inf and NaN
        factor = want.copy()
        factor[rng.random(factor.shape) < 0.1] = 0.0
        vmax, S = rng.uniform(0.5, 2, dof), float(rng.uniform(1, 100))
        feed = rng.choice([0.0, np.inf, np.nan, 7.0, 30.0], n + 1, p=[0.1, 0.3, 0.05, 0.3, 0.25])
        with np.errstate(divide="ignore", invalid="ignore"):
            want_cap2 = np.minimum(np.min(vmax[None] / factor, axis=1), feed / S) ** 2
        got_cap2 = constraints.PathVelocityConstraint(vmax, feed, S, factor).cap2(None, None)
        assert np.array_equal(got_cap2, want_cap2, equal_nan=True), trial
        with np.errstate(divide="ignore", invalid="ignore"):  # numpy's broadcasting: one feed for all
            want_cap2 = np.minimum(np.min(vmax[None] / factor, axis=1), 7.0 / S) ** 2
        assert np.array_equal(constraints.PathVelocityConstraint(vmax, 7.0, S, factor).cap2(None, None), want_cap2, equal_nan=True)
        with pytest.raises(ValueError):  # and its refusals: a feed for another grid
            constraints.PathVelocityConstraint(vmax, feed[:-1] if n else np.ones(3), S, factor).cap2(None, None)
        if n == 0:
            continue
        sd, xdd = rng.uniform(0, 2, n + 1), rng.normal(size=n)
        cap2, amax = rng.uniform(0.5, 4, n + 1) * (1e6 if trial % 2 else 1.0), rng.uniform(0.5, 2, dof)  # 1e6: no speed cap active
        acc = np.abs(dq[:, 0] * xdd[:, None] + ddq[:, 0] * (sd[:-1] ** 2)[:, None]) / amax[None]
        want = (sd[:-1] ** 2 >= solver_mod.ACTIVE * cap2[:-1]) | (sd[1:] ** 2 >= solver_mod.ACTIVE * cap2[1:]) | (acc.max(axis=1) >= solver_mod.ACTIVE)
        got = np.empty(n, dtype=bool)
        solver_mod._active_kernel(dq, ddq, xdd, sd, cap2, amax, got)
        assert np.array_equal(got, want), trial
        x = np.concatenate([[0.0], np.sort(rng.uniform(0, 1, n - 1)), [1.0]]) if n > 1 else np.array([0.0, 1.0])
        con = constraints.StageAccelerationConstraint(amax, constraints.CHECK, (dq, ddq))
        unit = rng.uniform(0.5, 30, n + 1)
        a, b = con.rows(None, x)
        sa, sb = con.rows(None, x, unit)
        c = unit[:, None]
        assert np.array_equal(sa, a / c, equal_nan=True) and np.array_equal(sb, b / (c * c), equal_nan=True), trial
    # a NaN channel beside one at its limit: numpy's max over the channels is NaN, not active
    dq, ddq = np.ones((1, 9, 2)), np.zeros((1, 9, 2))
    dq[0, 0, 0] = np.nan
    got = np.ones(1, dtype=bool)
    solver_mod._active_kernel(dq, ddq, np.array([1.0]), np.array([0.0, 0.0]), np.array([1.0, 1.0]), np.array([1.0, 1.0]), got)
    assert not got[0]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_travel_jobs_are_their_moves_definition(seed):
    """Each travel job's keywords (one-move travels take a scalar path) against their definition:
    from where the tool is to the last move's end, through the points between, the negative and
    positive filament summed apart, and the largest feed of a move that moves (None where none
    moves or that feed is not positive). Travels of one and of several moves, moves of zero
    length, retracts and unretracts."""
    from deltaslice.planning.jobs import split_runs, toolpath_jobs
    from deltaslice.toolpath import Role, ToolpathBuilder

    rng = np.random.default_rng(seed)
    b = ToolpathBuilder((0.0, 0.0, 5.0))
    b.new_layer(0.3)
    here = np.array([0.0, 0.0, 5.0])
    for _ in range(int(rng.integers(1, 6))):
        for _ in range(int(rng.integers(1, 4))):  # a travel of one to three moves
            step = rng.choice([0.0, 1.0]) * rng.normal(0, 10, 3)
            here = here + step
            b.add(here, float(rng.choice([5.0, 40.0, 120.0])), float(rng.choice([-0.8, 0.0, 0.5])), 0, Role.TRAVEL)
        pts = here + np.cumsum(rng.normal(0, 2, (3, 3)), axis=0)
        b.add(pts, 30.0, 0.1, 1, Role.PERIMETER)
        here = pts[-1]
    tp = b.build()
    travels = [(job.i, job.j, job.made) for job in toolpath_jobs(tp, split_runs(tp), False, made=True) if job.kind == "travel"]
    assert travels
    for i, j, job in travels:
        pos = tp.start if i == 0 else tp.xyz[i - 1]
        e = tp.e[i:j]
        moves = np.linalg.norm(tp.xyz[i:j] - np.concatenate([[pos], tp.xyz[i : j - 1]]), axis=1) > 0
        feed = max([0.0, *tp.feed[i:j][moves].tolist()])
        np.testing.assert_array_equal(job["a"], pos)
        np.testing.assert_array_equal(job["b"], tp.xyz[j - 1])
        np.testing.assert_array_equal(job["via"], tp.xyz[i : j - 1])
        assert job["retract"] == e[e < 0].sum() and job["unretract"] == e[e > 0].sum()
        assert job["feed"] == (feed if feed > 0 else None)
        assert job["layer"] == int(tp.layer[min(j, len(tp) - 1)])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 40))
def test_stepped_grid_points_are_numpys_in_order(seed, n):
    """The grid's geometric points (one compiled pass) are the joins and the masked broadcast of
    every join plus and minus the steps below 0.999 of half its interval, the same values, and
    come in order (zero-length and long intervals included)."""
    rng = np.random.default_rng(seed)
    offsets = np.cumsum([stages.MIN_STEP * stages.GROWTH**k for k in range(8)])
    # lengths drawn at random, and ones whose half is a step or just past it (within the 0.999)
    edge = 2 * offsets[rng.integers(0, 8, n)] * rng.choice([1.0, 1.0005, 1.002], n)
    length = np.where(rng.random(n) < 0.5, rng.choice([0.0, 0.01, 0.05, 0.3, 2.0, 40.0], n) * rng.uniform(0.5, 1.5, n), edge)
    joins = np.concatenate([[0.0], np.cumsum(length)])
    half = np.diff(joins) / 2
    inside = offsets[None, :] < half[:, None] * 0.999
    want = np.concatenate([joins, (joins[:-1, None] + offsets[None, :])[inside], (joins[1:, None] - offsets[None, :])[inside]])
    out = np.full(len(joins) + 2 * n * len(offsets), np.nan)
    got = out[: stages._stepped_points(joins, offsets, out)]
    assert np.all(np.diff(got) >= 0)
    np.testing.assert_array_equal(got, np.sort(want))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), units=st.integers(1, 12))
def test_unit_profiles_are_each_units_numpy_profile(seed, units):
    """_solve_units' per-unit pass against numpy a unit at a time, bit for bit: x from 0 to 1 in
    the unit's length, speed and acceleration scaled to it, time from 0 by np.cumsum (a unit of
    one stage and a zero first stage included); the active time to rounding. Each unit's rows are
    where the next unit's start."""
    rng = np.random.default_rng(seed)
    stages = rng.integers(1, 30, units)
    at = np.concatenate([[0], np.cumsum(stages)]).astype(np.int64)
    n = int(at[-1])
    s = np.concatenate([[0.0], np.cumsum(rng.uniform(0, 3, n))])
    lengths = s[at[1:]] - s[at[:-1]] + rng.choice([0.0, 1e-3], units)
    sd, xdd = rng.uniform(0, 2, n + 1), rng.normal(size=n)
    dt = rng.uniform(0, 0.1, n) * (rng.random(n) > 0.1)
    active = rng.random(n) > 0.3
    L = float(rng.uniform(1, 500))
    x, xd, t = (np.full(n + units, np.nan) for _ in range(3))
    acc, busy = np.full(n, np.nan), np.full(units, np.nan)
    batch_mod._unit_profiles(s, sd, xdd, dt, active, at, lengths, L, x, xd, acc, t, busy)
    for r in range(units):
        g0, g1, o = int(at[r]), int(at[r + 1]), int(at[r]) + r
        want_x = (s[g0 : g1 + 1] - s[g0]) / lengths[r]
        want_x[0], want_x[-1] = 0.0, 1.0
        scale = L / lengths[r]
        np.testing.assert_array_equal(x[o : o + g1 - g0 + 1], want_x)
        np.testing.assert_array_equal(xd[o : o + g1 - g0 + 1], sd[g0 : g1 + 1] * scale)
        np.testing.assert_array_equal(acc[g0:g1], xdd[g0:g1] * scale)
        np.testing.assert_array_equal(t[o : o + g1 - g0 + 1], np.concatenate([[0.0], np.cumsum(dt[g0:g1])]))
        assert busy[r] == pytest.approx(dt[g0:g1][active[g0:g1]].sum(), rel=1e-12, abs=1e-15)
    assert not np.isnan(x).any() and not np.isnan(xd).any() and not np.isnan(t).any() and not np.isnan(acc).any()


@pytest.mark.parametrize("name", ["delta_etitc", "linear_kossel"])
def test_the_filaments_rows_once_give_the_same_solution(name):
    """The compiled solver takes the filament's acceleration rows at one fraction of each stage
    (they are the same at every fraction): those columns are the full rows' columns of
    ``channels``, the repeated ones equal, and the solver's speeds, accelerations and controllable
    sets are the same bit for bit, with and without per-move units."""
    p, path, rp = _run_path(name)
    x = stages.grid(path) / path.length
    amax = p.planned_limits().acceleration[: rp.dof]
    con = constraints.StageAccelerationConstraint(amax, constraints.EVAL, rp.stage_derivatives(x, constraints.EVAL))
    f, dof = len(constraints.EVAL), rp.dof
    cap2 = np.full(len(x), 50.0)
    for unit in (None, np.random.default_rng(2).uniform(0.5, 3.0, len(x))):
        a, b = con.rows(rp, x, unit)
        a1, b1 = con.rows(rp, x, unit, last_once=True)
        ch = con.channels(True)
        assert len(ch) == f * dof - f + 1 and ch.tolist()[:dof] == list(range(dof))
        keep = [k * dof + j for k in range(f) for j in range(dof) if not (k and j == dof - 1)]
        assert np.array_equal(a1, a[:, keep]) and np.array_equal(b1, b[:, keep])
        for k in range(1, f):
            assert np.array_equal(a[:, k * dof + dof - 1], a[:, dof - 1]) and np.array_equal(b[:, k * dof + dof - 1], b[:, dof - 1])
        ds = np.diff(x) if unit is None else np.diff(x) * unit[:-1]
        full = solver_mod.fast_solve(a, b, -np.tile(amax, f), np.tile(amax, f), cap2, ds, interpolation=False)
        once = solver_mod.fast_solve(a1, b1, -amax[ch], amax[ch], cap2, ds, interpolation=False)
        assert all(np.array_equal(u, v, equal_nan=True) for u, v in zip(full, once))


def test_the_samplers_walk_is_searchsorted_from_any_start():
    """The sampler's search for a sample's stage and piece walks from the previous answer and
    bisects once it is more than a few steps away: from every start index, for values inside,
    on, before and after a sorted array with repeated values (and NaN, which sorts last), it
    gives numpy's clipped searchsorted."""
    from deltaslice.planning.blend import WALK, _last_at_or_below_from

    rng = np.random.default_rng(8)
    a = np.sort(np.concatenate([rng.uniform(0, 10, 60), [3.0, 3.0, 3.0]]))
    n_max = len(a) - 1
    values = np.concatenate([a, rng.uniform(-1, 11, 40), [np.nan, -np.inf, np.inf]])
    want = np.clip(np.searchsorted(a, values, side="right") - 1, 0, n_max - 1)
    for j in range(len(a)):
        got = [_last_at_or_below_from(a, float(v), n_max, j) for v in values]
        assert got == want.tolist(), j
    assert len(a) > 4 * WALK  # starts far from the answer bisect
    tail = np.concatenate([a, [np.nan] * 3])  # NaN at the end; starts before it
    want = np.clip(np.searchsorted(tail, values, side="right") - 1, 0, len(tail) - 2)
    for j in range(len(a)):
        assert [_last_at_or_below_from(tail, float(v), len(tail) - 1, j) for v in values] == want.tolist(), j


def _polyline(rng, kind: int) -> np.ndarray:
    """A run's polyline (at least two points, no segment under dedupe's micron) with the corners
    blending treats apart: sharp and gentle turns (0), collinear points and exact reversals (1),
    and segments short enough for two set-backs to meet (2)."""
    n = int(rng.integers(2, 9))
    if kind == 0:
        pts = np.column_stack([rng.uniform(-20, 20, (n, 2)), rng.uniform(0, 3, n)])
    elif kind == 1:
        steps = rng.choice([-1.0, 0.0, 1.0], size=(n - 1, 2)) * rng.uniform(0.5, 8.0, (n - 1, 1))
        pts = np.vstack([[0.0, 0.0, 1.0], np.column_stack([np.cumsum(steps, axis=0), np.ones(n - 1)])])
    else:
        ang = np.cumsum(rng.uniform(0.1, 0.6, n))
        pts = np.column_stack([np.cos(ang), np.sin(ang), np.ones(n)]) * rng.uniform(0.01, 0.2)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 2e-3])
    pts = pts[keep]
    return pts if len(pts) >= 2 else np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]])


def _reference_blend(points, tolerance):
    """Blending one polyline with numpy alone, as the planner did before blend_runs (cf0ef8f):
    the oracle the compiled layout is held to, bit for bit. -> (BlendedPath, stops (j,))."""
    seg = np.diff(points, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    d = seg / seg_len[:, None]
    m = len(seg)
    din, dout = d[:-1], d[1:]
    cos_t = np.clip(np.einsum("ij,ij->i", din, dout), -1.0, 1.0)
    turn = np.arccos(cos_t)
    blended = (turn > 1e-6) & (turn <= np.pi - 1e-3)
    half = turn / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        sb_tol = np.where(turn > np.pi - 1e-3, 0.0, tolerance * np.tan(half) / (1 / np.cos(half) - 1))
        setback = np.where(blended, np.minimum(sb_tol, 0.5 * np.minimum(seg_len[:-1], seg_len[1:])), 0.0)
        radius = np.where(blended, setback / np.tan(half), np.inf)
        perp = dout - cos_t[:, None] * din
        pn = np.linalg.norm(perp, axis=1)
        normal = np.where(pn[:, None] > 1e-12, perp / pn[:, None], 0.0)
    sb_start, sb_end = np.concatenate([[0.0], setback]), np.concatenate([setback, [0.0]])
    n = 2 * m - 1
    kind = np.tile(np.array([0, 1], dtype=np.int8), m)[:n]
    lengths = np.empty(n)
    lengths[0::2] = seg_len - sb_start - sb_end
    lengths[1::2] = np.where(blended, np.where(np.isfinite(radius), radius, 0.0) * turn, 0.0)
    p0, d0, nrm, rad = np.empty((n, 3)), np.empty((n, 3)), np.zeros((n, 3)), np.full(n, np.inf)
    p0[0::2], p0[1::2] = points[:-1] + sb_start[:, None] * d, points[1:-1] - setback[:, None] * din
    d0[0::2], d0[1::2] = d, din
    nrm[1::2], rad[1::2] = normal, radius
    segment = np.repeat(np.arange(m), 2)[1:]
    keep = lengths > 1e-12
    path = BlendedPath(np.concatenate([[0.0], np.cumsum(lengths[keep])]), kind[keep], p0[keep], d0[keep], nrm[keep],
                       rad[keep], segment[keep])
    j = path.joins()
    k = path.locate(j)
    dot = np.einsum("ij,ij->i", path.frame(j, k - 1)[1], path.frame(j, k)[1])
    return path, j[dot < 1 - 1e-9]


def _reference_path_inputs(poly, tol, speed_limit):
    """_path_inputs with numpy alone, one run, as before _path_inputs_many (cf0ef8f)."""
    path, stop_at = _reference_blend(poly.points, tol)
    e_ratio = (poly.e / np.linalg.norm(np.diff(poly.points, axis=0), axis=1))[path.segment]
    jump = np.zeros(len(e_ratio), dtype=bool)
    jump[1:] = np.abs(np.diff(e_ratio)) > 0.01 * np.maximum(np.abs(e_ratio[1:]), np.abs(e_ratio[:-1]))
    # between the stops at a width change, the stretch's mean filament per mm (since issue 48)
    lengths = np.diff(path.piece_start)
    stretch = np.cumsum(np.concatenate([[True], jump[1:]])) - 1
    total = np.bincount(stretch, weights=lengths)
    mean = np.bincount(stretch, weights=e_ratio * lengths) / np.where(total > 0, total, 1.0)
    e_ratio = np.where(total[stretch] > 0, mean[stretch], e_ratio)
    cum_e = np.concatenate([[0.0], np.cumsum(e_ratio * lengths)])
    extruder = bool(np.any(poly.e != 0))
    seg_feed = poly.feed if speed_limit == "feed" else np.full(len(poly.feed), np.inf)
    prev = np.maximum(path.segment - 1, 0)
    piece_feed = np.where(path.kind == 1, np.minimum(seg_feed[path.segment], seg_feed[prev]), seg_feed[path.segment])
    if extruder and len(path.kind) > 1:
        stop_at = np.concatenate([stop_at, path.piece_start[1:-1][jump[1:]]])
    return path, e_ratio, cum_e, extruder, piece_feed, stop_at


_PATH_FIELDS = ("piece_start", "kind", "p0", "d0", "normal", "radius", "segment")


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_runs_blended_together_are_each_blended_alone_bit_for_bit(seed):
    """blend_runs lays many polylines end to end and computes their corners in one pass, the
    vertices where one run ends and the next starts included: every run's pieces and stops must be
    those of blending it alone (no value of a neighbour may leak in), and those of blending it
    with numpy alone as the planner did before (the same arithmetic, bit for bit)."""
    rng = np.random.default_rng(seed)
    polys = [_polyline(rng, int(rng.integers(0, 3))) for _ in range(int(rng.integers(1, 6)))]
    tols = rng.uniform(0.005, 0.3, len(polys))
    starts = np.concatenate([[0], np.cumsum([len(p) for p in polys])])
    together = blend_runs(np.concatenate(polys), starts, tols)
    fields = _PATH_FIELDS
    for r, (pts, tol) in enumerate(zip(polys, tols)):
        alone = blend_runs(pts, np.array([0, len(pts)]), np.array([tol]))
        a, b = together.path(r), alone.path(0)
        for f in fields:
            assert np.array_equal(getattr(a, f), getattr(b, f)) and getattr(a, f).dtype == getattr(b, f).dtype, (r, f)
        assert np.array_equal(together.stops(r), alone.stops(0))
        want, stops = _reference_blend(pts, tol)
        for f in fields:
            assert np.array_equal(getattr(a, f), getattr(want, f)) and getattr(a, f).dtype == getattr(want, f).dtype, (r, f)
            assert np.array_equal(getattr(blend_polyline(pts, tol), f), getattr(want, f))
        assert np.array_equal(together.stops(r), stops)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_blend_breaks_are_where_the_tangent_turns(seed):
    """The stops blend_runs reports against the path itself: at every join, the unit tangents at
    the end of the piece before and the start of the piece after (evaluate, order 1); a stop
    where they differ (an exact reversal), none where the path stays tangent-continuous."""
    rng = np.random.default_rng(seed)
    pts = _polyline(rng, int(rng.integers(0, 3)))
    runs = blend_runs(pts, np.array([0, len(pts)]), np.array([0.05]))
    path = runs.path(0)
    j = path.joins()
    k = path.locate(j)
    dot = np.einsum("ij,ij->i", path.evaluate(j, 1, k - 1), path.evaluate(j, 1, k))
    assert np.array_equal(runs.stops(0), j[dot < 1 - 1e-9])
    assert not runs.breaks[0]
    d = np.diff(pts, axis=0)
    d /= np.linalg.norm(d, axis=1)[:, None]
    reversals = int((np.einsum("ij,ij->i", d[:-1], d[1:]) < np.cos(np.pi - 1e-3)).sum())
    assert len(runs.stops(0)) == reversals


@pytest.mark.parametrize("speed_limit", ["feed", "machine"])
def test_path_inputs_of_many_runs_are_each_runs_own(speed_limit):
    """_path_inputs_many (what plan_runs prepares a chunk's runs with) against _path_inputs of one
    run at a time, bit for bit: runs with and without filament, a width change inside a run
    (a stop), an exact reversal (a stop) and a run of one segment, side by side."""
    rng = np.random.default_rng(3)
    polys = []
    for kind in (0, 1, 2, 0, 1):
        pts = _polyline(rng, kind)
        m = len(pts) - 1
        e = 0.03 * np.linalg.norm(np.diff(pts, axis=0), axis=1) * (kind != 1)
        e[m // 2 :] *= 1.5 if kind == 0 else 1.0
        polys.append(runpath._Polyline(pts, rng.uniform(20, 80, m), e, None))
    polys.append(runpath._Polyline(np.array([[0.0, 0.0, 1.0], [-10.0, 0.0, 1.0], [0.0, 0.0, 1.0]]), np.full(2, 40.0),
                                np.full(2, 0.3), None))
    polys.append(runpath._Polyline(np.array([[1.0, 2.0, 1.0], [3.0, 2.0, 1.0]]), np.full(1, 40.0), np.zeros(1), None))
    tols = rng.uniform(0.01, 0.2, len(polys))
    many = runpath._path_inputs_many(polys, tols, speed_limit)
    assert sum(len(x.stop_at) > 0 for x in many) >= 2
    assert any(np.any(x.path.kind == 1) for x in many)
    for poly, tol, got in zip(polys, tols, many):
        for want in (runpath._path_inputs(poly, tol, speed_limit), None):
            if want is None:  # the numpy arithmetic of one run at a time, as before the batch
                path, e_ratio, cum_e, extruder, piece_feed, stop_at = _reference_path_inputs(poly, tol, speed_limit)
            else:
                path, e_ratio, cum_e, extruder = want.path, want.e_ratio, want.cum_e, want.extruder
                piece_feed, stop_at = want.piece_feed, want.stop_at
            assert got.extruder == extruder
            for f, v in (("e_ratio", e_ratio), ("cum_e", cum_e), ("piece_feed", piece_feed), ("stop_at", stop_at)):
                assert np.array_equal(getattr(got, f), v), f
            for f in _PATH_FIELDS:
                assert np.array_equal(getattr(got.path, f), getattr(path, f)), f


def test_locate_is_numpys_searchsorted():
    """BlendedPath.locate (compiled, each search from the answer before) against the numpy it
    replaces, clip(searchsorted(piece_start, s, side="right") - 1, 0, pieces - 1): arc lengths
    in order and not, exactly on piece starts, zero-length pieces (repeated starts), before
    the path, past its end, NaN and infinities; any shape, a scalar for a scalar."""
    rng = np.random.default_rng(2)
    for trial in range(2000):
        k = int(rng.integers(1, 40))
        starts = np.concatenate([[0.0], np.cumsum(rng.choice([0.0, 0.5, 1.0, 3.0], k))])
        path = BlendedPath(starts, np.zeros(k, np.int8), np.zeros((k, 3)), np.zeros((k, 3)), np.zeros((k, 3)),
                           np.full(k, np.inf), np.arange(k))
        n = int(rng.integers(0, 60))
        s = rng.uniform(-1, starts[-1] + 1, n)
        if trial % 2:
            s = np.sort(s)
        if n and trial % 3 == 0:
            s[rng.integers(0, n, 3)] = rng.choice(starts, 3)
        if n and trial % 5 == 0:
            s[rng.integers(0, n)] = rng.choice([np.nan, np.inf, -np.inf])
        want = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, k - 1)
        assert np.array_equal(path.locate(s), want), trial
        assert np.array_equal(path.locate(s.reshape(-1, 1)), want.reshape(-1, 1)), trial
        if n:
            got = path.locate(s[0])
            assert isinstance(got, np.integer) and got == want[0], trial
