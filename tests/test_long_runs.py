"""Long prints in bounded memory: a long run planned window by window (joined at speed, not at
rest), and a trajectory whose pieces are spooled to disk.

The windows are made small here (a few hundred segments) so the tests stay fast; the planner's
defaults are thousands (``deltaslice.planning.windows_mod.LONG_RUN``, ``WINDOW``, ``LOOKAHEAD``).
"""

from __future__ import annotations

import dataclasses
import pickle
import tracemalloc

import numpy as np
import pytest

from deltaslice import load_printer
from deltaslice.planning import plan, topp
from deltaslice.planning import runpath
from deltaslice.planning import solver as solver_mod
from deltaslice.planning import windows as windows_mod
from deltaslice.planning.context import PlanContext
from deltaslice.planning.spool import PieceSpool
from deltaslice.planning.runpath import RunSpec
from deltaslice.planning.stages import run_stage_maxima
from deltaslice.planning.topp import plan_run
from deltaslice.samples import Samples
from deltaslice.toolpath import Role, ToolpathBuilder


def spiral(n: int, z0: float = 0.3, r: float = 20.0, per_rev: int = 400, pitch: float = 0.2):
    """A wavy helix of n segments (a spiral vase's wall): points (n+1, 3) mm, filament per segment."""
    th = np.arange(n + 1) * 2 * np.pi / per_rev
    rr = r + 0.5 * np.sin(25 * th)
    pts = np.c_[rr * np.cos(th), rr * np.sin(th), z0 + pitch * th / (2 * np.pi)]
    e = 0.03 * np.linalg.norm(np.diff(pts, axis=0), axis=1)
    return pts, e


def _whole(kin, printer, spec, mode, monkeypatch):
    with monkeypatch.context() as m:
        m.setattr(windows_mod, "LONG_RUN", 10**9)
        return plan_run(PlanContext.of(printer, mode), spec)


@pytest.mark.parametrize("name,mode", [("linear_kossel", "feed"), ("delta_etitc", "machine"), ("fivebar_atlas", "machine")])
def test_a_long_run_in_windows_joins_at_speed_and_matches_the_whole_run(name, mode, small_windows, monkeypatch):
    printer = load_printer(name)
    kin = printer.kinematics()
    pts, e = spiral(1100)
    spec = RunSpec(pts, np.full(len(e), 40.0), e, 1.0, 0)
    windows = plan_run(PlanContext.of(printer, mode), spec)
    (whole,) = _whole(kin, printer, spec, mode, monkeypatch)
    assert len(windows) >= 5
    # Durations within the planner's optimality budget of the whole run planned at once.
    total = sum(p.duration for p in windows)
    assert abs(total / whole.duration - 1) < 1e-3, (total, whole.duration)
    # The filament is the whole run's (half of each cut segment on either side): the ratio per mm
    # times the path driven; a cut halves its segment, so the blends next to it may be a hair
    # shorter, and the path a hair longer.
    assert sum(p.filament_total for p in windows) == pytest.approx(whole.filament_total, rel=1e-5)
    # Starts and ends at rest; inside, consecutive windows meet at the same point and speed.
    assert windows[0].xd[0] == 0 and windows[-1].xd[-1] == 0
    vmax = printer.limits.velocity[: printer.n_joints]
    amax = printer.limits.acceleration[: printer.n_joints]
    for a, b in zip(windows[:-1], windows[1:]):
        end = a.path.evaluate(np.array([a.S]))[0]
        start = b.path.evaluate(np.array([0.0]))[0]
        np.testing.assert_allclose(end, start, atol=1e-9)
        np.testing.assert_allclose(a.q_end, b.q_start, atol=1e-9)
        v_end, v_start = a.xd[-1] * a.S, b.xd[0] * b.S
        assert v_end > 1.0  # not a stop
        assert v_end == pytest.approx(v_start, rel=1e-12)
    # Every window keeps every joint's limits on its continuous motion.
    for p in windows:
        assert run_stage_maxima(p, kin, vmax, amax).worst <= 1 + 1e-6


def test_a_window_that_cannot_start_that_fast_makes_the_previous_one_slow_down(small_windows, monkeypatch):
    printer = load_printer("linear_kossel")
    kin = printer.kinematics()
    pts, e = spiral(900)
    spec = RunSpec(pts, np.full(len(e), 40.0), e, 1.0, 0)
    real = windows_mod._plan_polyline
    calls, refused = [], []

    def strict_third_window(*args, v_start=0.0, cap=None, **kw):
        # The third window's first plan refuses to start faster than 5 mm/s.
        calls.append(v_start)
        if len(calls) == 3:
            refused.append(v_start)
            raise solver_mod._StartTooFast(5.0)
        return real(*args, v_start=v_start, cap=cap, **kw)

    monkeypatch.setattr(windows_mod, "_plan_polyline", strict_third_window)
    pieces = plan_run(PlanContext.of(printer, "feed"), spec)
    assert refused and refused[0] > 5.0, "the refusal was never exercised"
    # The second window was planned again to end at 5 mm/s, and the third starts there.
    v = [p.xd[-1] * p.S for p in pieces]
    assert 4.99 < v[1] <= 5.0
    assert pieces[2].xd[0] * pieces[2].S == pytest.approx(v[1], rel=1e-12)
    assert sum(p.filament_total for p in pieces) == pytest.approx(sum(p.filament_total for p in _whole(kin, printer, spec, "feed", monkeypatch)), rel=1e-5)


def test_window_memory_does_not_grow_with_the_run(small_windows):
    printer = load_printer("linear_kossel")
    kin = printer.kinematics()
    peaks = []
    for n in (700, 2100):
        pts, e = spiral(n)
        spec = RunSpec(pts, np.full(len(e), 40.0), e, 1.0, 0)
        tracemalloc.start()
        # iter_run hands out each window's piece as it is planned: keep only the last one
        for _piece, _done in topp.iter_run(PlanContext.of(printer, "feed"), spec):
            pass
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < 1.3 * peaks[0], peaks


def test_a_long_run_is_not_copied_while_its_windows_are_planned(monkeypatch):
    """What a long run holds besides the window being planned grows by the arc length at every
    vertex (8 bytes a segment), not by copies of its polyline (points, feed and filament: 40 bytes
    a segment each time): measured between the windows, on runs of 12,000 and 36,000 segments."""
    monkeypatch.setattr(windows_mod, "LONG_RUN", 3000)
    monkeypatch.setattr(windows_mod, "WINDOW", 2000)
    monkeypatch.setattr(windows_mod, "LOOKAHEAD", 300)
    monkeypatch.setattr(windows_mod, "LOOKAHEAD_MM", 5.0)
    printer = load_printer("linear_kossel")
    kin = printer.kinematics()
    held = []
    for n in (3600, 12000, 36000):  # the first warms the caches up
        pts, e = spiral(n)
        spec = RunSpec(pts, np.full(len(e), 40.0), e, 1.0, 0)
        tracemalloc.start()
        between = []
        for piece, _done in topp.iter_run(PlanContext.of(printer, "feed"), spec):
            del piece
            between.append(tracemalloc.get_traced_memory()[0])
        tracemalloc.stop()
        held.append(max(between))
    per_segment = (held[2] - held[1]) / (36000 - 12000)
    assert per_segment < 16, per_segment


@pytest.mark.parametrize("size", [1, 7, 199, 5000])
def test_a_long_runs_windows_are_the_same_however_its_stretches_come(size, small_windows, monkeypatch):
    """The windows see the run's polyline a stretch at a time (_Held): whatever the stretches' size
    (1 segment, 7, a window, all of it), every window is planned from the same polyline (cut
    segments split at their middles, half the filament on each side), tolerance, start speed and
    cap, bit for bit, and the pieces are the same."""
    printer = load_printer("linear_kossel")
    kin = printer.kinematics()
    pts, e = spiral(1000)
    rng = np.random.default_rng(4)
    poly = runpath._Polyline(pts, rng.uniform(20, 50, 1000), e, rng.uniform(0, 1, 1000))
    spec = RunSpec(pts, poly.feed, e, 1.0, 0)
    real = windows_mod._plan_polyline

    def windows(stretch):
        calls = []

        def record(ctx, spec_, p, tol, kind, v_start=0.0, cap=None):
            calls.append((p, tol, v_start, cap))
            return real(ctx, spec_, p, tol, kind, v_start=v_start, cap=cap)

        monkeypatch.setattr(windows_mod, "_plan_polyline", record)
        parts = ((poly.part(a, min(a + stretch, 1000)), 0.05) for a in range(0, 1000, stretch))
        pieces = [p for p, _done in windows_mod._iter_windows(PlanContext.of(printer, "feed"), spec, parts, "run")]
        return calls, pieces

    want, want_pieces = windows(1000)
    got, got_pieces = windows(size)
    assert len(want) >= 5 and len(got) == len(want)
    # the cuts: each window but the last is capped at a vertex that is a split segment's middle
    for (p, _tol, _v, cap) in want[:-1]:
        v = cap[0]
        np.testing.assert_array_equal(p.points[v], 0.5 * (p.points[v - 1] + p.points[v + 1]))
        assert p.e[v - 1] == p.e[v]
    for w, g in zip(want, got):
        for name in ("points", "feed", "e", "power"):
            assert np.array_equal(getattr(w[0], name), getattr(g[0], name)), name
        assert w[1:] == g[1:]
    assert [p.duration for p in got_pieces] == [p.duration for p in want_pieces]
    assert sum(p.filament_total for p in got_pieces) == pytest.approx(sum(p.filament_total for p in want_pieces), rel=1e-12)


def test_dedupe_hands_back_a_polyline_with_nothing_to_drop():
    """A run with no segment under a micron is not copied (a spiral vase's million segments)."""
    pts, e = spiral(50)
    feed = np.full(50, 30.0)
    out = topp.dedupe(pts, feed, e)
    assert out[0] is pts and out[1] is feed and out[2] is e
    pts2 = np.insert(pts, 10, pts[10] + 1e-4, axis=0)
    e2 = np.insert(e, 10, 0.002)
    kept = topp.dedupe(pts2, np.full(51, 30.0), e2)
    assert len(kept[0]) == 51 and kept[2].sum() == pytest.approx(e2.sum())


def _two_layer_spiral_toolpath():
    b = ToolpathBuilder((0.0, 0.0, 2.0))
    pts, e = spiral(700)
    b.new_layer(0.3)
    b.add(pts[:1], 100, 0, 0, Role.TRAVEL)
    b.add(pts[1:], 30, e, 1, Role.PERIMETER)
    b.add([[5.0, 0.0, pts[-1, 2] + 0.2]], 100, -1.0, 0, Role.TRAVEL)
    b.add([[5.0, 5.0, pts[-1, 2] + 0.2]], 30, 0.2, 1, Role.INFILL)
    return b.build()


def test_a_spooled_trajectory_samples_exactly_as_one_in_memory(small_windows):
    printer = load_printer("linear_kossel")
    tp = _two_layer_spiral_toolpath()
    mem = plan(tp, printer, workers=1, spool=False)
    disk = plan(tp, printer, workers=1, spool=True)
    assert isinstance(disk.pieces, PieceSpool) and isinstance(mem.pieces, list)
    assert len(disk.pieces) == len(mem.pieces) > 5
    assert disk.duration == mem.duration
    assert disk.piece_counts() == mem.piece_counts()
    assert disk.active_fraction == mem.active_fraction
    assert disk.events == mem.events
    a, b = mem.samples(), disk.samples()
    for name in ("t", "q", "e", "tool"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # read back in any order, not only in sequence
    for i in (len(mem.pieces) - 1, 0, 3, -2):
        assert disk.pieces[i].duration == mem.pieces[i].duration
    with pytest.raises(IndexError):
        disk.pieces[len(mem.pieces)]



@pytest.mark.parametrize("spool", [False, True])
def test_samples_from_forked_workers_are_the_blocks_sampled_here(spool, small_windows, monkeypatch):
    """Sampling workers give the same blocks, in order, as sampling in this process; from a spool
    too, whose file the forked workers read at their own offsets (seek-then-read would race on
    the shared file position and unpickle garbage)."""
    from deltaslice.planning import trajectory as trajectory_module

    from deltaslice import pool
    from deltaslice.planning import spool as spool_module

    monkeypatch.setattr(trajectory_module, "PARALLEL_BLOCKS", 2)
    monkeypatch.setattr(trajectory_module, "TASK_BLOCKS", 1)
    monkeypatch.setattr(spool_module, "BATCH_PIECES", 1)  # a batch per piece: every block reads the file
    traj = plan(_two_layer_spiral_toolpath(), load_printer("linear_kossel"), workers=1, spool=spool)
    assert isinstance(traj.pieces, PieceSpool) == spool
    here = list(traj.iter_samples(block=64))
    forked = list(traj.iter_samples(block=64, workers=3))
    # transient blocks are views of buffers the workers write again: right as each one is taken
    # (as the writers use them) they are the same blocks
    transient = [Samples(*(np.copy(getattr(b, name)) for name in ("t", "q", "e", "tool")))
                 for b in traj.iter_samples(block=64, workers=3, transient=True)]
    assert len(here) == len(forked) == len(transient) > 6 * 3  # more tasks than the workers hold ahead
    for a, b, c in zip(here, forked, transient):
        for name in ("t", "q", "e", "tool"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
            np.testing.assert_array_equal(getattr(a, name), getattr(c, name))
    # and a task's blocks come as one transient block: the same samples in the same order
    monkeypatch.setattr(trajectory_module, "TASK_BLOCKS", 3)
    tasks = [Samples(*(np.copy(getattr(b, name)) for name in ("t", "q", "e", "tool")))
             for b in traj.iter_samples(block=64, workers=3, transient=True)]
    assert [len(b) for b in tasks[:-1]] == [3 * 64] * (len(tasks) - 1) and len(tasks) > 6
    for name in ("t", "q", "e", "tool"):
        np.testing.assert_array_equal(np.concatenate([getattr(a, name) for a in here]),
                                      np.concatenate([getattr(c, name) for c in tasks]))
    assert not pool._INHERITED  # the parent keeps no reference for the next pool


def test_workers_plan_around_a_long_run_exactly_as_one_process(small_windows):
    """A long run planned in the main process while the pool plans the runs before and after it."""
    printer = load_printer("linear_kossel")
    b = ToolpathBuilder((0.0, 0.0, 2.0))
    pts, e = spiral(700)
    b.new_layer(0.3)
    for k in range(4):  # short runs, then the spiral, then more short runs
        b.add([[-10.0 + 5 * k, -25.0, 0.3]], 100, 0, 0, Role.TRAVEL)
        b.add([[-10.0 + 5 * k, -20.0, 0.3]], 30, 0.2, 1, Role.INFILL)
    b.add(pts[:1], 100, 0, 0, Role.TRAVEL)
    b.add(pts[1:], 30, e, 1, Role.PERIMETER)
    for k in range(4):
        b.add([[-10.0 + 5 * k, 25.0, pts[-1, 2]]], 100, 0, 0, Role.TRAVEL)
        b.add([[-10.0 + 5 * k, 20.0, pts[-1, 2]]], 30, 0.2, 1, Role.INFILL)
    tp = b.build()
    one = plan(tp, printer, workers=1)
    two = plan(tp, printer, workers=2)
    assert len(one.pieces) == len(two.pieces) > 20
    assert two.duration == one.duration and two.events == one.events
    a, c = one.samples(), two.samples()
    np.testing.assert_array_equal(a.q, c.q)
    np.testing.assert_array_equal(a.e, c.e)


def test_the_spool_writes_pieces_in_batches_and_reads_them_back_in_order(monkeypatch):
    """Small pieces (travels, filament moves) are pickled a batch at a time, not one call and
    two index entries each; what is still waiting is counted, indexed and read like the rest."""
    from deltaslice.planning import spool as spool_module
    from deltaslice.planning.pieces import FilamentPiece

    monkeypatch.setattr(spool_module, "BATCH_PIECES", 50)
    pieces = [FilamentPiece(np.zeros(3), 0.1 * (k + 1), 20.0, 500.0, k) for k in range(120)]
    sp = PieceSpool()
    for p in pieces:
        sp.append(p)  # one job at a time, as the planner puts them away
    assert len(sp._first) - 1 == 2 and len(sp) == 120  # two batches of 50 written, 20 waiting
    assert [p.layer for p in sp] == list(range(120))  # iteration writes what waits first
    assert len(sp._first) - 1 == 3
    assert sp[119].amount == pytest.approx(12.0) and sp[-120].layer == 0
    np.testing.assert_array_equal(np.asarray(sp.durations), [p.duration for p in pieces])
    sp.close()


def _same_piece(a, b):
    """a and b hold the same values bit for bit, b's arrays as the compiled kernels take them."""
    assert type(a) is type(b)
    for f in dataclasses.fields(a):
        u, v = getattr(a, f.name), getattr(b, f.name)
        if dataclasses.is_dataclass(u):
            _same_piece(u, v)
        elif isinstance(u, np.ndarray):
            assert (v.dtype, v.shape, v.tobytes()) == (u.dtype, u.shape, u.tobytes()), f.name
            assert v.flags.c_contiguous and v.flags.writeable, f.name
        else:
            assert v == u, f.name


def test_a_piece_batch_pickles_its_pieces_bit_for_bit():
    """Planning workers hand their pieces back as a PieceBatch, the runs' arrays a column a
    field: every piece comes back the same, in its job's list, and samples the same. Runs with
    laser power beside runs without, and runs sharing a path (kept shared), too."""
    from deltaslice.planning.pieces import PieceBatch, RunPiece

    printer = load_printer("linear_kossel")
    kin = printer.kinematics()
    b = ToolpathBuilder((0.0, 0.0, 2.0))
    b.new_layer(0.3)
    for k in range(4):
        b.add([[-10.0 + 5 * k, -25.0, 0.3]], 100, -0.5 * (k % 2), 0, Role.TRAVEL)
        b.add([[-10.0 + 5 * k, -20.0, 0.3], [-8.0 + 5 * k, -18.0, 0.3], [-8.0 + 5 * k, -12.0, 0.3]], 30, 0.2, 1,
              Role.INFILL)
    pieces = list(plan(b.build(), printer, workers=1).pieces)
    assert {type(p).__name__ for p in pieces} >= {"RunPiece", "FilamentPiece"}
    runs = [i for i, p in enumerate(pieces) if type(p) is RunPiece]
    assert len(runs) >= 4
    for i in runs[::2]:  # laser power on every other run, None on the rest
        pieces[i] = dataclasses.replace(pieces[i], power=np.linspace(0.2, 1.0, len(pieces[i].e_ratio)))
    groups = [pieces[:3], [], pieces[3:]]
    back = pickle.loads(pickle.dumps(PieceBatch(groups))).groups
    assert [len(g) for g in back] == [len(g) for g in groups]
    tau = np.linspace(0.0, 1.0, 7)
    for a, c in zip(pieces, [p for g in back for p in g]):
        _same_piece(a, c)
        for u, v in zip(a.sample(kin, tau * a.duration), c.sample(kin, tau * a.duration)):
            np.testing.assert_array_equal(u, v)
    # F-ordered 2-D fields come back C-ordered; a field 1-D in one run and 0-d in another, as it is
    fortran = [dataclasses.replace(pieces[i], path=dataclasses.replace(
        pieces[i].path, p0=np.asfortranarray(pieces[i].path.p0), d0=np.asfortranarray(pieces[i].path.d0)))
        for i in runs]
    fortran = [dataclasses.replace(p, nominal_feed=np.array(30.0) if k == 1 else np.array([30.0]))
               for k, p in enumerate(fortran)]
    back = pickle.loads(pickle.dumps(PieceBatch([fortran]))).groups[0]
    for a, c in zip(fortran, back):
        _same_piece(a, c)
    # a field of two dtypes, or of two shapes past the first axis, comes back as it is too
    mixed = [dataclasses.replace(p, power=np.ones(len(p.e_ratio), np.int64 if k == 1 else np.float64),
                                 nominal_feed=np.ones((len(p.e_ratio), 2 if k == 1 else 1)))
             for k, p in enumerate(pieces[i] for i in runs)]
    back = pickle.loads(pickle.dumps(PieceBatch([mixed]))).groups[0]
    for a, c in zip(mixed, back):
        _same_piece(a, c)
    shared = [pieces[runs[0]], dataclasses.replace(pieces[runs[1]], path=pieces[runs[0]].path)]
    back = pickle.loads(pickle.dumps(PieceBatch([shared]))).groups[0]
    assert back[0].path is back[1].path
    for a, c in zip(shared, back):
        _same_piece(a, c)


def test_a_true_spiral_vase_from_gcode_plans_in_windows(tmp_path, monkeypatch):
    """A spiral vase as a slicer writes it (Z rising along every move, coordinates to 3 decimals,
    E to 5, a ;LAYER_CHANGE a turn): one run of 20,000 segments, planned window by window on
    linear_kossel with the default window sizes. It failed ("tower2 acceleration reaches
    14106.82 % of its limit between grid points ... after 3 grid refinements") until the forward
    pass's shrink was held to each stage's range of u. Its print time is within 0.05 % of
    planning the run whole."""
    from deltaslice.gcode import read_gcode

    n, per_turn = 20000, 2000
    k = np.arange(1, n + 1)
    th = 2 * np.pi * k / per_turn
    r = 30 + 0.8 * np.sin(100 * th)
    x, y, z = r * np.cos(th), r * np.sin(th), 0.2 + 0.1 * k / per_turn
    e = np.cumsum(np.hypot(np.diff(x, prepend=30.0), np.diff(y, prepend=0.0)) * 0.45 * 0.1 / (np.pi * 1.75**2 / 4))
    lines = ["G21", "G90", "M82", "G92 E0", "G1 Z0.2 F7800", "G1 X30 Y0", "G1 F1800"]
    for i in range(n):
        if i % per_turn == 0:
            lines += [";LAYER_CHANGE", f";Z:{z[i]:.3f}"]
        lines.append(f"G1 X{x[i]:.3f} Y{y[i]:.3f} Z{z[i]:.4f} E{e[i]:.5f}")
    path = tmp_path / "spiral.gcode"
    path.write_text("\n".join(lines) + "\n")
    printer = load_printer("linear_kossel")
    tp = read_gcode(path, printer=printer)
    windowed = plan(tp, printer, workers=1)
    runs = [p for p in windowed.pieces if p.kind == "run"]
    assert len(runs) >= 3  # planned in windows, joined without stopping
    for a, b in zip(runs, runs[1:]):
        assert a.xd[-1] * a.S == pytest.approx(b.xd[0] * b.S, rel=1e-9) and a.xd[-1] > 0
    monkeypatch.setattr(windows_mod, "LONG_RUN", 10**9)
    whole = plan(tp, printer, workers=1)
    assert windowed.duration == pytest.approx(whole.duration, rel=5e-4)
