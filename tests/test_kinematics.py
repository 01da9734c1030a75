"""The kinematics contract (deltaslice/kinematics/base.py), checked on every family:
the six shipped printers plus a Cartesian machine built here.

Round trips to 1e-9 mm / rad, the Jacobian against finite differences of
``forward``, ``inverse_jacobian @ jacobian == I``, the delta forward solutions
against an independent least-squares solve of the closure equations, NaN and
``reachable == False`` instead of exceptions, and batch == point by point.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.optimize import least_squares

from deltaslice.jit import njit
from deltaslice.kinematics import make_kinematics
from deltaslice.kinematics.cartesian import Cartesian, CartesianGeometry
from deltaslice.kinematics.five_bar import FiveBar
from deltaslice.kinematics.linear_delta import LinearDelta
from deltaslice.kinematics.rotary_delta import RotaryDelta, RotaryDeltaGeometry
from deltaslice.kinematics.rotary_delta import atan2 as rotary_atan2

from conftest import PRINTER_NAMES, printer

SETTINGS = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])

CARTESIAN = Cartesian(CartesianGeometry(offset_x=110.0, offset_y=-7.5, offset_z=3.0), [0.0, -120.0, 0.0], [220.0, 105.0, 200.0])
# The Kossel with its tool tip 12 mm below the effector's joints: every shipped linear delta has a
# tool_offset of 0, which hides the offset's sign.
_KOSSEL = printer("linear_kossel").kinematics()
KOSSEL_OFFSET = LinearDelta(dataclasses.replace(_KOSSEL.geometry, tool_offset=12.0), _KOSSEL.position_min,
                            _KOSSEL.position_max, _KOSSEL.singularity_limit)
BUILT = {"cartesian": CARTESIAN, "linear_kossel_offset": KOSSEL_OFFSET}  # machines built here, not shipped
CASES = PRINTER_NAMES + list(BUILT)


def kin_of(name):
    return BUILT[name] if name in BUILT else printer(name).kinematics()


def family_of(name):
    return kin_of(name).__module__.rsplit(".", 1)[1]


def box_of(name):
    """A box of tool points that mostly lies in the workspace: the bed up to max_height."""
    if name == "cartesian":
        return np.array([-110.0, -110.0, 0.0]), np.array([110.0, 110.0, 195.0])
    bed = printer("linear_kossel" if name == "linear_kossel_offset" else name).bed
    hx, hy = (bed.radius, bed.radius) if bed.shape == "circle" else (bed.size_x / 2, bed.size_y / 2)
    return np.array([-hx, -hy, 0.0]), np.array([hx, hy, bed.max_height])


def point_batches(lo, hi, max_size=12):
    coord = [st.floats(float(a), float(b), allow_nan=False) for a, b in zip(lo, hi)]
    return st.lists(st.tuples(*coord), min_size=1, max_size=max_size).map(lambda rows: np.array(rows, dtype=float))


def reachable_batch(name, data):
    """Draw a batch of points from the printer's box and keep the reachable ones."""
    kin = kin_of(name)
    pts = data.draw(point_batches(*box_of(name)))
    ok = kin.reachable(pts)
    assume(ok.any())
    return kin, pts[ok]


def fd_jacobian(kin, q, h=1e-6):
    """Central finite differences of forward: (N,3,J)."""
    out = np.empty((len(q), 3, q.shape[1]))
    for j in range(q.shape[1]):
        dq = np.zeros(q.shape[1])
        dq[j] = h
        out[:, :, j] = (kin.forward(q + dq) - kin.forward(q - dq)) / (2 * h)
    return out


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("name", CASES)
@SETTINGS
@given(data=st.data())
def test_forward_of_inverse_is_identity(name, data):
    kin, pts = reachable_batch(name, data)
    q = kin.inverse(pts)
    assert np.all(np.isfinite(q))
    assert np.max(np.abs(kin.forward(q) - pts)) <= 1e-9


@pytest.mark.parametrize("name", CASES)
@SETTINGS
@given(data=st.data())
def test_inverse_of_forward_is_identity(name, data):
    kin = kin_of(name)
    n = data.draw(st.integers(1, 12))
    u = np.array(data.draw(st.lists(st.floats(0.0, 1.0), min_size=3 * n, max_size=3 * n))).reshape(n, 3)
    q = kin.position_min + u * (kin.position_max - kin.position_min)
    pts = kin.forward(q)
    ok = np.all(np.isfinite(pts), axis=1)
    ok[ok] = kin.reachable(pts[ok])
    assume(ok.any())
    assert np.max(np.abs(kin.inverse(pts[ok]) - q[ok])) <= 1e-9


# --------------------------------------------------------------------------- Jacobians


@pytest.mark.parametrize("name", CASES)
@SETTINGS
@given(data=st.data())
def test_jacobian_matches_finite_differences(name, data):
    kin, pts = reachable_batch(name, data)
    q = kin.inverse(pts)
    jac = kin.jacobian(q)
    assert jac.shape == (len(q), 3, 3)
    fd = fd_jacobian(kin, q)
    scale = np.max(np.abs(jac), axis=(1, 2), keepdims=True)
    assert np.all(np.abs(jac - fd) <= 1e-6 * scale)


def unit_rows(data, n, perpendicular_to=None):
    """n random vectors: unit ones, or (perpendicular_to given) ones perpendicular to those rows
    with a length (curvature, 1/mm) up to 2."""
    v = np.array(data.draw(st.lists(st.floats(-1.0, 1.0), min_size=3 * n, max_size=3 * n))).reshape(n, 3)
    if perpendicular_to is None:
        norm = np.linalg.norm(v, axis=1)
        assume(np.all(norm > 0.1))
        return v / norm[:, None]
    v -= np.sum(v * perpendicular_to, axis=1)[:, None] * perpendicular_to
    return v * 2.0


@pytest.mark.parametrize("name", CASES)
@SETTINGS
@given(data=st.data())
def test_path_derivatives_match_inverse_kinematics_along_a_curve(name, data):
    """The planner's joint derivatives along a curve (the closed form each family has) against
    the brute force: inverse kinematics along p(s) = p + t s + kappa s^2 / 2, differenced, and
    against the default (a difference of the inverse Jacobian)."""
    from deltaslice.kinematics.base import Kinematics

    kin, pts = reachable_batch(name, data)
    t = unit_rows(data, len(pts))
    kappa = unit_rows(data, len(pts), perpendicular_to=t)
    q = kin.inverse(pts)
    d1, d2 = kin.path_derivatives(pts, q, t, kappa)

    def stencils(h):
        qs = [kin.inverse(pts + t * s + kappa * s * s / 2) for s in (-2 * h, -h, 0.0, h, 2 * h)]
        assume(all(np.all(np.isfinite(x)) for x in qs))
        return ((qs[0] - 8 * qs[1] + 8 * qs[3] - qs[4]) / (12 * h),
                (-qs[0] + 16 * qs[1] - 30 * qs[2] + 16 * qs[3] - qs[4]) / (12 * h * h))

    # Fourth-order stencils at h and h/2: their difference bounds the truncation (large near the
    # workspace edge, where a linear delta's rod lies almost flat); a few ulps of each coordinate
    # over h^2 is their rounding.
    h = 1e-2
    (c1, c2), (fd1, fd2) = stencils(h), stencils(h / 2)
    s1 = np.abs(fd1).max(axis=1, keepdims=True) + 1e-9
    s2 = np.abs(fd2).max(axis=1, keepdims=True) + np.abs(fd1).max(axis=1, keepdims=True) ** 2 + 1e-9
    rounding = 160 * np.finfo(float).eps * (np.abs(q) + 1) / (h * h)
    assert np.all(np.abs(d1 - fd1) <= 1e-8 * s1 + np.abs(c1 - fd1))
    assert np.all(np.abs(d2 - fd2) <= 1e-6 * s2 + np.abs(c2 - fd2) + rounding)
    assert np.allclose(d1, np.einsum("nij,nj->ni", kin.inverse_jacobian(q), t), rtol=1e-9, atol=1e-12)
    r1, r2 = Kinematics.path_derivatives(kin, pts, q, t, kappa)
    assert np.all(np.abs(d2 - r2) <= 1e-6 * s2)


@pytest.mark.parametrize("name", CASES)
@SETTINGS
@given(data=st.data())
def test_scaled_path_derivatives_equal_the_separate_calls(name, data):
    """The planner's one call (fused with the inverse in the rotary delta's compiled kernel: cos q
    and sin q from the root itself, scaled as written) gives what ``inverse`` and
    ``path_derivatives`` give, into strided views, NaN rows and the first unreachable point
    included."""
    kin, pts = reachable_batch(name, data)
    pts = np.vstack([pts, [[np.nan, 0.0, 0.0], [1e6, 0.0, 0.0]]])
    t = np.vstack([unit_rows(data, len(pts) - 2), [[1.0, 0.0, 0.0]] * 2])
    kappa = np.zeros_like(t)
    scale = data.draw(st.floats(0.5, 300.0))
    J = kin.n_joints
    d1, d2 = np.zeros((len(pts), J + 1)), np.zeros((len(pts), J + 1))  # the planner's (N, dof) arrays
    first = kin.scaled_path_derivatives(pts, t, kappa, scale, d1[:, :J], d2[:, :J])
    assert first == len(pts) - 2
    assert not d1[:, J].any() and not d2[:, J].any()
    q0 = kin.inverse(pts)
    e1, e2 = kin.path_derivatives(pts, q0, t, kappa)
    ok = np.isfinite(q0).all(axis=1)
    assert np.isnan(d1[~ok, :J]).all() and np.isnan(d2[~ok, :J]).all()
    assert np.allclose(d1[ok, :J], e1[ok] * scale, rtol=1e-9, atol=1e-12)
    assert np.allclose(d2[ok, :J], e2[ok] * scale * scale, rtol=1e-9, atol=1e-12)
    reach = np.zeros((len(pts) - 2, J))
    assert kin.scaled_path_derivatives(pts[:-2], t[:-2], kappa[:-2], scale, reach, reach.copy()) == -1
    short = np.zeros((len(pts) + 4, J))[:2]  # too few rows: refused, nothing written past them
    with pytest.raises(ValueError):
        kin.scaled_path_derivatives(pts, t, kappa, scale, short, short.copy())
    assert not short.base[2:].any()



@pytest.mark.parametrize("name", CASES)
@SETTINGS
@given(data=st.data())
def test_inverse_jacobian_times_jacobian_is_identity(name, data):
    kin, pts = reachable_batch(name, data)
    q = kin.inverse(pts)
    prod = kin.inverse_jacobian(q) @ kin.jacobian(q)
    assert np.max(np.abs(prod - np.eye(3))) <= 1e-9


# --------------------------------------------------------------------------- independent forward solve


def closure_residuals(kin, q):
    """|E_i - B_i| - L per arm as a function of the tool point, written from the
    geometry alone (no code of the kinematics module)."""
    g = kin.geometry
    ang = np.radians([0.0, 120.0, 240.0])
    u = np.stack([np.cos(ang), np.sin(ang), np.zeros(3)], axis=1)
    ez = np.array([0.0, 0.0, 1.0])
    if isinstance(kin, RotaryDelta):
        elbows = g.base_radius * u + g.shoulder_height * ez + g.upper_arm * (
            np.cos(q)[:, None] * u - np.sin(q)[:, None] * ez
        )
        return lambda p: np.linalg.norm(elbows - (p + g.platform_radius * u + g.tool_offset * ez), axis=1) - g.forearm
    carriages = g.delta_radius * u + q[:, None] * ez
    return lambda p: np.linalg.norm(carriages - (p + g.tool_offset * ez), axis=1) - g.diagonal_rod


def start_below_base(kin, q):
    g = kin.geometry
    if isinstance(kin, RotaryDelta):
        return np.array([0.0, 0.0, g.shoulder_height - g.tool_offset - g.forearm])
    return np.array([0.0, 0.0, q.min() - g.tool_offset - 0.7 * g.diagonal_rod])


DELTAS = [n for n in PRINTER_NAMES if isinstance(printer(n).kinematics(), (RotaryDelta, LinearDelta))]


@pytest.mark.parametrize("name", DELTAS)
@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(data=st.data())
def test_delta_forward_matches_numeric_solve(name, data):
    kin, pts = reachable_batch(name, data)
    qs = kin.inverse(pts)
    ours = kin.forward(qs)
    for q, p in zip(qs, ours):
        sol = least_squares(closure_residuals(kin, q), start_below_base(kin, q), xtol=1e-15, ftol=1e-15, gtol=1e-15)
        assert np.max(np.abs(sol.fun)) < 1e-9
        assert np.max(np.abs(sol.x - p)) < 1e-7


# --------------------------------------------------------------------------- unreachable: NaN, never an exception


def _quiet(fn, *args):
    """Call fn with every numpy warning turned into an error: on finite input, hot loops
    must stay silent."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return fn(*args)


def _no_raise(fn, *args):
    """Call fn on NaN/inf input: warnings allowed, exceptions not."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*args)


@pytest.mark.parametrize("name", CASES)
@SETTINGS
@given(data=st.data())
def test_anywhere_no_exception_and_consistent_masks(name, data):
    kin = kin_of(name)
    coord = st.floats(-3000.0, 3000.0, allow_nan=False)
    pts = np.array(data.draw(st.lists(st.tuples(coord, coord, coord), min_size=1, max_size=16)))
    q = _quiet(kin.inverse, pts)
    ok = _quiet(kin.reachable, pts)
    assert q.shape == (len(pts), 3) and ok.dtype == bool and ok.shape == (len(pts),)
    finite = np.isfinite(q)
    assert np.all(finite.all(axis=1) | ~finite.any(axis=1)), "a row is all NaN or all finite"
    assert not np.any(ok & ~finite.all(axis=1)), "NaN inverse must be unreachable"
    assert np.all(kin.within_joint_limits(q[ok]))
    if ok.any():  # where reachable, forward and both Jacobians are finite
        qq = q[ok]
        assert np.all(np.isfinite(_quiet(kin.forward, qq)))
        assert np.all(np.isfinite(_quiet(kin.jacobian, qq)))
        assert np.all(np.isfinite(_quiet(kin.inverse_jacobian, qq)))


@pytest.mark.parametrize("name", CASES)
def test_far_and_invalid_points(name):
    kin = kin_of(name)
    pts = np.array(
        [
            [1e5, 0.0, 0.0],
            [0.0, -1e5, 50.0],
            [0.0, 0.0, 1e5] if name != "cartesian" else [0.0, 0.0, -1e5],
            [np.nan, 0.0, 0.0],
            [0.0, np.inf, 0.0],
            [0.0, 0.0, -np.inf],
        ]
    )
    q = _no_raise(kin.inverse, pts)
    ok = _no_raise(kin.reachable, pts)
    assert not ok.any()
    assert not _quiet(kin.reachable, pts[:3]).any()
    if name != "cartesian":  # a Cartesian machine's inverse is defined everywhere; only its limits refuse
        assert np.all(np.isnan(q[:2]))  # (a prismatic z axis reaches any height; its limits refuse 1e5)
    assert np.all(np.isnan(q[3:]))
    bad_q = np.array([[np.nan, 0.0, 0.0], [0.0, np.inf, 0.0]])
    assert np.all(np.isnan(_no_raise(kin.forward, bad_q)))
    assert np.all(np.isinf(_no_raise(kin.condition, bad_q)))
    assert _quiet(kin.reachable, np.empty((0, 3))).shape == (0,)


@pytest.mark.parametrize("name", [n for n in CASES if family_of(n) in ("rotary_delta", "linear_delta")])
def test_compiled_inverse_refuses_rows_not_of_three(name):
    """The compiled families' kernels read three columns unchecked: rows of two (or a bare
    list of four numbers) are refused, not read past their ends into garbage angles."""
    kin = kin_of(name)
    for bad in (np.zeros((4, 2)), np.zeros(4), np.zeros((2, 3, 1))):
        with pytest.raises(ValueError, match="rows of 3"):
            kin.inverse(bad)
    assert kin.inverse(np.array([0.0, 0.0, 100.0])).shape == (1, 3)


@pytest.mark.parametrize("name", CASES)
@SETTINGS
@given(data=st.data())
def test_inverse_into_writes_inverse(name, data):
    """inverse_into (the sampler's call, compiled straight into a block's rows in the deltas) writes
    the very values of inverse, NaN rows included, into every row of out and nowhere else; an out
    of another shape or dtype is refused, not written past its end."""
    kin = kin_of(name)
    pts = np.concatenate([data.draw(point_batches(*box_of(name))), [[1e5, 0.0, 0.0], [np.nan, 0.0, 0.0]]])
    rows = np.full((len(pts) + 2, kin.n_joints), -7.0)
    kin.inverse_into(pts, rows[1:-1])
    np.testing.assert_array_equal(rows[1:-1], _quiet(kin.inverse, pts))
    assert np.all(rows[[0, -1]] == -7.0)
    for bad in (np.empty((len(pts) - 1, kin.n_joints)), np.empty((len(pts), kin.n_joints), dtype=np.float32)):
        with pytest.raises(ValueError, match="out"):
            kin.inverse_into(pts, bad)


def test_rotary_forward_nan_where_forearms_cannot_meet():
    # Forearms (40 mm) shorter than the distance from the axis to the sphere centres (85 mm).
    g = RotaryDeltaGeometry(base_radius=60.0, platform_radius=35.0, upper_arm=60.0, forearm=40.0, shoulder_height=110.0)
    kin = make_kinematics(g, np.radians([-90.0] * 3), np.radians([90.0] * 3))
    assert np.all(np.isnan(_quiet(kin.forward, np.zeros((2, 3)))))
    assert not _quiet(kin.reachable, np.array([[0.0, 0.0, -60.0]])).any()  # 162 mm from a shoulder > 100
    assert _quiet(kin.reachable, np.array([[0.0, 0.0, 50.0]])).all()


# --------------------------------------------------------------------------- vectorisation


@pytest.mark.parametrize("name", CASES)
@settings(max_examples=15, deadline=None)
@given(data=st.data())
def test_batch_equals_point_by_point(name, data):
    kin = kin_of(name)
    lo, hi = box_of(name)
    pad = 0.3 * (hi - lo)  # reach past the box so some rows are unreachable
    pts = data.draw(point_batches(lo - pad, hi + pad, max_size=10))
    q = kin.inverse(pts)
    ok = kin.reachable(pts)
    for i in range(len(pts)):
        one = pts[i : i + 1]
        np.testing.assert_allclose(kin.inverse(one)[0], q[i], rtol=1e-13, atol=1e-12)
        assert kin.reachable(one)[0] == ok[i]
    good = np.all(np.isfinite(q), axis=1)
    qg = q[good]
    batch = {f: getattr(kin, f)(qg) for f in ("forward", "jacobian", "inverse_jacobian", "condition")}
    for i in range(len(qg)):
        for f, value in batch.items():
            np.testing.assert_allclose(getattr(kin, f)(qg[i : i + 1])[0], value[i], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("name", [n for n in CASES if family_of(n) == "rotary_delta"])
def test_rotary_kernels_equal_point_by_point_across_their_blocks(name):
    """The rotary delta's compiled kernels go a block of points at a time (rotary_delta.BLOCK, for
    vector instructions): across block ends, with unreachable rows at and beside them (the
    first of them in a later block), a batch gives every point's values alone, bit for bit, and
    the first unreachable row."""
    from deltaslice.kinematics import rotary_delta

    kin = kin_of(name)
    lo, hi = box_of(name)
    n = 2 * rotary_delta.BLOCK + 7
    rng = np.random.default_rng(3)
    pts = lo + (hi - lo) * rng.uniform(0.3, 0.7, (n, 3))
    far = [rotary_delta.BLOCK + 3, rotary_delta.BLOCK - 1, 2 * rotary_delta.BLOCK, n - 1]
    pts[far] = [[0.0, 0.0, 1e6], [np.nan, 0.0, 0.0], [np.inf, 0.0, 0.0], [0.0, 0.0, -1e3]]
    t = rng.normal(size=(n, 3))
    t /= np.linalg.norm(t, axis=1)[:, None]
    kappa = rng.normal(size=(n, 3))
    q = kin.inverse(pts)
    d1, d2 = np.zeros((n, 4)), np.zeros((n, 4))
    assert kin.scaled_path_derivatives(pts, t, kappa, 7.5, d1[:, :3], d2[:, :3]) == min(far)
    keep = np.delete(np.arange(n), min(far))  # the first unreachable row is then in the second block
    assert kin.scaled_path_derivatives(pts[keep], t[keep], kappa[keep], 7.5, np.empty((n - 1, 3)),
                                       np.empty((n - 1, 3))) == rotary_delta.BLOCK + 2
    assert np.isnan(q[far]).all() and np.isfinite(np.delete(q, far, axis=0)).all()
    for i in range(n):
        one1, one2 = np.empty((1, 3)), np.empty((1, 3))
        kin.scaled_path_derivatives(pts[i : i + 1], t[i : i + 1], kappa[i : i + 1], 7.5, one1, one2)
        assert np.array_equal(kin.inverse(pts[i : i + 1])[0], q[i], equal_nan=True)
        assert np.array_equal(one1[0], d1[i, :3], equal_nan=True) and np.array_equal(one2[0], d2[i, :3], equal_nan=True)
    assert not d1[:, 3].any() and not d2[:, 3].any()


@pytest.mark.parametrize("name", [n for n in CASES if family_of(n) == "rotary_delta"])
def test_rotary_inverse_is_the_knee_outward_root_in_its_range(name):
    """The compiled inverse (its own atan2, then moved into (-2 pi, pi]) against
    the module's formula per arm in numpy, theta = atan2(b, a) - acos(c / hypot(a, b)), over a box
    wider than the reach: the same angles, the same NaN rows, and angles below -pi among them on
    the printers whose joints go there (a wrong range would be off by 2 pi)."""
    from deltaslice.kinematics.rotary_delta import U

    kin = kin_of(name)
    rng = np.random.default_rng(5)
    pts = rng.uniform(-400.0, 400.0, (50_000, 3))
    w = pts[:, None, :] + kin._offsets[None]
    a, b = np.einsum("nij,ij->ni", w, U), -w[..., 2]
    c = (kin.L1**2 + np.einsum("nij,nij->ni", w, w) - kin.L2**2) / (2 * kin.L1)
    with np.errstate(invalid="ignore"):
        want = np.arctan2(b, a) - np.arccos(c / np.hypot(a, b))
    want[np.isnan(want).any(axis=1)] = np.nan
    got = kin.inverse(pts)
    assert np.array_equal(np.isnan(got), np.isnan(want)) and np.isfinite(got).any()
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert got[np.isfinite(got)].min() > -2 * np.pi and got[np.isfinite(got)].max() <= np.pi
    if name != "delta_etitc":  # its arms never reach past -pi in this box
        assert (got < -np.pi).sum() > 100


_ATAN2_SPECIAL = [0.0, -0.0, 1.0, -1.0, 1e-310, -1e-310, 1e300, -1e300, np.inf, -np.inf, np.nan]


@njit(cache=False)
def _atan2_values(y, x, out):
    """The rotary delta's compiled atan2 (inlined, as the inverse calls it) over arrays."""
    for k in range(len(y)):
        out[k] = rotary_atan2(y[k], x[k])


def _atan2_kernel_values(y, x):
    out = np.empty(len(y))
    _atan2_values(np.asarray(y, dtype=float), np.asarray(x, dtype=float), out)
    return out


def _ulps_from_libm(got, y, x):
    want = np.array([math.atan2(b, a) for b, a in zip(y, x)])
    same_bits = (got == want) & (np.signbit(got) == np.signbit(want))
    both_nan = np.isnan(got) & np.isnan(want)
    return np.where(same_bits | both_nan, 0.0, np.abs(got - want) / np.spacing(np.abs(want)))


def test_rotary_atan2_is_libm_on_its_special_values():
    """Signed zeros (atan2(+-0, -0) is +-pi), infinities, subnormals, huge values and NaN, each
    against each: what math.atan2 gives, bit for bit."""
    y, x = (np.array(v, dtype=float).ravel() for v in np.meshgrid(_ATAN2_SPECIAL, _ATAN2_SPECIAL))
    assert not _ulps_from_libm(_atan2_kernel_values(y, x), y, x).any()


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(-300, 300))
def test_rotary_atan2_is_libm_within_two_ulp(seed, log_scale):
    """Angles all round the circle (both octant reductions, every quadrant) at scales from 1e-300 to
    1e300: within 2 ulp of libm's atan2, and mostly the same bits."""
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-np.pi, np.pi, 4000)
    r = 10.0**log_scale * rng.uniform(0.5, 1.0, 4000)
    y, x = r * np.sin(theta), r * np.cos(theta)
    ulps = _ulps_from_libm(_atan2_kernel_values(y, x), y, x)
    assert ulps.max() <= 2.0 and np.mean(ulps == 0) > 0.8


# --------------------------------------------------------------------------- source numbers and regressions


@pytest.mark.parametrize(
    "deg, thesis_z",
    [(0.0, 291.6830), (0.2929, 292.5844), (0.087, 291.9504), (0.061, 291.8705)],
)
def test_etitc_thesis_platform_heights(deg, thesis_z):
    """ETITC sec. 8.4.5: all three joints at deg move the platform centre to thesis Z
    (origin at the base centre, Z down, platform plane)."""
    p = printer("delta_etitc")
    g = p.geometry
    pt = p.kinematics().forward(np.radians([[deg, deg, deg]]))[0]
    assert abs(pt[0]) < 1e-9 and abs(pt[1]) < 1e-9
    assert abs((g.shoulder_height - pt[2] - g.tool_offset) - thesis_z) < 1e-3


def test_etitc_thesis_steps():
    """The resolution steps the thesis quotes: 0.90, 0.2674, 0.1875 mm along the axis."""
    kin = printer("delta_etitc").kinematics()
    z = kin.forward(np.radians([[0.0] * 3, [0.2929] * 3, [0.087] * 3, [0.061] * 3]))[:, 2]
    steps = z[0] - z[1:]
    np.testing.assert_allclose(steps, [0.9014, 0.2674, 0.1875], atol=1e-3)


def test_five_bar_forward_keeps_the_assembly_mode():
    """Regression: the same joint angles served two points (the two assembly modes),
    and forward picked the one behind the motors, ~378 mm from the point asked for."""
    kin = printer("fivebar_atlas").kinematics()
    p = np.array([[0.17209363, 146.84703378, 20.0]])
    assert kin.reachable(p)[0]
    np.testing.assert_allclose(kin.forward(kin.inverse(p)), p, atol=1e-9)
    # The mirror point of the other assembly mode has the same joint angles under the
    # same working mode: it is not the machine's and is unreachable.
    mirror = np.array([[0.0579238564, -231.173904, 20.0]])
    np.testing.assert_allclose(kin.inverse(mirror)[:, :2], kin.inverse(p)[:, :2], atol=1e-6)
    assert not kin.reachable(mirror)[0]
    assert isinstance(kin, FiveBar) and kin.assembly in (1.0, -1.0)


def test_linear_delta_forward_never_puts_a_carriage_below_the_effector():
    """Regression: forward returned points whose rods ran up from a low carriage, so
    inverse(forward(q)) != q for about half of the joint box of the Kossel."""
    kin = printer("linear_kossel").kinematics()
    rng = np.random.default_rng(3)
    q = kin.position_min + rng.random((4000, 3)) * (kin.position_max - kin.position_min)
    pts = kin.forward(q)
    good = np.all(np.isfinite(pts), axis=1)
    assert good.any() and not good.all()
    assert np.all(q[good] - pts[good, 2:3] - kin.t > 0)
    np.testing.assert_allclose(kin.inverse(pts[good]), q[good], atol=1e-9)
    assert isinstance(kin, LinearDelta)


def test_linear_delta_tool_offset_puts_the_tool_below_the_effector_joints():
    """Independent of the kernels: with the tool tip t below the effector's joints, every rod from
    a carriage's joint (tower i at i x 120 deg, delta_radius out, height q_i) to the effector's joint
    (the tool point raised by t) is diagonal_rod long and rises to the carriage; forward gives the
    tool point back. A sign of the offset flipped in inverse, forward or the derivatives fails."""
    kin, g = KOSSEL_OFFSET, KOSSEL_OFFSET.geometry
    assert g.tool_offset == 12.0
    rng = np.random.default_rng(7)
    pts = np.column_stack([rng.uniform(-60, 60, 200), rng.uniform(-60, 60, 200), rng.uniform(0, 150, 200)])
    q = kin.inverse(pts)
    assert np.all(np.isfinite(q))
    angles = np.radians([0.0, 120.0, 240.0])
    carriages = np.stack([np.broadcast_to(g.delta_radius * np.cos(angles), q.shape),
                          np.broadcast_to(g.delta_radius * np.sin(angles), q.shape), q], axis=2)  # (N, 3 towers, xyz)
    joint = pts + [0.0, 0.0, g.tool_offset]
    rods = carriages - joint[:, None, :]
    np.testing.assert_allclose(np.linalg.norm(rods, axis=2), g.diagonal_rod, rtol=0, atol=1e-9)
    assert np.all(rods[..., 2] > 0)
    np.testing.assert_allclose(kin.forward(q), pts, rtol=0, atol=1e-9)
    # the joints' derivatives along a line: d q_i / ds = t_z - (w_i . t_xy) / h_i, h_i the rod's rise
    tangent = np.broadcast_to([0.6, 0.0, 0.8], pts.shape)
    q1, _ = kin.path_derivatives(pts, q, tangent, np.zeros_like(pts))
    w = joint[:, None, :2] - carriages[..., :2]
    np.testing.assert_allclose(q1, 0.8 - (w @ tangent[0, :2]) / rods[..., 2], rtol=0, atol=1e-9)


def test_cartesian_is_an_offset():
    q = CARTESIAN.inverse(np.array([[1.0, 2.0, 3.0]]))
    np.testing.assert_allclose(q, [[111.0, -5.5, 6.0]])
    assert math.isclose(CARTESIAN.condition(q)[0], 1.0)


@pytest.mark.parametrize("name", PRINTER_NAMES)
def test_reachable_in_blocks_equals_reachable_at_once(name, monkeypatch):
    import deltaslice.kinematics.base as base

    kin = printer(name).kinematics()
    rng = np.random.default_rng(3)
    pts = rng.uniform([-120, -120, -5], [120, 120, 150], (500, 3))
    whole = kin.reachable(pts)
    assert whole.any() and not whole.all()
    monkeypatch.setattr(base, "REACH_BLOCK", 37)
    np.testing.assert_array_equal(kin.reachable(pts), whole)


@pytest.mark.parametrize("name", PRINTER_NAMES)
def test_well_conditioned_is_the_svd_condition_below_the_limit(name):
    """The bound that decides most points must never decide one the SVD would not, wherever
    reachable() asks (real inverse, within the joint limits): points everywhere, and points
    walked out along rays to where the mechanism is lost, so that conditions lie on both sides
    of the limit."""
    kin = printer(name).kinematics()
    rng = np.random.default_rng(5)
    centre = kin.forward(0.5 * (kin.position_min + kin.position_max)[None])[0]
    if not np.all(np.isfinite(centre)):
        centre = np.zeros(3)
    rays = rng.normal(size=(200, 3))
    rays /= np.linalg.norm(rays, axis=1)[:, None]
    steps = np.linspace(0.0, 600.0, 3000)
    pts = np.concatenate([(centre + steps[:, None, None] * rays[None]).reshape(-1, 3),
                          rng.uniform([-300, -300, -50], [300, 300, 400], (20000, 3))])
    q = _quiet(kin.inverse, pts)
    keep = np.all(np.isfinite(q), axis=1)
    pts, q = pts[keep], q[keep]
    keep = kin.within_joint_limits(q) & kin.extra_ok(pts, q)  # where reachable() asks for the condition
    pts, q = pts[keep], q[keep]
    cond = _quiet(kin.condition, q)
    assert len(cond) > 1000
    # the printer's own limit, and limits that cut through the sample (most of it is well
    # conditioned inside the joint limits), each with many points within a factor 3 of it
    for limit in (kin.singularity_limit, *np.quantile(cond, [0.2, 0.5, 0.9, 0.999])):
        kin.singularity_limit = limit
        np.testing.assert_array_equal(_quiet(kin.well_conditioned, pts, q), cond < limit)


@pytest.mark.parametrize("name", ["delta_etitc", "delta_ucb", "delta_uady", "delta_espe_laser"])
def test_rotary_compiled_reach_tests_are_the_numpy_forms(name):
    """The rotary delta's compiled condition bound and ball-joint tilt test against the numpy
    they replace (the base's bound from inverse_jacobian, ball_joint_tilt): the same bound to
    rounding (inf and NaN where it is), the same tilt decisions, with a limit that cuts through
    the sample, and NaN joints refused."""
    from deltaslice.kinematics.base import Kinematics

    kin = printer(name).kinematics()
    rng = np.random.default_rng(11)
    pts = _no_raise(kin.forward, rng.uniform(kin.position_min, kin.position_max, (20000, 3)))  # the joint space through
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    q = _quiet(kin.inverse, pts)
    keep = np.all(np.isfinite(q), axis=1)
    pts, q = pts[keep], q[keep]
    q[:5] = [[np.nan, 0, 0], [0, np.inf, 0], [0.3, 0.3, 0.3], [-1.2, -1.2, -1.2], [1.4, -0.9, 0.2]]  # NaN, beyond reach
    pts[5] += [0.0, 3 * kin.L2, 0.0]  # a forearm sideways beyond its length: the tilt's sine clipped to 1
    got, want = _no_raise(kin.condition_bound, q), _no_raise(Kinematics.condition_bound, kin, q)
    finite = np.isfinite(want)
    assert len(q) > 1000 and finite.sum() > 1000
    np.testing.assert_array_equal(np.isfinite(got), finite)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[finite], want[finite], rtol=1e-9)
    tilts = np.abs(_no_raise(kin.ball_joint_tilt, pts, q))
    for limit in (kin.geometry.ball_joint_tilt_max, *np.nanquantile(tilts.max(axis=1), [0.1, 0.5, 0.9]), math.pi / 2):
        tilted = type(kin)(dataclasses.replace(kin.geometry, ball_joint_tilt_max=limit), kin.position_min, kin.position_max)
        want_ok = np.ones(len(q), bool) if limit is None else np.all(tilts <= limit + 1e-12, axis=1)
        np.testing.assert_array_equal(tilted.extra_ok(pts, q), want_ok)
    # the kernels read three columns and a joint row per point unchecked: other shapes are refused
    with pytest.raises(ValueError):
        kin.condition_bound(np.zeros((2, 2)))
    if kin.geometry.ball_joint_tilt_max is not None:
        with pytest.raises(ValueError):
            kin.extra_ok(pts[:3], q[:4])


def test_rotary_condition_bound_leaves_a_level_pair_of_roots_to_the_exact_test():
    """Where the elbows' plane is vertical the forward solution's two roots are level, and which
    one a form takes is rounding: the compiled forward took the other root from numpy's here (a
    helper review's case, delta_ucb with its joints free to +-179 degrees), its bound came out
    10.6 for a pose whose condition is 3224, and the pose was taken as reachable. The bound is NaN
    there, so the exact test decides."""
    from deltaslice.machine import load_printer

    kin = load_printer("delta_ucb", overrides={"joints.position_min": -179.0, "joints.position_max": 179.0}).kinematics()
    p = np.array([[8.972135848523633, 60.60792034664124, 101.81792749111217]])
    q = kin.inverse(p)
    cond = kin.condition(q)[0]
    assert np.isfinite(q).all() and cond > kin.singularity_limit
    bound = kin.condition_bound(q)[0]
    assert not bound < cond * (1 - 1e-9)  # never a bound below the condition it bounds (NaN: ask the SVD)
    assert not kin.well_conditioned(p, q)[0] and not kin.reachable(p)[0]


def test_well_conditioned_judges_the_pose_the_joints_hold():
    """A rotary delta whose joints may pass -90 degrees reaches, by its inverse kinematics, a point
    above the arms whose joint angles the machine holds at the lower root (forward(q)): the
    condition is that pose's (449), not the point's (29), as condition(q) judges it."""
    from deltaslice import load_printer

    kin = load_printer("delta_uady", {"joints.position_min": [-100.0] * 3}).kinematics()
    pt = np.array([[6.83, 1.017, 695.684]])
    q = kin.inverse(pt)
    assert np.all(np.isfinite(q)) and kin.within_joint_limits(q).all()
    assert not np.allclose(kin.forward(q), pt)
    assert kin.condition(q)[0] > kin.singularity_limit
    assert not kin.well_conditioned(pt, q)[0] and not kin.reachable(pt)[0]


def test_rotary_inverse_without_numba_gives_nan_out_of_reach():
    """The kernels' pure-Python fallback (deltaslice.jit without numba) runs the same code: a point
    out of reach is a NaN row, not a math domain error from the discriminant's square root."""
    import os
    import subprocess
    import sys

    code = ("import numpy as np; from deltaslice import load_printer; "
            "q = load_printer('delta_etitc').kinematics().inverse(np.array([[0, 0, 100.0], [0, 0, 5000.0]])); "
            "assert np.isfinite(q[0]).all() and np.isnan(q[1]).all(), q; print('ok')")
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and "ok" in out.stdout, out.stderr[-2000:]
