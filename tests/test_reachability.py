"""The compiled reachability solver against toppra (the reference) and against a brute-force
evaluation of every constraint at every stage."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import toppra
import toppra.algorithm
import toppra.constraint
from toppra.constraint.linear_constraint import LinearConstraint
from toppra.interpolator import AbstractGeometricPath

from deltaslice import load_printer
from deltaslice.errors import DeltasliceError
from deltaslice.planning import plan
from deltaslice.planning.reachability import solve, solve_batch
from deltaslice.toolpath import Role, ToolpathBuilder

logging.getLogger("toppra").setLevel(logging.ERROR)
ROOT = Path(__file__).resolve().parents[1]
TOL = 1e-5  # relative; a real violation (a wrong LP bound) is of order 1


class _TablePath(AbstractGeometricPath):
    """A path known only by its derivatives at the grid points (what the constraints read)."""

    def __init__(self, grid, d1, d2):
        self.grid, self.d1, self.d2 = grid, d1, d2

    @property
    def dof(self):
        return self.d1.shape[1]

    @property
    def path_interval(self):
        return np.array([0.0, 1.0])

    def __call__(self, xs, order=0):
        i = np.searchsorted(self.grid, np.atleast_1d(xs))
        if order == 0:
            return np.zeros((len(i), self.dof))
        return (self.d1 if order == 1 else self.d2)[i]


class _XBound(LinearConstraint):
    def __init__(self, xmax):
        super().__init__()
        self.xmax, self.dof = xmax, 1

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        xb = np.zeros((len(gridpoints), 2))
        xb[:, 1] = self.xmax
        return None, None, None, None, None, None, xb


def _toppra(grid, d1, d2, amax, xmax, interpolation=True):
    scheme = toppra.constraint.DiscretizationType.Interpolation if interpolation else toppra.constraint.DiscretizationType.Collocation
    cons = [_XBound(xmax), toppra.constraint.JointAccelerationConstraint(amax, discretization_scheme=scheme)]
    algo = toppra.algorithm.TOPPRA(cons, _TablePath(grid, d1, d2), gridpoints=grid, solver_wrapper="seidel")
    _, sd, _ = algo.compute_parameterization(0.0, 0.0)
    return sd


def _duration(grid, x):
    v = np.sqrt(np.maximum(x, 0))
    return float(np.sum(2 * np.diff(grid) / (v[:-1] + v[1:])))


def _random_problem(rng, stops=True):
    n = int(rng.integers(2, 80))
    m = int(rng.integers(1, 5))
    grid = np.concatenate([[0.0], np.sort(rng.uniform(0, 1, n - 1)), [1.0]])
    d1 = rng.normal(0, 1, (n + 1, m)) * rng.uniform(0.1, 10)
    d2 = rng.normal(0, 1, (n + 1, m)) * rng.uniform(0, 20)
    amax = rng.uniform(0.5, 5, m) * rng.choice([1.0, 100.0])
    xmax = rng.uniform(0.5, 50, n + 1)
    if stops:
        xmax[rng.random(n + 1) < 0.05] = 0.0
    return grid, d1, d2, amax, xmax


def _violation(grid, d1, d2, amax, xmax, x, u, interpolation=True):
    """Largest relative violation of any constraint at any stage, evaluated directly. The forward
    pass shrinks each x_{i+1} by 0.01 % below x_i + 2 ds u_i (as toppra does, against rounding
    into infeasibility), so rows at grid point i+1 may differ from the LP's by ~1e-6 relative."""
    ds = np.diff(grid)
    worst = [
        np.max(np.abs(d1[:-1] * u[:, None] + d2[:-1] * x[:-1, None]) / amax - 1),
        np.max((x - xmax) / np.maximum(xmax, 1.0)),
        -x.min(),
        np.max(np.abs(x[1:] - x[:-1] - 2 * ds * u)) / max(1.0, x.max()) - 1e-4,  # the 0.9999 shrink
        abs(x[0]) - 1e-12,
        abs(x[-1]) - 1e-12,
    ]
    if interpolation:
        worst.append(np.max(np.abs(d1[1:] * u[:, None] + d2[1:] * x[1:, None]) / amax - 1))
    return max(worst)


@pytest.mark.parametrize("interpolation", [True, False])
@pytest.mark.parametrize("seed", range(6))
def test_matches_toppra_on_random_problems(seed, interpolation):
    rng = np.random.default_rng(seed)
    compared = 0
    for _ in range(25):
        grid, d1, d2, amax, xmax = _random_problem(rng, stops=False)
        sd = _toppra(grid, d1, d2, amax, xmax, interpolation)
        x, u, _ = solve(d1, d2, -amax, amax, xmax, np.diff(grid), interpolation=interpolation)
        assert np.all(np.isfinite(x)), "a problem feasible at rest must be solved"
        assert _violation(grid, d1, d2, amax, xmax, x, u, interpolation) < TOL
        if sd is None or not np.all(np.isfinite(sd)):
            continue  # toppra's seidel LP degenerates now and then; ours is checked above
        ref = _duration(grid, sd**2)
        assert _duration(grid, x) == pytest.approx(ref, rel=1e-3)
        compared += 1
    assert compared >= 15


def test_constraints_hold_with_interior_stops():
    rng = np.random.default_rng(42)
    for _ in range(50):
        grid, d1, d2, amax, xmax = _random_problem(rng, stops=True)
        x, u, _ = solve(d1, d2, -amax, amax, xmax, np.diff(grid))
        assert _violation(grid, d1, d2, amax, xmax, x, u) < TOL
        assert np.all(x[xmax == 0] <= 1e-12)


def test_one_sided_rows_equal_the_two_sided_row():
    """A row given as two one-sided copies (the other bound infinite) gives the same profile as the
    row itself, with and without interpolation: the torque rows are one-sided."""
    rng = np.random.default_rng(7)
    for interpolation in (False, True):
        for _ in range(30):
            grid, d1, d2, amax, xmax = _random_problem(rng, stops=True)
            m = d1.shape[1]
            x, u, _ = solve(d1, d2, -amax, amax, xmax, np.diff(grid), interpolation=interpolation)
            inf = np.full(m, np.inf)
            x1, u1, _ = solve(np.hstack([d1, d1]), np.hstack([d2, d2]), np.concatenate([-amax, -inf]),
                              np.concatenate([inf, amax]), xmax, np.diff(grid), interpolation=interpolation)
            np.testing.assert_array_equal(np.isnan(x1), np.isnan(x))
            ok = ~np.isnan(x)
            np.testing.assert_allclose(x1[ok], x[ok], rtol=1e-9, atol=1e-12)


def test_single_joint_bang_bang_is_exact():
    """One joint, q' = 1, q'' = 0: x rises at 2*amax per path unit to the midpoint, then falls."""
    grid = np.linspace(0, 1, 201)
    x, u, _ = solve(np.ones((201, 1)), np.zeros((201, 1)), [-2.0], [2.0], np.full(201, np.inf), np.diff(grid))
    expected = 4.0 * np.minimum(grid, 1 - grid)
    assert np.allclose(x, expected, rtol=2e-3, atol=1e-6)
    assert np.all(np.abs(u) <= 2.0 + 1e-9)


def test_the_shrink_never_decelerates_beyond_the_rows_on_tiny_stages():
    """toppra's forward pass shrinks every step by 1e-8 in x whatever the stage's width; on
    stages 1e-9 long (a refined grid in a long window: S = 1.5 m) that alone was a deceleration
    of 4 where the rows allow 1 (a spiral vase's window failed its check at 141 times a joint's
    limit). The path acceleration implied by consecutive points, (x[i+1] - x[i]) / (2 ds), stays
    within the rows' [-1, 1] on every stage."""
    ds = np.full(300, 1e-3)
    ds[140:190] = 1e-9  # a cruise at the cap, refined
    n = len(ds)
    x, _u, _ = solve(np.ones((n + 1, 1)), np.zeros((n + 1, 1)), [-1.0], [1.0], np.full(n + 1, 0.1), ds,
                     interpolation=False)
    implied = np.diff(x) / (2 * ds)
    assert np.all(np.isfinite(x)) and x.max() > 0.09
    assert implied.min() >= -1 - 1e-6, f"a stage decelerates at {implied.min():.3g}"
    assert implied.max() <= 1 + 1e-6


def test_toppra_box_is_reproduced():
    """toppra's seidel solver bounds u and x by 1e8: tiny runs at high speed hit it; so do we."""
    n = 1000
    grid = np.linspace(0, 1, n + 1)
    x, _, _ = solve(np.ones((n + 1, 1)), np.zeros((n + 1, 1)), [-1e12], [1e12], np.full(n + 1, np.inf), np.diff(grid))
    sd = _toppra(grid, np.ones((n + 1, 1)), np.zeros((n + 1, 1)), np.array([1e12]), np.full(n + 1, np.inf))
    assert x.max() == pytest.approx(1e8, rel=1e-6)
    assert _duration(grid, x) == pytest.approx(_duration(grid, sd**2), rel=1e-6)


def test_infeasible_stage_gives_nan():
    """A row without u whose bounds exclude x = 0 and every x > 0: no profile (toppra: None)."""
    grid = np.linspace(0, 1, 11)
    a = np.ones((11, 2))
    a[5, 1] = 0.0
    b = np.zeros((11, 2))
    b[5, 1] = -1.0
    lo, hi = np.array([-1.0, 0.5]), np.array([1.0, 1.0])
    x, u, _ = solve(a, b, lo, hi, np.full(11, 10.0), np.diff(grid))
    assert np.all(np.isnan(x)) and np.all(np.isnan(u))


def test_start_speed_not_controllable_gives_nan():
    grid = np.linspace(0, 1, 11)
    x, _, _ = solve(np.ones((11, 1)), np.zeros((11, 1)), [-1.0], [1.0], np.full(11, 0.5), np.diff(grid), x_start=4.0)
    assert np.all(np.isnan(x))


def test_degenerate_rows_and_zero_length_stage():
    """A joint that never moves (all-zero rows), a joint whose rows have no u term, and two
    coincident grid points: still solved, every constraint held."""
    grid = np.array([0.0, 0.1, 0.3, 0.3, 0.6, 1.0])
    n = len(grid) - 1
    d1 = np.column_stack([np.ones(n + 1), np.zeros(n + 1), np.zeros(n + 1)])
    d2 = np.column_stack([np.full(n + 1, 0.5), np.zeros(n + 1), np.full(n + 1, 2.0)])
    amax = np.array([1.0, 1.0, 8.0])
    xmax = np.full(n + 1, 3.0)
    x, u, _ = solve(d1, d2, -amax, amax, xmax, np.diff(grid))
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(u))
    assert _violation(grid, d1, d2, amax, xmax, x, u) < TOL
    assert x[2] == pytest.approx(x[3], rel=1e-3)
    assert np.all(x <= 4.0 + 1e-9)  # joint 3: |2 x| <= 8


def test_batch_equals_single_runs():
    rng = np.random.default_rng(7)
    m = 3
    amax = np.array([2.0, 3.0, 5.0])
    problems = []
    for _ in range(20):
        grid, d1, d2, _, xmax = _random_problem(rng)
        problems.append((d1[:, :m] if d1.shape[1] >= m else np.resize(d1, (len(d1), m)),
                         d2[:, :m] if d2.shape[1] >= m else np.resize(d2, (len(d2), m)), xmax, np.diff(grid)))
    batch = solve_batch(problems, -amax, amax)
    for (a, b, xmax, ds), (xb, ub) in zip(problems, batch):
        x, u, _ = solve(a, b, -amax, amax, xmax, ds)
        np.testing.assert_array_equal(x, xb)
        np.testing.assert_array_equal(u, ub)


def _circle_and_square(printer):
    z = printer.slicing.first_layer_height
    b = ToolpathBuilder((0.0, 0.0, z + 1))
    b.new_layer(z)
    th = np.linspace(0, 2 * np.pi, 91)
    xy = np.c_[15 * np.cos(th), 15 * np.sin(th)]
    b.add([[xy[0, 0], xy[0, 1], z]], printer.slicing.travel_speed, 0, 0, Role.TRAVEL)
    ratio = printer.slicing.perimeter_width * z / printer.tool.filament_area
    seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    b.add(np.c_[xy[1:], np.full(90, z)], printer.slicing.perimeter_speed, seg * ratio, 1, Role.PERIMETER)
    sq = np.array([[-10, -10], [10, -10], [10, 10], [-10, 10], [-10, -10]], float)
    b.add([[sq[0, 0], sq[0, 1], z]], printer.slicing.travel_speed, -1.0, 0, Role.TRAVEL)
    b.add(np.c_[sq[1:], np.full(4, z)], printer.slicing.infill_speed, np.full(4, 20 * ratio), 1, Role.INFILL)
    return b.build()


@pytest.mark.parametrize("printer_name", ["delta_etitc", "fivebar_atlas"])
@pytest.mark.parametrize("speed_limit", ["feed", "machine"])
def test_planned_durations_match_toppra(printer_name, speed_limit):
    """Real runs and travels through the kinematics: every piece within 0.1 % of toppra (the
    acceleration rows: toppra's reference plans no torque rows)."""
    printer = load_printer(ROOT / "printers" / f"{printer_name}.toml", {"planning.torque_limit": "off"})
    tp = _circle_and_square(printer)
    fast = plan(tp, printer, speed_limit=speed_limit, workers=1, solver="fast")
    ref = plan(tp, printer, speed_limit=speed_limit, workers=1, solver="toppra")
    assert [p.kind for p in fast.pieces] == [p.kind for p in ref.pieces]
    np.testing.assert_allclose(fast.durations, ref.durations, rtol=1e-3)
    assert fast.duration == pytest.approx(ref.duration, rel=1e-3)


def test_unknown_solver_is_refused():
    printer = load_printer(ROOT / "printers" / "delta_etitc.toml")
    with pytest.raises(DeltasliceError, match="solver"):
        plan(_circle_and_square(printer), printer, solver="seidel")


def test_cli_solver_option_gives_the_same_print_time(tmp_path):
    """`--solver toppra` and the default (fast) compile the same part to the same print time."""
    import re

    from click.testing import CliRunner

    from deltaslice.cli import main

    printer = str(ROOT / "printers" / "delta_etitc.toml")
    cube = ROOT / "examples" / "parts" / "calibration_cube.stl"
    runner = CliRunner()
    gcode = tmp_path / "cube.gcode"
    r = runner.invoke(main, ["slice", str(cube), "--printer", printer, "-o", str(gcode), "--scale", "0.3", "--quiet"])
    assert r.exit_code == 0, r.output
    times = {}
    for solver in ("fast", "toppra"):
        r = runner.invoke(main, [str(gcode), "--printer", printer, "-o", str(tmp_path / f"{solver}.dsl"), "--quiet",
                                 "--workers", "1", "--solver", solver, "--set", "planning.torque_limit=off"])
        assert r.exit_code == 0, r.output
        times[solver] = float(re.search(r"print time: ([\d.]+) s", r.output).group(1))
    assert times["fast"] == pytest.approx(times["toppra"], rel=1e-3)
    r = runner.invoke(main, [str(gcode), "--printer", printer, "-o", str(tmp_path / "x.dsl"), "--solver", "cvxpy"])
    assert r.exit_code != 0 and "cvxpy" in r.output


def _x_range_every_pair(low, up, xl, xh):
    """The projection by brute force: every pair of a lower and an upper bound on u."""
    from deltaslice.planning.reachability import PARALLEL

    for p, r in low:
        for q, s in up:
            c, e = r - s, q - p
            if c > PARALLEL:
                xh = min(xh, e / c)
            elif c < -PARALLEL:
                xl = max(xl, e / c)
            elif e < -1e-12 * (abs(q) + abs(p) + 1.0):
                return np.inf, -np.inf
    return xl, xh


def _x_range_of(low, up, xl, xh):
    from deltaslice.planning.reachability import _x_range

    low, up = np.asarray(low, float).reshape(-1, 2), np.asarray(up, float).reshape(-1, 2)
    return _x_range(len(low), len(up), np.ascontiguousarray(low[:, 0]), np.ascontiguousarray(low[:, 1]),
                    np.ascontiguousarray(up[:, 0]), np.ascontiguousarray(up[:, 1]), xl, xh,
                    np.empty(len(low), np.int64), np.empty(len(up), np.int64))


def test_x_range_keeps_the_binding_one_of_near_duplicate_bounds():
    """Two stages the first envelope test got wrong (found by a review's random search): lines
    compared by their values at |p| ~ 4e6 tied once rounded and the binding one was left out (an
    empty stage came out feasible); and a bound left out whose partner was within PARALLEL of
    parallel, where every pair takes the range from the left-out one (xl 1.8 % looser)."""
    cases = [
        ([(3885552.9153668564, -1210.8391542033703), (3885552.9153669165, -1210.839154203389)],
         [(3885552.9153716494, -1210.839154204864)], 3208.9752812157953, 3213.295446064159),
        ([(3.6392999976793007e05, -1.0504036448927319), (3.6392999976789975e05, -1.0504036448926442)],
         [(3.6392999976754835e05, -1.0504036448916501)], 3.4646680972350866e05, 3.5564899435618531e05),
    ]
    for low, up, xl, xh in cases:
        assert _x_range_of(low, up, xl, xh) == _x_range_every_pair(low, up, xl, xh)
    assert not _x_range_of(*cases[0][:2], cases[0][2], cases[0][3])[0] <= _x_range_of(*cases[0])[1]


@pytest.mark.parametrize("seed", range(6))
def test_x_range_from_the_envelopes_equals_every_pair(seed):
    """The stage's projection pairs only the bounds that can lie on their envelope: the same x
    range as every pair, on random bounds of every kind: nearly parallel families (a joint's rows
    at five fractions), near duplicates far from zero (|p| ~ 1e6, differences of 1e-13), exact
    duplicates, ranges that are empty, a point, or as wide as the box."""
    from deltaslice.planning.reachability import BOX, _x_range

    rng = np.random.default_rng(seed)
    checked = 0
    for trial in range(3000):
        nl, nu = rng.integers(1, 24, 2)
        spread = [1e-3, 1e-13, 0.0][trial % 3]
        fam = lambda n: np.repeat(rng.normal(size=(max(1, n // 5) + 1, 2)), 5, axis=0)[:n] * (
            1 + spread * rng.normal(size=(n, 2)) * rng.integers(0, 2))
        low, up = fam(nl), fam(nu)
        low[:, 0] -= rng.uniform(0, 3)  # most stages feasible
        up[:, 0] += rng.uniform(0, 3)
        if trial % 2:  # far from zero: lines of slope -r through u = p0 + ... at large x
            big = rng.uniform(1e5, 5e6)
            low[:, 0] = low[:, 0] * 1e-6 + big
            up[:, 0] = up[:, 0] * 1e-6 + big
            low[:, 1] = low[:, 1] * 1e-9 - big / 3000
            up[:, 1] = up[:, 1] * 1e-9 - big / 3000
        if rng.random() < 0.2:
            low[-1] = low[0]  # an exact duplicate
        xl = 0.0 if trial % 2 == 0 else rng.uniform(0, 3000)
        xh = [xl + rng.uniform(0.1, 10.0), BOX, xl, xl + rng.uniform(-1, 1)][rng.integers(0, 4)]
        low_p, low_r = np.ascontiguousarray(low[:, 0]), np.ascontiguousarray(low[:, 1])
        up_p, up_r = np.ascontiguousarray(up[:, 0]), np.ascontiguousarray(up[:, 1])
        keep_l, keep_u = np.empty(nl, np.int64), np.empty(nu, np.int64)
        got = _x_range(nl, nu, low_p, low_r, up_p, up_r, xl, xh, keep_l, keep_u)
        want = _x_range_every_pair(zip(low_p, low_r), list(zip(up_p, up_r)), xl, xh)
        assert got == want, (seed, nl, nu, xh)
        checked += want[0] <= want[1]
    assert checked > 1000  # enough of them feasible
