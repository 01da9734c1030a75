"""Planner invariants: limits never exceeded at the output rate, the path followed
within the blend tolerance, extrusion conserved, grid convergence, travel clearance."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from deltaslice import UnreachableError, load_printer
from deltaslice import planning
from deltaslice.planning import plan, split_runs, stages
from deltaslice.planning.blend import blend_polyline
from deltaslice.planning.pieces import JointMovePiece
from deltaslice.planning.trapezoid import corner_violations, plan_firmware, plan_safe
from deltaslice.toolpath import Role, ToolpathBuilder
from trajectories import finite_differences

MARGIN = 1.02  # toppra enforces limits at grid points; samples may exceed by discretisation only


def layered_part(z0, dz, n_layers, size, filament_per_mm=0.02, center=(0.0, 0.0), retract=1.0):
    """Square perimeters plus a circle per layer, with retracts on travels."""
    b = ToolpathBuilder((center[0], center[1], z0 + 2))
    cx, cy = center
    th = np.linspace(0, 2 * np.pi, 73)
    for k in range(n_layers):
        z = z0 + k * dz
        b.new_layer(z)
        h = size / 2
        sq = np.array([[-h, -h], [h, -h], [h, h], [-h, h], [-h, -h]]) + [cx, cy]
        b.add([[sq[0, 0], sq[0, 1], z]], 100, 0, 0, Role.TRAVEL)
        b.add([[sq[0, 0], sq[0, 1], z]], 30, retract, 0, Role.RETRACT)
        seg = np.linalg.norm(np.diff(sq, axis=0), axis=1)
        b.add(np.c_[sq[1:], np.full(4, z)], 30, seg * filament_per_mm, 1, Role.PERIMETER)
        b.add([[sq[-1, 0], sq[-1, 1], z]], 30, -retract, 0, Role.RETRACT)
        r = size / 4
        circ = np.c_[cx + r * np.cos(th), cy + r * np.sin(th)]
        b.add([[circ[0, 0], circ[0, 1], z]], 100, 0, 0, Role.TRAVEL)
        b.add([[circ[0, 0], circ[0, 1], z]], 30, retract, 0, Role.RETRACT)
        seg = np.linalg.norm(np.diff(circ, axis=0), axis=1)
        b.add(np.c_[circ[1:], np.full(72, z)], 45, seg * filament_per_mm, 1, Role.INFILL)
        b.add([[circ[-1, 0], circ[-1, 1], z]], 30, -retract, 0, Role.RETRACT)
    return b.build()


def laser_part(size):
    b = ToolpathBuilder((0, 0, 0))
    b.new_layer(0.0)
    h = size / 2
    sq = np.array([[-h, -h], [h, -h], [h, h], [-h, h], [-h, -h]])
    b.add([[sq[0, 0], sq[0, 1], 0]], 80, 0, 0, Role.TRAVEL)
    b.add(np.c_[sq[1:], np.zeros(4)], 15, 0, 0.8, Role.LASER)
    b.add([[0, 0, 0]], 80, 0, 0, Role.TRAVEL)
    b.add([[h / 2, 0, 0], [h / 2, h / 2, 0]], 15, 0, 1.0, Role.LASER)
    return b.build()


CASES = {
    "delta_etitc": lambda: layered_part(0.5, 0.4, 3, 40),
    "delta_ucb": lambda: layered_part(0.25, 0.2, 3, 30),
    "delta_uady": lambda: layered_part(0.25, 0.2, 2, 40),
    "fivebar_atlas": lambda: layered_part(0.3, 0.3, 2, 40),
    "linear_kossel": lambda: layered_part(0.3, 0.2, 2, 40),
    "delta_espe_laser": lambda: laser_part(40),
}


@pytest.fixture(scope="module", params=sorted(CASES))
def planned(request):
    printer = load_printer(f"printers/{request.param}.toml")
    toolpath = CASES[request.param]()
    out = {}
    for mode in ("feed", "machine"):
        traj = plan(toolpath, printer, speed_limit=mode, workers=1)
        out[mode] = (traj, traj.samples())
    return printer, toolpath, out


def _distance_to_polyline(points, poly):
    """points (n,3), poly (m+1,3) -> (n,) distance to the nearest segment."""
    a, b = poly[:-1], poly[1:]
    ab = b - a
    ll = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
    ap = points[:, None, :] - a[None]
    t = np.clip(np.einsum("nij,ij->ni", ap, ab) / ll, 0, 1)
    d = ap - t[..., None] * ab[None]
    return np.sqrt(np.einsum("nij,nij->ni", d, d)).min(axis=1)


def test_joint_limits_never_exceeded(planned):
    printer, _, out = planned
    rate = printer.planning.output_rate
    for mode, (traj, s) in out.items():
        v, a = finite_differences(s, rate)
        rv = np.abs(v).max(axis=0) / printer.limits.velocity[:printer.n_joints]
        ra = np.abs(a).max(axis=0) / printer.limits.acceleration[:printer.n_joints]
        assert rv.max() <= MARGIN, f"{printer.name} {mode}: joint velocity at {100 * rv.max():.1f} % of its limit"
        assert ra.max() <= MARGIN, f"{printer.name} {mode}: joint acceleration at {100 * ra.max():.1f} % of its limit"
        kin = printer.kinematics()
        assert kin.within_joint_limits(s.q).all()


def test_tool_limits_and_extrusion(planned):
    printer, toolpath, out = planned
    if printer.is_laser:
        for traj, s in out.values():
            # The laser fires at both powers the toolpath asks for, and at nothing else.
            assert set(np.unique(s.tool)) == {0.0, 0.8, 1.0}
        return
    rate = printer.planning.output_rate
    for mode, (traj, s) in out.items():
        ev = np.abs(np.diff(s.e)) * rate
        on = s.tool[1:] > 0
        assert ev[on].max() <= printer.tool.max_filament_speed * MARGIN, mode
        # Monotone while extruding; total is the slicer's filament per mm times the path
        # driven: blending corners shortens the path (and the filament) by under 1 %.
        assert np.all(np.diff(s.e)[on] >= -1e-12)
        runs = [p for p in traj.pieces if p.kind == "run"]
        driven = sum(float(np.dot(p.e_ratio, np.diff(p.path.piece_start))) for p in runs)
        assert s.e[-1] == pytest.approx(driven, abs=1e-9)
        assert 0.99 * toolpath.extruded_length() <= s.e[-1] <= toolpath.extruded_length() + 1e-9


def test_pieces_write_every_row_they_are_given(planned):
    """sample_into (the sampler's per-piece call, into a block's rows) writes every row of the
    slices it is given and nothing beside them: NaN-filled buffers come back finite inside, NaN
    outside; the ends are the piece's (rest poses, its filament; times past them hold them), and
    each sample of the trajectory is its piece's plus the filament before it, also written into
    given arrays (a sampler's slot). On every printer's pieces, the trapezoid planner's included."""
    printer, toolpath, out = planned
    kin = printer.kinematics()
    J = printer.n_joints
    trajs = [traj for traj, _ in out.values()] + [plan(toolpath, printer, planner="trapezoid", workers=1)]
    kinds = set()
    for traj in trajs:
        for k, piece in enumerate(traj.pieces):
            kinds.add(piece.kind)
            tau = np.concatenate([[-0.5, 0.0], np.linspace(0.0, piece.duration, 40), [piece.duration, piece.duration + 0.5]])
            q, de, tool = np.full((len(tau) + 4, J), np.nan), np.full(len(tau) + 4, np.nan), np.full(len(tau) + 4, np.nan)
            piece.sample_into(kin, tau, q[2:-2], de[2:-2], tool[2:-2])
            for a in (q, de, tool):
                assert np.isfinite(a[2:-2]).all(), f"{printer.name} {piece.kind} {k}: a row left unwritten"
                assert np.isnan(a[:2]).all() and np.isnan(a[-2:]).all(), f"{printer.name} {piece.kind} {k}: written outside"
            np.testing.assert_allclose(q[2:4], [piece.q_start, piece.q_start], atol=1e-9)
            np.testing.assert_allclose(q[-4:-2], [piece.q_end, piece.q_end], atol=1e-9)
            np.testing.assert_allclose(de[[2, 3, -4, -3]], [0.0, 0.0, piece.filament_total, piece.filament_total], atol=1e-9)
            t = traj.starts[k] + tau[2:-2]
            inside = (t > traj.starts[k]) & (t < traj.starts[k] + piece.duration)
            s = traj.sample_at(t[inside])
            ref_q, ref_de, ref_tool = piece.sample(kin, t[inside] - traj.starts[k])
            np.testing.assert_array_equal(s.q, ref_q)
            np.testing.assert_array_equal(s.e, traj.e_offsets[k] + ref_de)
            np.testing.assert_array_equal(s.tool, ref_tool)
        # a sampler's slot: the trajectory's samples written into given arrays, the same values
        t = np.linspace(-0.1, traj.duration + 0.1, 501)
        want = traj.sample_at(t)
        out = (np.full((len(t), J), np.nan), np.full(len(t), np.nan), np.full(len(t), np.nan))
        got = traj.sample_at(t, out=out)
        assert all(np.shares_memory(a, b) for a, b in zip((got.q, got.e, got.tool), out))
        for a, b in ((got.q, want.q), (got.e, want.e), (got.tool, want.tool)):
            np.testing.assert_array_equal(a, b)
    assert {"run", "travel", "trapezoid"} <= kinds and ("retract" in kinds or printer.is_laser)


def test_path_followed_within_blend_tolerance(planned):
    printer, toolpath, out = planned
    kin = printer.kinematics()
    tol = printer.planning.blend_tolerance
    from deltaslice.planning import split_runs

    for mode, (traj, s) in out.items():
        run_pieces = [p for p in traj.pieces if p.kind == "run"]
        ranges = split_runs(toolpath)
        assert len(run_pieces) == len(ranges)
        for piece, (i, j) in zip(run_pieces, ranges):
            tau = np.linspace(0, piece.duration, 400)
            q, _, _ = piece.sample(kin, tau)
            pts = kin.forward(q)
            poly = np.concatenate([(toolpath.start if i == 0 else toolpath.xyz[i - 1])[None], toolpath.xyz[i:j]])
            dev = _distance_to_polyline(pts, poly)
            assert dev.max() <= tol + 1e-6, f"{printer.name} {mode}: deviation {dev.max():.4f} mm"


def test_travels_clear_the_part(planned):
    """Every travel stays in the reachable volume; a straight one never dips below the lower of
    its two ends, so it cannot dig into what is printed under either; a joint-space one clears
    the printed part by half the lift. Checked on 400 samples per travel."""
    printer, toolpath, out = planned
    kin = printer.kinematics()
    lift = printer.tool.travel_lift(printer.planning)
    for mode, (traj, _) in out.items():
        top, checked = 0.0, 0
        for piece in traj.pieces:
            q, _, _ = piece.sample(kin, np.linspace(0, piece.duration, 400))
            p = kin.forward(q)
            if piece.kind == "run":
                top = max(top, p[:, 2].max())
                continue
            if piece.kind != "travel":
                continue
            checked += 1
            assert np.isfinite(p).all() and kin.reachable(p).all(), mode
            if isinstance(piece, JointMovePiece):  # a curve in Cartesian space: clearance is half the lift
                assert p[:, 2].min() >= top + 0.5 * lift - 1e-6, mode
            else:
                assert p[:, 2].min() >= min(p[0, 2], p[-1, 2]) - 1e-6, mode
        assert checked >= 2, f"{printer.name} {mode}: the case must have travels"


def test_machine_limit_is_faster_and_feed_never_slower_than_baseline(planned):
    printer, toolpath, out = planned
    feed_traj, _ = out["feed"]
    machine_traj, _ = out["machine"]
    assert machine_traj.duration <= feed_traj.duration * 1.0001
    safe = plan(toolpath, printer, planner="trapezoid", speed_limit="feed", workers=1)  # also from and to rest
    assert corner_violations(safe)["violating_samples"] == 0
    assert feed_traj.duration <= safe.duration * 1.001, (feed_traj.duration, safe.duration)


def test_every_trajectory_starts_and_parks_at_rest(planned):
    printer, toolpath, out = planned
    trajs = [traj for traj, _ in out.values()] + [plan(toolpath, printer, planner="trapezoid", workers=1)]
    for traj in trajs:
        s = traj.samples()
        # at rest to 1e-12 rad: where torque limits leave no joint-space link (delta_ucb's level arms)
        # the link is a straight line, its ends through forward and inverse kinematics
        assert np.allclose(s.q[0], printer.rest_pose, atol=1e-12) and np.allclose(s.q[-1], printer.rest_pose, atol=1e-12)
        assert traj.pieces[0].kind == "travel" and traj.pieces[-1].kind == "travel"
        # the first working sample comes after the tool has reached the toolpath's start
        p = printer.kinematics().forward(traj.pieces[0].q_end[None])[0]
        assert p[2] >= toolpath.start[2] - 1e-9


def test_grid_refinement_changes_duration_under_one_percent(monkeypatch):
    printer = load_printer("printers/delta_etitc.toml")
    toolpath = layered_part(0.5, 0.4, 1, 40)
    coarse = plan(toolpath, printer, speed_limit="machine", workers=1)
    monkeypatch.setattr(stages, "REFINE", 10)
    fine = plan(toolpath, printer, speed_limit="machine", workers=1)
    runs = lambda t: sum(p.duration for p in t.pieces if p.kind == "run")  # noqa: E731
    assert sum(len(p.x) for p in fine.pieces if p.kind == "run") > 9 * sum(len(p.x) for p in coarse.pieces if p.kind == "run")
    assert abs(runs(fine) - runs(coarse)) / runs(fine) < 0.01


def test_active_constraint_fraction_is_high():
    printer = load_printer("printers/delta_etitc.toml")
    traj = plan(layered_part(0.5, 0.4, 2, 40), printer, speed_limit="machine", workers=1)
    assert traj.active_fraction > 0.9


def test_parallel_equals_serial():
    printer = load_printer("printers/delta_ucb.toml")
    toolpath = layered_part(0.25, 0.2, 6, 30)
    a = plan(toolpath, printer, workers=1)
    b = plan(toolpath, printer, workers=2)
    assert a.duration == pytest.approx(b.duration, rel=1e-12)


@pytest.mark.parametrize("name", ["delta_ucb", "delta_espe_laser"])
def test_jobs_named_by_their_moves_are_the_jobs_themselves(name):
    """The planning workers get each job as the moves it is made from (its i, j and the printed
    top before it) and make its arguments from the toolpath they inherit: the same RunSpec
    (a laser's too, with its power) and the same travel keywords as the parent makes: the first
    travel from the toolpath's start, those between runs from the run before, the last after the
    last run, the printed top before each."""
    from dataclasses import fields

    printer = load_printer(f"printers/{name}.toml")
    toolpath = CASES[name]()
    if name == "delta_ucb":  # a last travel after the last run, and z-hop travels of several moves
        b = ToolpathBuilder(tuple(toolpath.start))
        b.new_layer(0.25)
        b.add(toolpath.xyz, toolpath.feed, toolpath.e, toolpath.tool, toolpath.role)
        b.add([[5.0, 5.0, 2.0], [8.0, 5.0, 2.0], [8.0, 5.0, 0.85]], 100, [-1.0, 0, 0], 0, Role.TRAVEL)
        toolpath = b.build()
    laser = printer.tool.takes_laser_power
    ranges = split_runs(toolpath, laser)
    full = list(planning.jobs.toolpath_jobs(toolpath, ranges, laser, made=True))
    named = list(planning.jobs.toolpath_jobs(toolpath, ranges, laser))
    kinds = [job.kind for job in full]
    assert kinds.count("run") == len(ranges) and kinds[0] == "travel" and "travel" in kinds[1:-1]
    assert (kinds[-1] == "travel") == (name == "delta_ucb")
    for whole, ref in zip(full, named, strict=True):
        assert (whole.kind, whole.start, whole.end, whole.i, whole.j) == (ref.kind, ref.start, ref.end, ref.i, ref.j)
        assert ref.made is None
        made, job = ref.arguments(toolpath, laser), whole.arguments(None, laser)
        assert type(made) is type(job)
        if whole.kind == "run":
            for f in fields(job):
                np.testing.assert_array_equal(getattr(made, f.name), getattr(job, f.name), err_msg=f.name)
        else:
            assert made.keys() == job.keys()
            for key in job:
                np.testing.assert_array_equal(made[key], job[key], err_msg=key)


def test_a_long_run_first_is_planned_here_from_its_moves(monkeypatch):
    """A long run is planned in the main process (its windows put away one by one), from the moves
    its job names, also where it is the print's first job (no travel, so no chunk, before it: the
    main process has planned nothing yet); the same trajectory with the workers as in one process,
    and the main process keeps no toolpath once planned."""
    printer = load_printer("printers/delta_ucb.toml")
    b = ToolpathBuilder((0.0, 0.0, 0.25))
    b.new_layer(0.25)
    t = np.linspace(0, 4 * np.pi, 121)[1:]
    b.add(np.c_[10 * np.cos(t) - 10, 10 * np.sin(t), np.full(len(t), 0.25)], 30, np.full(len(t), 0.01), 1,
          Role.PERIMETER)
    for k in range(12):
        b.add([[15.0 + k, 5.0, 0.25]], 100, 0, 0, Role.TRAVEL)
        b.add([[15.0 + k, 10.0, 0.25], [16.0 + k, 10.0, 0.25]], 30, [0.02, 0.01], 1, Role.PERIMETER)
    toolpath = b.build()
    assert split_runs(toolpath)[0][0] == 0
    monkeypatch.setattr(planning.scheduler, "is_long", lambda moves: moves > 50)  # the first run, not the short ones
    pools = plan(toolpath, printer, workers=2)
    assert planning.scheduler._WORKER.toolpath is None
    alone = plan(toolpath, printer, workers=1)
    assert pools.duration == alone.duration and len(pools.pieces) == len(alone.pieces)
    np.testing.assert_array_equal(pools.samples().q, alone.samples().q)


def test_unreachable_point_is_named_before_any_output(tmp_path):
    printer = load_printer("printers/delta_ucb.toml")
    b = ToolpathBuilder((0, 0, 1))
    b.new_layer(0.25)
    b.add([[0, 0, 0.25], [200, 0, 0.25]], 30, [0, 1.0], [0, 1], Role.PERIMETER)
    with pytest.raises(UnreachableError, match=r"layer 0: x = 200.00, y = 0.00"):
        plan(b.build(), printer)


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("runs_before", [0, 4])
def test_the_reach_check_speaks_first_while_workers_plan(workers, runs_before):
    """The reach check runs while the workers start on the first runs (plan's rest links): a
    point out of reach in the first chunk is reported by the check (layer, point, why, whether it
    would fit centred), not by the chunk that met it first: among the first chunk's first jobs,
    planned in this process before the workers fork (to load the kernels), or after them, which
    the workers plan."""
    printer = load_printer("printers/delta_ucb.toml")
    good = layered_part(0.25, 0.2, 24, 30)
    ranges = split_runs(good)
    cut = ranges[runs_before][0] if runs_before else 0
    b = ToolpathBuilder((0, 0, 1))
    b.new_layer(0.25)
    b.add(good.xyz[:cut], good.feed[:cut], good.e[:cut], good.tool[:cut], good.role[:cut])
    b.add([[0, 0, 0.25], [200, 0, 0.25]], 30, [0, 1.0], [0, 1], Role.PERIMETER)
    b.add(good.xyz[cut:], good.feed[cut:], good.e[cut:], good.tool[cut:], good.role[cut:])  # all within reach
    bad = b.build()
    n_jobs = 2 * len(split_runs(bad)) + 1
    chunk = planning.scheduler.chunk_size(n_jobs)
    # the bad run's job (a travel before each run) among the first jobs, or past them in the first chunk
    assert (2 * runs_before + 1 < planning.scheduler.WARM_UP_JOBS) == (runs_before == 0) and 2 * runs_before + 1 < chunk
    with pytest.raises(UnreachableError, match=r"x = 200.00, y = 0.00, z = 0.25 mm is out of reach of delta_ucb"):
        plan(bad, printer, workers=workers)


def test_the_chunks_in_flight_are_four_a_worker_and_the_next(monkeypatch):
    """Memory is bounded by the chunks in flight: four per worker handed out and not yet put away
    (one more once the next is handed out, before the oldest is), the first chunk among them."""
    import deltaslice.planning as planning

    monkeypatch.setattr(planning.scheduler, "CHUNK_MAX", 2)  # many chunks from a small part
    pool_futures, state = set(), {"out": 0, "peak": 0}
    real_start, real_drain = planning.scheduler.start_pool, planning.scheduler._drain_one

    def counting_pool(*args, **kwargs):
        pool = real_start(*args, **kwargs)
        real_submit = pool.submit

        def submit(*a, **k):
            future = real_submit(*a, **k)
            pool_futures.add(future)
            state["out"] += 1
            state["peak"] = max(state["peak"], state["out"])
            return future

        pool.submit = submit
        return pool

    def counting_drain(queue, *args):
        from_pool = queue[0][1] in pool_futures
        done = real_drain(queue, *args)
        state["out"] -= from_pool
        return done

    monkeypatch.setattr(planning.scheduler, "start_pool", counting_pool)
    monkeypatch.setattr(planning.scheduler, "_drain_one", counting_drain)
    printer = load_printer("printers/delta_etitc.toml")
    part = layered_part(0.5, 0.4, 16, 20)
    assert len(split_runs(part)) >= 30  # 2 jobs a chunk: 30 chunks and more, against 8 in flight
    trajectory = plan(part, printer, workers=2)
    assert state["peak"] == 4 * 2 + 1 and state["out"] == 0
    assert trajectory.duration == plan(part, printer, workers=1).duration


def test_firmware_baseline_violates_where_corners_are_sharp():
    # A weak machine: the UCB geometry with slow joints; firmware's instantaneous corner
    # velocity changes exceed its joint acceleration at the output rate.
    printer = load_printer("printers/delta_uady.toml")
    toolpath = layered_part(0.25, 0.2, 1, 40)
    fw = plan_firmware(toolpath, printer, speed_limit="feed")
    assert corner_violations(fw)["events"] > 0
    safe = plan(toolpath, printer, planner="trapezoid", speed_limit="feed", workers=1)
    assert corner_violations(safe)["violating_samples"] == 0
    ours = plan(toolpath, printer, speed_limit="feed", workers=1)
    assert ours.duration < safe.duration


def test_the_safe_planners_peak_checks_sampled_by_workers_keep_the_plan(monkeypatch):
    """plan_safe's peak checks sampled by worker processes (as a compile's trapezoid planner has
    them) see the samples sampled here: the same peaks, so the same scale and the same plan."""
    from deltaslice.planning import trajectory as trajectory_module
    from deltaslice.planning.trapezoid import _monitor

    monkeypatch.setattr(trajectory_module, "PARALLEL_BLOCKS", 1)  # this 14 s print sampled in the workers
    forks = []
    forked_blocks = trajectory_module.Trajectory._forked_blocks

    def counted(self, *args, **kwargs):
        forks.append(1)
        return forked_blocks(self, *args, **kwargs)

    monkeypatch.setattr(trajectory_module.Trajectory, "_forked_blocks", counted)
    printer = load_printer("printers/delta_uady.toml")  # slowed: a bisection of several peak checks
    toolpath = layered_part(0.25, 0.2, 1, 40)
    here = plan(toolpath, printer, planner="trapezoid", workers=1)
    assert not forks
    forked = plan(toolpath, printer, planner="trapezoid", workers=2)
    assert len(forks) > 2
    assert here.info["scale"] == forked.info["scale"] < 1 and here.duration == forked.duration
    a, b = _monitor(here, printer.planning.output_rate), _monitor(here, printer.planning.output_rate, workers=2)
    np.testing.assert_array_equal(a.peak_v, b.peak_v)
    np.testing.assert_array_equal(a.peak_a, b.peak_a)
    assert (a.peak_tool_v, a.violating_samples, a.events) == (b.peak_tool_v, b.violating_samples, b.events)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=3, max_size=12),
    st.floats(0.005, 0.5),
)
def test_blend_stays_in_tolerance_band_and_is_tangent_continuous(xy, tol):
    pts = np.c_[np.array(xy), np.zeros(len(xy))]
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-3])
    pts = pts[keep]
    if len(pts) < 2:
        return
    path = blend_polyline(pts, tol)
    s = np.linspace(0, path.length, 2000)
    dev = _distance_to_polyline(path.evaluate(s), pts)
    assert dev.max() <= tol * (1 + 1e-6) + 1e-9
    assert path.length <= np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() + 1e-9
    # Tangent continuity at every join, unless the polyline reverses exactly (a point turn).
    d = np.diff(pts, axis=0)
    d /= np.linalg.norm(d, axis=1)[:, None]
    if np.all(np.einsum("ij,ij->i", d[:-1], d[1:]) > -1 + 1e-6):
        j = path.joins()
        before = path.evaluate(j - 1e-9, 1)
        after = path.evaluate(j, 1)
        assert np.all(np.einsum("ij,ij->i", before, after) > 1 - 1e-5)
    # Endpoints unchanged.
    assert np.allclose(path.evaluate(np.array([0.0, path.length])), pts[[0, -1]], atol=1e-9)


def test_exact_reversal_stops_at_the_cusp_within_limits():
    printer = load_printer("printers/delta_etitc.toml")
    b = ToolpathBuilder((0, 0, 0.5))
    b.new_layer(0.5)
    b.add([[10, 0, 0.5], [0, 0, 0.5], [0, 10, 0.5]], 60, 0.2, 1, Role.INFILL)
    traj = plan(b.build(), printer, speed_limit="machine", workers=1)
    s = traj.samples()
    v, a = finite_differences(s, printer.planning.output_rate)
    assert (np.abs(a).max(axis=0) / printer.limits.acceleration[:printer.n_joints]).max() <= MARGIN
    p = printer.kinematics().forward(s.q)
    cusp = np.argmin(np.linalg.norm(p[:, :2] - [10, 0], axis=1))
    assert np.linalg.norm(p[cusp, :2] - [10, 0]) < 5e-3  # it really goes to the reversal point


def test_toppra_degenerate_stage_falls_back_to_a_safe_profile():
    # A travel on which toppra's seidel solver returns a NaN controllable set (found by the
    # benchmark): the run is still planned, within every limit.
    printer = load_printer("printers/delta_etitc.toml")
    b = ToolpathBuilder((10.74668719, -20.97418369, 1.3))
    b.new_layer(1.3)
    b.add([[12.16288082, -20.18612611, 1.3]], 130, 0.0, 0, Role.TRAVEL)
    traj = plan(b.build(), printer, speed_limit="machine", workers=1)
    s = traj.samples()
    v, a = finite_differences(s, printer.planning.output_rate)
    assert (np.abs(a).max(axis=0) / printer.limits.acceleration[:printer.n_joints]).max() <= MARGIN
    assert (np.abs(v).max(axis=0) / printer.limits.velocity[:printer.n_joints]).max() <= MARGIN
    travel = [piece for piece in traj.pieces if piece.kind == "travel"]
    kin = printer.kinematics()
    target = [12.16288082, -20.18612611, 1.3]
    assert any(np.allclose(kin.forward(piece.q_end[None])[0], target, atol=1e-6) for piece in travel)
    assert np.allclose(s.q[-1], printer.rest_pose)  # then parks


@pytest.mark.parametrize("seed", range(8))
def test_limit_monitor_in_one_pass_equals_brute_force_over_the_whole_signal(seed):
    """The monitor's compiled pass over blocks of any size (one and two samples included) gives
    the peaks, the samples beyond a limit and the stretches of them that a brute-force numpy
    evaluation of the whole signal gives; from seed 4 on a joint's sample is NaN (numpy's
    max is then NaN: that joint's peaks, and its rows' velocity or acceleration, which then
    does not count the row as beyond a limit); seeds 6 and 7 hand it one sample at a time."""
    from types import SimpleNamespace

    from deltaslice.machine import LimitMonitor

    printer = load_printer("printers/delta_etitc.toml")
    rate, J = 1000.0, printer.n_joints
    rng = np.random.default_rng(seed)
    n = 3000
    t = np.arange(n) / rate
    # Smooth motion near the limits, with a few spikes beyond them.
    amp = printer.limits.velocity[:J] / (2 * np.pi * 3.0) * rng.uniform(0.5, 1.2, J)
    q = amp[None] * np.sin(2 * np.pi * 3.0 * t[:, None] + rng.uniform(0, 6, J))
    q[rng.integers(2, n - 2, 6), rng.integers(0, J, 6)] += rng.uniform(-0.05, 0.05, 6)
    if seed >= 4:  # beside a spike of another joint: the row's other bound still counts
        k = int(rng.integers(10, n - 10))
        q[k, 0] = np.nan
        q[k + 1, 1] += 0.05  # row k - 1: its velocity is beyond, its acceleration NaN
    e = np.cumsum(rng.uniform(0, 2e-3, n))
    tool = (rng.uniform(size=n) > 0.3).astype(float)
    cuts = np.unique(np.concatenate([[0, 1, 3, 4, n], rng.integers(0, n, 40)]))
    if seed >= 6:  # a sample a block: every sample judged with the two before it
        cuts = np.arange(n + 1)
    m = LimitMonitor(printer.limits, printer.tool, rate)
    for a, b in zip(cuts[:-1], cuts[1:]):
        m.observe(SimpleNamespace(q=q[a:b], e=e[a:b], tool=tool[a:b]))
    v = (q[2:] - q[:-2]) * rate / 2
    acc = (q[2:] - 2 * q[1:-1] + q[:-2]) * rate**2
    rv, ra = np.abs(v) / printer.limits.velocity[:J], np.abs(acc) / printer.limits.acceleration[:J]
    assert np.allclose(m.peak_v, rv.max(axis=0), rtol=1e-12, equal_nan=True)
    assert np.allclose(m.peak_a, ra.max(axis=0), rtol=1e-12, equal_nan=True)
    assert np.isnan(m.peak_v[0]) == (seed >= 4) and np.isfinite(m.peak_v[1:]).all()
    bad = (rv.max(axis=1) > 1) | (ra.max(axis=1) > 1)
    assert m.violating_samples == int(bad.sum()) > 0
    assert m.events == int((np.diff(np.concatenate([[0], bad.astype(int)])) == 1).sum()) > 1
    tv = np.abs(e[2:] - e[:-2]) * rate / 2 * (tool[1:-1] > 0)
    assert m.peak_tool_v == pytest.approx(tv.max() / printer.limits.velocity[-1], rel=1e-12)


def test_limit_monitor_counts_a_ratio_one_ulp_above_the_limit():
    """Where velocity / limit rounds to one ulp above 1 but the product by the reciprocal limit the
    monitor screens with rounds to 1 or just below, the row is still beyond the limit: the screen
    must leave a margin, not compare with 1."""
    from deltaslice.machine.limits import _observe_kernel

    rate = 1000.0
    half = 0.5 * rate
    rng = np.random.default_rng(0)
    cases = []
    for vlim in rng.uniform(0.5, 50.0, 2000):
        dv = np.nextafter(vlim / half, np.inf)
        if (dv * half) / vlim > 1.0 and dv * (half / vlim) <= 1.0:
            cases.append((vlim, dv))
    assert len(cases) > 10
    for vlim, dv in cases[:50]:
        q = np.array([[0.0], [0.0], [dv]])
        peak_v, peak_a = np.zeros(1), np.zeros(1)
        flat = np.zeros(3)
        _tool_v, bad, events, last_bad = _observe_kernel(q, flat, flat, rate, np.array([vlim]), np.array([np.inf]),
                                                          peak_v, peak_a, False)
        assert (bad, events, last_bad) == (1, 1, True) and peak_v[0] > 1.0, (vlim, dv)


def test_limit_monitor_over_blocks_equals_whole_array_differences():
    from deltaslice.machine import LimitMonitor

    printer = load_printer("printers/delta_etitc.toml")
    traj = plan(layered_part(0.5, 0.4, 1, 40), printer, speed_limit="machine", workers=1)
    rate = printer.planning.output_rate
    s = traj.samples()
    v, a = finite_differences(s, rate)
    m = LimitMonitor(printer.limits, printer.tool, rate).consume(traj.iter_samples(rate, block=97))
    assert np.allclose(m.peak_v, (np.abs(v[1:-1]) / printer.limits.velocity[:printer.n_joints]).max(axis=0), rtol=1e-12)
    assert np.allclose(m.peak_a, (np.abs(a[1:-1]) / printer.limits.acceleration[:printer.n_joints]).max(axis=0), rtol=1e-12)
    fw = plan_firmware(layered_part(0.25, 0.2, 1, 40), load_printer("printers/delta_uady.toml"))
    whole = corner_violations(fw)
    fv, fa = finite_differences(fw.samples(), fw.printer.planning.output_rate)
    bad = ((np.abs(fv) / fw.printer.limits.velocity[:fw.printer.n_joints]).max(axis=1) > 1) | (
        (np.abs(fa) / fw.printer.limits.acceleration[:fw.printer.n_joints]).max(axis=1) > 1
    )
    assert whole["violating_samples"] == int(bad[1:-1].sum()) > 0


def test_limit_monitor_watching_blocks_refilled_in_place_sees_each_as_it_was():
    """watch observes each block in a second thread while the caller uses it: every block must be
    observed before the next is taken, since a writer's blocks are views of buffers refilled then.
    Here one buffer is refilled with each block (and scribbled over with NaN while the next is
    asked for) and each observation is slowed: the results are those of observing copies one by
    one, and the caller gets every block unchanged."""
    import threading
    import time

    from deltaslice.machine import LimitMonitor
    from deltaslice.samples import Samples

    printer = load_printer("printers/delta_etitc.toml")
    traj = plan(layered_part(0.5, 0.4, 1, 40), printer, speed_limit="machine", workers=1)
    rate = printer.planning.output_rate
    blocks = list(traj.iter_samples(rate, block=331))
    buf = [np.empty((331, printer.n_joints)), np.empty(331), np.empty(331), np.empty(331)]
    observing = []

    class Slow(LimitMonitor):
        def observe(self, block):
            observing.append(threading.get_ident())
            time.sleep(0.002)
            super().observe(block)

    def refilled():
        for b in blocks:
            n = len(b)
            for dst, src in zip(buf, (b.q, b.t, b.e, b.tool)):
                dst[:n] = src
            yield Samples(buf[1][:n], buf[0][:n], buf[2][:n], buf[3][:n])
            for dst in buf:  # what a sampler's next task does to the slot
                dst[:] = np.nan

    ref = LimitMonitor(printer.limits, printer.tool, rate).consume(blocks)
    m = Slow(printer.limits, printer.tool, rate)
    for got, b in zip(m.watch(refilled()), blocks):
        np.testing.assert_array_equal(got.q, b.q)
    assert len(observing) == len(blocks) and threading.get_ident() not in observing
    np.testing.assert_array_equal(m.peak_v, ref.peak_v)
    np.testing.assert_array_equal(m.peak_a, ref.peak_a)
    assert (m.peak_tool_v, m.violating_samples, m.events) == (ref.peak_tool_v, ref.violating_samples, ref.events)


def test_split_runs_is_the_run_by_run_cut():
    """split_runs (the extruder's, in one numpy pass over the toolpath) against cutting each run
    of working moves where its tool value changes or a wait stands inside it: random tool values
    (off, partial, full), waits and other events anywhere (at 0, at the end, repeated, outside
    runs), one-move runs and a toolpath of one move."""
    from deltaslice.toolpath import WAIT_KINDS, EventKind, Toolpath, make_events

    def by_run(tp):
        waits = tp.events["index"][np.isin(tp.events["kind"], [int(k) for k in WAIT_KINDS])]
        out = []
        for i, j in tp.runs():
            cuts = np.union1d(np.flatnonzero(np.diff(tp.tool[i:j]) != 0) + 1, waits[(waits > i) & (waits < j)] - i).astype(int)
            edges = np.concatenate([[0], cuts, [j - i]]) + i
            out.extend(zip(edges[:-1].tolist(), edges[1:].tolist()))
        return out

    rng = np.random.default_rng(8)
    kinds = [int(k) for k in EventKind if k != EventKind.LASER_MODE]
    for trial in range(400):
        n = int(rng.integers(1, 60))
        tool = rng.choice([0.0, 0.0, 0.4, 1.0, 1.0, 1.0], n)
        rows = [(int(rng.integers(0, n + 1)), int(rng.choice(kinds)), 200.0) for _ in range(int(rng.integers(0, 8)))]
        tp = Toolpath(start=np.zeros(3), xyz=rng.uniform(0, 10, (n, 3)), feed=np.full(n, 20.0), e=np.zeros(n), tool=tool,
                      role=np.zeros(n, np.uint8), layer=np.zeros(n, np.int32), layer_z=np.array([0.3]), events=make_events(rows))
        assert split_runs(tp) == by_run(tp), trial



@settings(max_examples=200, deadline=None)
@given(st.integers(2, 40), st.integers(0, 2**32 - 1), st.floats(0.0, 1.0), st.sampled_from([0.004, 0.012]))
def test_merge_short_leaves_no_vertex_it_could_remove(m, seed, short_share, short_step):
    """merge_short measures the segments again only once a pass removed vertices, and stops at
    once where none is short: what it returns is a fixed point (merged again, nothing moves: no
    pass was cut short), within the deviation, with the filament total and the ends kept; a
    polyline with no short segment comes back as it was given."""
    from deltaslice.planning.blend import merge_short

    rng = np.random.default_rng(seed)
    steps = rng.normal(size=(m, 3)) * np.where(rng.random(m) < short_share, short_step, 1.0)[:, None]
    pts = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    feed, e = rng.uniform(5, 60, m), rng.uniform(0, 0.1, m)
    out, f, ee, dev = merge_short(pts, feed, e, 0.02, 0.01)
    again = merge_short(out, f, ee, 0.02, 0.01)
    for g, w in zip(again[:3], (out, f, ee)):
        assert g.tobytes() == w.tobytes()
    assert again[3] == 0.0 and dev <= 0.01
    assert np.isclose(ee.sum(), e.sum(), rtol=1e-12, atol=1e-15)
    assert (out[0] == pts[0]).all() and (out[-1] == pts[-1]).all() and len(f) == len(ee) == len(out) - 1
    if not (np.linalg.norm(steps, axis=1) < 0.02).any():
        assert out.tobytes() == pts.tobytes() and f.tobytes() == feed.tobytes() and ee.tobytes() == e.tobytes()


def test_merge_short_drops_a_short_segments_vertex_on_a_straight_line():
    from deltaslice.planning.blend import merge_short

    pts = np.array([[0.0, 0, 0], [5.0, 0, 0], [5.005, 0, 0], [10.0, 0, 0]])
    out, feed, e, dev = merge_short(pts, np.array([20.0, 10.0, 30.0]), np.array([0.1, 0.001, 0.1]), 0.02, 0.01)
    assert len(out) == 3 and dev == 0.0 and np.isclose(e.sum(), 0.201)
    # two short segments merged make one that is not short: the vertex after it stays
    pts = np.array([[0.0, 0, 0], [0.015, 0, 0], [0.03, 0, 0], [10.0, 0, 0]])
    out, _feed, _e, _dev = merge_short(pts, np.full(3, 20.0), np.full(3, 0.01), 0.02, 0.01)
    assert out.tolist() == [[0.0, 0, 0], [0.03, 0, 0], [10.0, 0, 0]]
