"""Workspace facts the printer files and docs/printers.md rest on.

UCB (003_*.txt, fig. 5 and annex C): the effective workspace is a hexagonal
prism, vertices (+-50, 0), (+-25, +-40), UCB z = -80..-110 mm (z negative down
from the shoulder plane; our bed is at UCB z = -110, so prism z = 0..30). The
document draws all of it as reachable with joints 0..90 deg; it is not quite.

ETITC (000_*.txt sec. 3.2): a 15 cm build cube was the target; the 13 deg
ball-joint tilt limit bounds it to a 118.6 mm cube and a 162 mm cylinder.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from deltaslice.kinematics import make_kinematics
from deltaslice.kinematics.workspace import analyse

from conftest import PRINTER_NAMES, printer

# --------------------------------------------------------------------------- UCB prism

UCB_SHOULDER = 110.0  # our bed is at UCB z = -110


def prism_points(step_xy=2.0, step_z=1.0):
    """Grid over the UCB hexagonal prism, bed frame (z 0..30)."""
    xs = np.arange(-50.0, 50.0 + step_xy / 2, step_xy)
    ys = np.arange(-40.0, 40.0 + step_xy / 2, step_xy)
    zs = np.arange(0.0, 30.0 + step_z / 2, step_z)
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    p = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    inside = np.abs(p[:, 1]) <= 40.0 * (50.0 - np.abs(p[:, 0])) / 25.0 + 1e-9
    return p[inside]


def ucb_inverse_deg(points):
    """The UCB's own inverse kinematics (annex: Arduino and MATLAB code), in its frame:
    a = -2 z L1, b = 2 L1 (x cos(phi) + y sin(phi) + r - R),
    c = (x + cos(phi)(r - R))^2 + (y + sin(phi)(r - R))^2 + z^2 + L1^2 - L2^2,
    q = asin(c / sqrt(a^2 + b^2)) - atan(b / a). Degrees."""
    R, r, L1, L2 = 60.0, 35.0, 60.0, 90.0
    x, y, z = points[:, 0], points[:, 1], points[:, 2] - UCB_SHOULDER
    out = []
    for phi in np.radians([0.0, 120.0, 240.0]):
        a = -2 * z * L1
        b = 2 * L1 * (x * np.cos(phi) + y * np.sin(phi) + r - R)
        c = (x + np.cos(phi) * (r - R)) ** 2 + (y + np.sin(phi) * (r - R)) ** 2 + z**2 + L1**2 - L2**2
        with np.errstate(invalid="ignore"):
            out.append(np.degrees(np.arcsin(c / np.sqrt(a**2 + b**2)) - np.arctan(b / a)))
    return np.stack(out, axis=1)


def test_ucb_geometry_is_the_code_that_ran():
    g = printer("delta_ucb").geometry
    assert (g.base_radius, g.platform_radius, g.upper_arm, g.forearm) == (60.0, 35.0, 60.0, 90.0)
    assert g.shoulder_height == UCB_SHOULDER and g.tool_offset == 0.0 and g.ball_joint_tilt_max is None
    j = printer("delta_ucb").joints
    assert all(math.isclose(math.degrees(x.position_min), 0.0) and math.isclose(math.degrees(x.position_max), 90.0) for x in j)


def test_ucb_inverse_matches_the_ucb_code():
    pts = prism_points()
    ours = np.degrees(printer("delta_ucb").kinematics().inverse(pts))
    np.testing.assert_allclose(ours, ucb_inverse_deg(pts), atol=1e-9)


def test_ucb_prism_reachability_equals_joint_range_truth():
    """Reachable exactly where the UCB's own inverse gives every joint in 0..90 deg."""
    pts = prism_points()
    kin = printer("delta_ucb").kinematics()
    ok = kin.reachable(pts)
    q = ucb_inverse_deg(pts)
    truth = np.all((q >= -1e-7) & (q <= 90 + 1e-7), axis=1)
    np.testing.assert_array_equal(ok, truth)
    # The singularity limit plays no part here (condition number <= 2.9 in the prism).
    assert kin.condition(kin.inverse(pts)).max() < 3.0


def test_ucb_prism_is_almost_all_reachable_and_fails_at_the_top_vertices():
    pts = prism_points()
    kin = printer("delta_ucb").kinematics()
    ok = kin.reachable(pts)
    frac = ok.mean()
    assert 0.995 < frac < 1.0  # 99.95 % on a 0.25 mm grid (docs/printers.md)
    bad = pts[~ok]
    q = ucb_inverse_deg(bad)
    # Every failure is one joint leaving 0..90: above horizontal at the top, past vertical at one vertex.
    top = bad[:, 2] >= 27.0
    assert np.all(q[top].min(axis=1) < 0) and q[top].min() > -3.0
    assert np.all(np.isclose(bad[~top], [-50.0, 0.0, 0.0]).all(axis=1)), bad[~top]
    # The top failures sit near the three vertices that face the motors (0, 120, 240 deg).
    ang = np.degrees(np.arctan2(bad[top, 1], bad[top, 0]))
    near_motor = np.min(np.abs(((ang[:, None] - [0.0, 120.0, -120.0]) + 180) % 360 - 180), axis=1)
    assert np.all(near_motor < 12.0)
    assert np.hypot(bad[top, 0], bad[top, 1]).min() > 43.0


@pytest.mark.parametrize(
    "point, reachable, joint, q_deg",
    [
        ((50.0, 0.0, 30.0), False, 0, -2.8145),  # vertex toward motor 1, top: arm 1 above horizontal
        ((-25.0, 40.0, 30.0), False, 1, -1.5697),  # vertex near motor 2, top
        ((-25.0, -40.0, 30.0), False, 2, -1.5697),  # vertex near motor 3, top
        ((-50.0, 0.0, 0.0), False, 0, 90.1595),  # vertex opposite motor 1, bottom: arm 1 past vertical
        ((50.0, 0.0, 0.0), True, 0, 24.61),
        ((-50.0, 0.0, 30.0), True, 0, 78.03),
        ((0.0, 0.0, 30.0), True, 0, 31.894),
        ((0.0, 0.0, 0.0), True, 0, 50.221),
        ((45.0, 0.0, 27.0), True, 0, 2.249),
    ],
)
def test_ucb_specific_points(point, reachable, joint, q_deg):
    kin = printer("delta_ucb").kinematics()
    p = np.array([point])
    q = np.degrees(kin.inverse(p))[0]
    assert q[joint] == pytest.approx(q_deg, abs=0.01)
    assert kin.reachable(p)[0] == reachable
    assert kin.reachable(p)[0] == bool(np.all((q >= 0) & (q <= 90)))


def test_ucb_test_square_is_reachable():
    """The document's test sequence: the square (+-30, +-30) at UCB z = -90 (bed z = 20)."""
    s = np.linspace(-30.0, 30.0, 61)
    edge = np.concatenate([np.stack([s, np.full_like(s, v)], 1) for v in (-30.0, 30.0)]
                          + [np.stack([np.full_like(s, v), s], 1) for v in (-30.0, 30.0)])
    pts = np.column_stack([edge, np.full(len(edge), UCB_SHOULDER - 90.0)])
    assert printer("delta_ucb").kinematics().reachable(pts).all()


# --------------------------------------------------------------------------- every shipped bed


@pytest.mark.parametrize("name", PRINTER_NAMES)
def test_whole_bed_reachable_up_to_max_height(name):
    """The contract the slicer leans on: every point of the bed (disk or rectangle),
    from z = 0 to [bed] max_height, is reachable."""
    p = printer(name)
    bed = p.bed
    t = np.linspace(0, 1, 25)
    if bed.shape == "circle":
        ang = np.linspace(0, 2 * np.pi, 240, endpoint=False)
        rr = np.concatenate([[0.0], bed.radius * np.sqrt(t[1:])])
        xy = np.concatenate([[[0.0, 0.0]]] + [np.stack([r * np.cos(ang), r * np.sin(ang)], 1) for r in rr[1:]])
    else:
        g = np.linspace(-0.5, 0.5, 41)
        X, Y = np.meshgrid(g * bed.size_x, g * bed.size_y)
        xy = np.stack([X.ravel(), Y.ravel()], 1)
    z = np.linspace(0.0, bed.max_height, 16)
    pts = np.column_stack([np.tile(xy, (len(z), 1)), np.repeat(z, len(xy))])
    ok = p.kinematics().reachable(pts)
    assert ok.all(), f"{name}: {np.count_nonzero(~ok)} bed points unreachable, e.g. {pts[~ok][:3]}"


# --------------------------------------------------------------------------- ETITC build volume

ETITC_TILT_HEX = 360.0 * math.sin(math.radians(13.0))  # |p . v_i| <= L2 sin(13 deg) = 80.98 mm
ETITC_CUBE = 2 * ETITC_TILT_HEX / (math.cos(math.radians(30.0)) + 0.5)  # square in that hexagon: 118.57 mm


def etitc_kinematics(tilt=True):
    p = printer("delta_etitc")
    g = p.geometry if tilt else dataclasses.replace(p.geometry, ball_joint_tilt_max=None)
    return make_kinematics(g, p.limits.position_min[:p.n_joints], p.limits.position_max[:p.n_joints], p.planning.singularity_limit)


def test_etitc_tilt_bounds_a_hexagon():
    """The tilt of forearm i out of its arm's plane depends on x-y only: sin(tilt) = p . v_i / L2.
    So the tilt limit is a hexagonal column of inradius 80.98 mm, and the largest square
    in it has half-width 59.28 mm at its corners."""
    kin = etitc_kinematics()
    for z in (0.0, 60.0, 118.0, 250.0):
        a = ETITC_CUBE / 2
        inner = np.array([[sx * (a - 0.05), sy * (a - 0.05), z] for sx in (-1, 1) for sy in (-1, 1)])
        outer = np.array([[sx * (a + 0.05), sy * (a + 0.05), z] for sx in (-1, 1) for sy in (-1, 1)])
        assert kin.reachable(inner).all() and not kin.reachable(outer).any()
        # Flat edges at y = +-80.98 (arm 1's tangent direction is y).
        h = ETITC_TILT_HEX
        assert kin.reachable(np.array([[0.0, h - 0.05, z], [0.0, -(h - 0.05), z]])).all()
        assert not kin.reachable(np.array([[0.0, h + 0.05, z], [0.0, -(h + 0.05), z]])).any()
    # Without the limit the same corners are well inside.
    assert etitc_kinematics(tilt=False).reachable(np.array([[70.0, 70.0, 60.0]])).all()


def test_etitc_build_volume_with_and_without_tilt_limit():
    cpu = printer("delta_etitc").limits.counts_per_unit[:printer("delta_etitc").n_joints]
    # Coarse grids (z step 5 mm, radius step 2 / 5 mm) to stay fast; docs/printers.md has the fine figures.
    rep = analyse(etitc_kinematics(), cpu, (-40.0, 300.0), 100.0, nz=69, nr=51)
    dr = 2.0
    side = 2 * rep.cube_on_bed.half_width
    assert ETITC_CUBE - 2 * dr <= side <= ETITC_CUBE + 1e-6  # 116 on this grid, 118.57 exact
    assert rep.cube_on_bed.z0 == pytest.approx(0.0, abs=1e-9)
    # The shoulder height puts the largest cube on the bed: within a grid step of the largest anywhere.
    assert 2 * rep.cube.half_width - side <= 2 * dr
    # Cylinder: the hexagon's inscribed disk, 162 mm, standing on the bed and 260 mm tall.
    assert 2 * ETITC_TILT_HEX - 2 * dr <= 2 * rep.cylinder_on_bed.half_width <= 2 * ETITC_TILT_HEX
    assert rep.cylinder_on_bed.height >= 255.0
    # The thesis's 15 cm cube does not fit with the 13 deg ball joints...
    assert side < 150.0
    # ... and does without them: the joint range and forearms then allow ~208 mm on the bed.
    free = analyse(etitc_kinematics(tilt=False), cpu, (-60.0, 300.0), 360.0, nz=73, nr=73)
    assert 2 * free.cube_on_bed.half_width > 190.0
    assert 2 * free.cylinder_on_bed.half_width > 280.0
    assert free.reachable_volume > 5 * rep.reachable_volume
