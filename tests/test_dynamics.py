"""The inverse dynamics of every family (issue 56) against calculations that share none of its code:
the static torques against the gradient of the potential energy, and the work the joints do along a
trajectory against the change of kinetic plus potential energy, both from the bodies' positions by
forward kinematics (velocities by finite differences in time, each uniform rod's kinetic energy in
its own closed form, not the model's three-point split)."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
from conftest import PRINTER_DIR, printer
from hypothesis import given, settings
from hypothesis import strategies as st

from deltaslice.errors import PrinterFileError
from deltaslice.kinematics.base import path_coefficients
from deltaslice.kinematics.five_bar import FiveBar, FiveBarGeometry, FiveBarMasses
from deltaslice.kinematics.linear_delta import LinearDelta, LinearDeltaGeometry, LinearDeltaMasses
from deltaslice.kinematics.rotary_delta import RotaryDelta, RotaryDeltaGeometry, RotaryDeltaMasses
from deltaslice.machine import load_printer, printer_from_dict
from deltaslice.machine.dynamics import ActuatorCurves, sampled_torques

G = 9.80665
ANG = np.radians([0.0, 120.0, 240.0])
UNIT = np.stack([np.cos(ANG), np.sin(ANG), np.zeros(3)], axis=1)


def rod_kinetic(m, va, vb):
    """A uniform thin rod's kinetic energy from its ends' velocities (m/s): the integral of
    m/2 |v|^2 along it, v linear from va to vb."""
    return m / 6 * (np.einsum("...i,...i->...", va, va) + np.einsum("...i,...i->...", va, vb)
                    + np.einsum("...i,...i->...", vb, vb))


# ------------------------------------------------------------------------------------ the machines
# Each machine: its kinematics, masses (unequal and odd on purpose, so a term applied to the wrong
# body shows), a trajectory's centre and amplitude in joint units, and its energies from positions:
# potential(q (N, 3)) -> (N,) J and kinetic(q (T, 3) sampled every dt s) -> (T,) J.

Z = np.array([0.0, 0.0, 1.0])


class Rotary:
    kin = RotaryDelta(RotaryDeltaGeometry(93.5, 58.5, 176.0, 360.0, 527.0, 40.0, None),
                      np.radians([-45.0] * 3), np.radians([90.0] * 3))
    m = RotaryDeltaMasses(upper_arm_mass=0.05793, upper_arm_inertia=0.0021, upper_arm_com=70.0, elbow_mass=0.06124,
                          forearm_mass=0.08, platform_mass=0.76872, rotor_inertia=0.003)
    centre, amplitude = np.radians([30.0, 25.0, 35.0]), np.radians([25.0, 30.0, 20.0])

    @classmethod
    def bodies(cls, q):
        """Platform (N, 3) and elbows (N, 3, 3), m: the platform translates, so each of its points
        moves as the tool tip; the elbows from the thesis's geometry."""
        g = cls.kin.geometry
        c, s = np.cos(q)[..., None], np.sin(q)[..., None]
        shoulder = (g.base_radius * UNIT + g.shoulder_height * Z) * 1e-3
        return cls.kin.forward(q) * 1e-3, shoulder + g.upper_arm * 1e-3 * (c * UNIT - s * Z)

    @classmethod
    def potential(cls, q):
        m = cls.m
        p, e = cls.bodies(q)
        arm = -m.upper_arm_com * 1e-3 * np.sin(q)  # the arm's centre of mass below its shoulder
        return G * (m.upper_arm_mass * arm.sum(1) + m.elbow_mass * e[..., 2].sum(1)
                    + m.forearm_mass * (0.5 * (e[..., 2] + p[:, None, 2])).sum(1) + m.platform_mass * p[:, 2])

    @classmethod
    def kinetic(cls, q, dt):
        m = cls.m
        p, e = cls.bodies(q)
        vp, ve, qd = (np.gradient(x, dt, axis=0) for x in (p, e, q))
        return (0.5 * (m.upper_arm_inertia + m.rotor_inertia) * (qd**2).sum(1) + 0.5 * m.elbow_mass * (ve**2).sum((1, 2))
                + rod_kinetic(m.forearm_mass, ve, vp[:, None]).sum(1) + 0.5 * m.platform_mass * (vp**2).sum(1))


class Linear:
    kin = LinearDelta(LinearDeltaGeometry(105.0, 215.0, 12.0), np.zeros(3), np.full(3, 480.0))
    m = LinearDeltaMasses(carriage_mass=0.083, rod_mass=0.041, effector_mass=0.27, drive_mass=0.055)
    centre, amplitude = np.array([300.0, 310.0, 290.0]), np.array([40.0, 55.0, 35.0])

    @classmethod
    def bodies(cls, q):
        """Effector joints' point (N, 3) and carriages (N, 3, 3), m."""
        towers = np.concatenate([cls.kin.towers, np.zeros((3, 1))], axis=1)
        eff = cls.kin.forward(q) + cls.kin.geometry.tool_offset * Z
        return eff * 1e-3, (towers[None] + q[..., None] * Z) * 1e-3

    @classmethod
    def potential(cls, q):
        m = cls.m
        p, c = cls.bodies(q)
        return G * (m.carriage_mass * c[..., 2].sum(1) + m.rod_mass * (0.5 * (c[..., 2] + p[:, None, 2])).sum(1)
                    + m.effector_mass * p[:, 2])

    @classmethod
    def kinetic(cls, q, dt):
        m = cls.m
        p, c = cls.bodies(q)
        vp, vc = np.gradient(p, dt, axis=0), np.gradient(c, dt, axis=0)
        return (0.5 * (m.carriage_mass + m.drive_mass) * (vc**2).sum((1, 2)) + rod_kinetic(m.rod_mass, vc, vp[:, None]).sum(1)
                + 0.5 * m.effector_mass * (vp**2).sum(1))


class Five:
    geometry = FiveBarGeometry(80.0, 150.0, 200.0, 150.0, 200.0, -40.0, -190.0, 1, -1)
    kin = FiveBar(geometry, np.array([np.radians(-60), np.radians(-60), 0.0]), np.array([np.radians(240), np.radians(240), 150.0]))
    m = FiveBarMasses(proximal_inertia=(0.0011, 0.0017), elbow_mass=0.021, distal_mass=0.047, tool_mass=0.31,
                      z_mass=2.3, z_carries="bed", rotor_inertia=0.0004)
    centre, amplitude = np.array([np.radians(120.0), np.radians(50.0), 60.0]), np.array([np.radians(15.0), np.radians(18.0), 30.0])

    @classmethod
    def bodies(cls, q):
        """Tool point (N, 2) and elbows B, D (N, 2, 2) in the linkage's plane, m."""
        g = cls.geometry
        a = np.array([g.origin_x, g.origin_y])
        motors = np.stack([a, a + [g.base_length, 0.0]])
        lengths = np.array([g.proximal_a, g.proximal_c])[:, None]
        elbows = motors + lengths * np.stack([np.cos(q[:, :2]), np.sin(q[:, :2])], axis=2)
        return cls.kin.forward(q)[:, :2] * 1e-3, elbows * 1e-3

    @classmethod
    def potential(cls, q):
        return -G * cls.m.z_mass * q[:, 2] * 1e-3  # the bed goes down as the tool height grows

    @classmethod
    def kinetic(cls, q, dt):
        m = cls.m
        p, e = cls.bodies(q)
        vp, ve, qd = (np.gradient(x, dt, axis=0) for x in (p, e, q))
        return (0.5 * ((np.array(m.proximal_inertia) + m.rotor_inertia) * qd[:, :2] ** 2).sum(1)
                + 0.5 * m.elbow_mass * (ve**2).sum((1, 2)) + rod_kinetic(m.distal_mass, ve, vp[:, None]).sum(1)
                + 0.5 * m.tool_mass * (vp**2).sum(1) + 0.5 * m.z_mass * (qd[:, 2] * 1e-3) ** 2)


class FiveHead(Five):
    """The five-bar whose lead screw lifts the head (linkage and all) instead of the bed."""

    m = FiveBarMasses(proximal_inertia=(0.0011, 0.0017), elbow_mass=0.021, distal_mass=0.047, tool_mass=0.31,
                      z_mass=1.7, z_carries="head", rotor_inertia=0.0004)

    @classmethod
    def potential(cls, q):
        return G * cls.m.z_mass * q[:, 2] * 1e-3


MACHINES = {"rotary_delta": Rotary, "linear_delta": Linear, "five_bar": Five, "five_bar_head": FiveHead}


def trajectory(machine, phases, freqs, duration, dt):
    """Joints q(t) = centre + amplitude sin(2 pi f t + phase), with their exact qd and qdd, every dt s."""
    t = np.arange(0.0, duration + dt / 2, dt)[:, None]
    w = 2 * np.pi * np.asarray(freqs)
    arg = w * t + np.asarray(phases)
    a = machine.amplitude
    return t[:, 0], machine.centre + a * np.sin(arg), a * w * np.cos(arg), -a * w**2 * np.sin(arg)


def si_rates(machine, qd):
    """Joint velocities in SI (rad/s, m/s) from joint units per second (rad, mm)."""
    return qd * np.array([1.0 if k == "revolute" else 1e-3 for k in machine.kin.joint_kinds])


def energy_balance(machine, phases, freqs, duration=0.4, dt=2e-5):
    """(work done by the joints, change of kinetic + potential energy, work throughput), J, over a
    trajectory: the work by Simpson's rule on tau . qd; the energies from positions only, at the
    samples where central differences exist (all but the first and last)."""
    t, q, qd, qdd = trajectory(machine, phases, freqs, duration, dt)
    tau = machine.kin.inverse_dynamics(machine.m, q, qd, qdd)
    power = np.einsum("nj,nj->n", tau, si_rates(machine, qd))[1:-1]
    if len(power) % 2 == 0:
        power = power[:-1]
    n = len(power)
    work = dt / 3 * (power[0] + power[-1] + 4 * power[1:-1:2].sum() + 2 * power[2:-1:2].sum())
    energy = machine.kinetic(q, dt) + machine.potential(q)
    return work, energy[n] - energy[1], dt * np.abs(power).sum()


@pytest.mark.parametrize("name", sorted(MACHINES))
def test_static_torques_are_the_gradient_of_the_potential_energy(name):
    """At rest, tau = dV/dq: V from the bodies' heights by forward kinematics, its gradient by
    central differences (joint steps of 1e-6 rad or 1e-4 mm)."""
    machine = MACHINES[name]
    rng = np.random.default_rng(7)
    q = machine.centre + machine.amplitude * rng.uniform(-1, 1, (40, 3))
    tau = machine.kin.inverse_dynamics(machine.m, q, np.zeros_like(q), np.zeros_like(q))
    assert np.all(np.isfinite(tau))
    grad = np.empty_like(q)
    for j, kind in enumerate(machine.kin.joint_kinds):
        h = 1e-6 if kind == "revolute" else 1e-4
        step = np.zeros(3)
        step[j] = h
        # dV/dq per joint unit; a prismatic joint's unit is the mm, its force N = J/m
        grad[:, j] = (machine.potential(q + step) - machine.potential(q - step)) / (2 * h) * (1 if kind == "revolute" else 1e3)
    assert np.abs(tau - grad).max() < 1e-6 * max(1.0, np.abs(grad).max()), np.abs(tau - grad).max()


@pytest.mark.parametrize("name", sorted(MACHINES))
def test_work_of_the_joints_is_the_change_of_energy(name):
    """Integral of tau . qd dt = change of kinetic + potential energy along a trajectory that
    speeds up and slows down every joint (a dropped velocity term, a misplaced mass or a wrong
    rod split each break it by far more than the tolerance)."""
    machine = MACHINES[name]
    work, change, throughput = energy_balance(machine, [0.3, 1.9, 4.0], [2.3, 1.7, 3.1])
    assert throughput > 0.05
    assert abs(work - change) < 1e-6 * throughput, (work, change, throughput)


@settings(max_examples=12, deadline=None)
@given(name=st.sampled_from(sorted(MACHINES)), phases=st.lists(st.floats(0, 6.3), min_size=3, max_size=3),
       freqs=st.lists(st.floats(0.5, 4.0), min_size=3, max_size=3))
def test_energy_balance_holds_on_any_trajectory(name, phases, freqs):
    machine = MACHINES[name]
    work, change, throughput = energy_balance(machine, phases, freqs, duration=0.3)
    assert abs(work - change) < 1e-6 * throughput + 1e-9, (work, change, throughput)


@pytest.mark.parametrize("name", sorted(MACHINES))
def test_path_coefficients_give_the_torque_along_a_path(name):
    """tau(q, q' sd, q' sdd + q'' sd^2) = A sdd + B sd^2 + C at any path speed sd and acceleration
    sdd: the torque is linear in sdd and in sd^2, the form the planner's constraints take."""
    machine = MACHINES[name]
    rng = np.random.default_rng(3)
    s = rng.uniform(0, 1, 200)[:, None]
    k, phase = np.array([2.1, -1.3, 2.9]), np.array([0.4, 1.1, 2.0])
    q = machine.centre + machine.amplitude * np.sin(k * s + phase)
    dq = machine.amplitude * k * np.cos(k * s + phase)
    ddq = -machine.amplitude * k**2 * np.sin(k * s + phase)
    sd, sdd = rng.uniform(-3, 3, (200, 1)), rng.uniform(-40, 40, (200, 1))
    a, b, c = path_coefficients(lambda *x: machine.kin.inverse_dynamics(machine.m, *x), q, dq, ddq)
    direct = machine.kin.inverse_dynamics(machine.m, q, dq * sd, dq * sdd + ddq * sd**2)
    assert np.all(np.isfinite(direct))
    assert np.allclose(a * sdd + b * sd**2 + c, direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max())


# ------------------------------------------------------------------------------- the printer file

ETITC_TEXT = (PRINTER_DIR / "delta_etitc.toml").read_text()


def _load(tmp_path, text):
    path = tmp_path / "p.toml"
    path.write_text(text)
    return load_printer(path)


def test_etitc_masses_are_the_thesis_parts():
    m = printer("delta_etitc").dynamics.masses
    hardware = 2 * 0.025 + 2 * 0.00362 + 0.004  # two rod ends, two nuts, one axle at each end of a chain
    assert m.elbow_mass == pytest.approx(hardware)
    assert m.platform_mass == pytest.approx(0.085 + 0.5 + 3 * hardware)
    assert m.forearm_mass == pytest.approx(2 * 0.040) and m.upper_arm_mass == pytest.approx(0.05793)
    a = printer("delta_etitc").dynamics.actuators
    assert a.stall == pytest.approx((0.20 * 9.807,) * 3, abs=5e-4) and np.degrees(a.no_load_speed[0]) == pytest.approx(60 / 0.2)


def test_gravity_at_the_bed_centre_takes_28_percent_of_stall():
    """The issue's figure: gravity alone takes 28-41 % of the 9805BB's stall near the bed."""
    p = printer("delta_etitc")
    q = p.kinematics().inverse(np.array([[0.0, 0.0, 0.5]]))
    tau = p.joint_torques(q, 0 * q, 0 * q)
    assert np.abs(tau / 1.961) == pytest.approx(np.full((1, 3), 0.281), abs=0.005)


def test_a_printer_without_dynamics_data_has_none(tmp_path):
    start = ETITC_TEXT.index("\n[dynamics]\n")
    text = ETITC_TEXT[:start] + ETITC_TEXT[ETITC_TEXT.index("\n[sources]\n"):]
    text = "\n".join(line for line in text.splitlines() if not line.startswith('"dynamics.'))
    p = _load(tmp_path, text)
    assert p.dynamics is None
    with pytest.raises(ValueError, match="no \\[dynamics\\]"):
        p.joint_torques(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)))


@pytest.mark.parametrize("old, new, message", [
    ("forearm_mass = 0.080", "forearm_mas = 0.080", "[dynamics] unknown key 'forearm_mas': did you mean 'forearm_mass'?"),
    ("elbow_mass = 0.06124", "elbow_mass = -0.06", "[dynamics] elbow_mass = -0.06: expected a number >= 0"),
    ("stall_torque = 1.961", "stall_torque = [1.961, 0.0, 1.961]", "[dynamics] stall_torque = 0.0: expected a number > 0"),
    ('speed_torque_curve = "linear"', 'speed_torque_curve = "pullout"', "did you mean 'pull_out'?"),
    ('speed_torque_curve = "linear"', 'speed_torque_curve = "pull_out"', "[dynamics] corner_speed missing"),
    ('speed_torque_curve = "linear"', 'speed_torque_curve = "pull_out"\ncorner_speed = 300.0',
     "[dynamics] corner_speed = [300.0, 300.0, 300.0]: expected a corner speed below no_load_speed"),
    ('speed_torque_curve = "linear"', 'speed_torque_curve = "table"\ncurve_points = [[0.1, 1.0], [1.0, 0.0]]',
     "[dynamics] curve_points = [[0.1, 1.0], [1.0, 0.0]]: expected a list of at least 2"),
])
def test_bad_dynamics_values_name_the_file_key_value_and_bound(tmp_path, old, new, message):
    assert old in ETITC_TEXT
    with pytest.raises(PrinterFileError) as err:
        _load(tmp_path, ETITC_TEXT.replace(old, new))
    assert message in str(err.value) and str(tmp_path / "p.toml") in str(err.value), str(err.value)


def test_a_table_curve_loads(tmp_path):
    text = ETITC_TEXT.replace('speed_torque_curve = "linear"',
                              'speed_torque_curve = "table"\ncurve_points = [[0.0, 1.0], [0.5, 0.8], [1.0, 0.0]]')
    a = _load(tmp_path, text).dynamics.actuators
    v0 = a.no_load_speed[0]
    assert a.driving_limit(np.array([[0.0, 0.25 * v0, 0.75 * v0]]))[0] == pytest.approx(1.961 * np.array([1.0, 0.9, 0.4]))


def test_speed_torque_curves():
    lin = ActuatorCurves("linear", (2.0, 1.0), (10.0, 4.0))
    assert lin.driving_limit(np.array([[0.0, 0.0], [5.0, -2.0], [10.0, 4.0], [-30.0, 9.0]])) == pytest.approx(
        np.array([[2.0, 1.0], [1.0, 0.5], [0.0, 0.0], [0.0, 0.0]]))
    step = ActuatorCurves("pull_out", (2.0,), (10.0,), corner_speed=(2.0,))
    assert step.driving_limit(np.array([[1.0], [2.0], [4.0], [-8.0], [10.0]]))[:, 0] == pytest.approx([2.0, 2.0, 1.0, 0.5, 0.0])
    # driving (torque and speed of one sign) against the curve; braking against stall
    speed, torque = np.array([[5.0, 5.0, 5.0, -5.0]]), np.array([[1.1, 0.9, -1.9, 1.9]])
    two = ActuatorCurves("linear", (2.0,) * 4, (10.0,) * 4)
    assert two.over_line(speed, torque).tolist() == [[True, False, False, False]]
    assert two.available(speed, torque) == pytest.approx(np.array([[1.0, 1.0, 2.0, 2.0]]))


def test_sampled_torques_read_back_the_exact_motion():
    """Joints on a cubic in time, sampled at 1 kHz: the read-back (central differences, second
    differences averaged over 5 ms) gives the model's torques at the exact q, qd, qdd (a cubic's
    second differences are exact and its acceleration linear, which a centred mean keeps)."""
    p = printer("delta_etitc")
    t = np.arange(0.0, 0.2, 1e-3)[:, None]
    b, c, d = np.array([0.5, -0.3, 0.2]), np.array([4.0, -2.0, 3.0]), np.array([-20.0, 30.0, 10.0])
    q = np.radians(40.0) + b * t + c * t**2 + d * t**3
    tau, qd = sampled_torques(p, q, 1000.0)
    exact = p.joint_torques(q, b + 2 * c * t + 3 * d * t**2, 2 * c + 6 * d * t)
    inner = slice(3, -3)
    assert np.abs(tau[inner] - exact[inner]).max() < 1e-5 * np.abs(exact).max()


def test_a_family_without_a_model_refuses_a_dynamics_table():
    data = tomllib.loads((PRINTER_DIR / "linear_kossel.toml").read_text())
    data["kinematics"] = {"family": "cartesian"}
    with pytest.raises(PrinterFileError, match=r"x.toml: \[dynamics\] .*the cartesian family has no dynamics model"):
        printer_from_dict(data, "x.toml")
    del data["dynamics"]
    assert printer_from_dict(data, "x.toml").dynamics is None


def test_torques_read_back_in_blocks_are_those_of_the_whole_array():
    p = printer("delta_etitc")
    t = np.arange(0.0, 0.3, 1e-3)[:, None]
    q = np.radians(40.0) + 0.3 * np.sin(np.array([7.0, 11.0, 13.0]) * t)
    whole = sampled_torques(p, q, 1000.0)
    for block in (1, 7, 64):
        parts = sampled_torques(p, q, 1000.0, block=block)
        assert all(np.array_equal(a, b) for a, b in zip(parts, whole)), block


@settings(max_examples=30, deadline=None)
@given(name=st.sampled_from(sorted(MACHINES)), u=st.lists(st.floats(-1, 1), min_size=3, max_size=3))
def test_the_mass_matrix_is_symmetric_and_positive_definite(name, u):
    """M(q), column j the torques of a unit acceleration of joint j at rest less gravity, is a
    kinetic energy's Hessian (in SI joint units): symmetric, positive definite. A force projected
    through another Jacobian than the one its acceleration came from breaks the symmetry."""
    machine = MACHINES[name]
    q = (machine.centre + machine.amplitude * np.array(u))[None]
    si = np.array([1.0 if k == "revolute" else 1e-3 for k in machine.kin.joint_kinds])
    zero = np.zeros_like(q)
    g = machine.kin.inverse_dynamics(machine.m, q, zero, zero)[0]
    # a unit SI acceleration of joint j: 1 rad/s^2 or 1 m/s^2 (1000 mm/s^2); the torques are SI already
    M = np.column_stack([machine.kin.inverse_dynamics(machine.m, q, zero, np.eye(3)[j][None] / si)[0] - g
                         for j in range(3)])
    assert np.allclose(M, M.T, rtol=1e-9, atol=1e-12 * np.abs(M).max())
    assert np.linalg.eigvalsh(0.5 * (M + M.T)).min() > 0


@pytest.mark.parametrize("name", ["delta_etitc", "linear_kossel", "fivebar_atlas"])
def test_the_compiled_torque_coefficients_are_the_reference(name):
    """A family's compiled torque_coefficients against path_coefficients of its inverse_dynamics
    (numpy; the model the energy checks hold), along a curve over the printer's bed."""
    p = printer(name)
    kin, m = p.kinematics(), p.dynamics.masses
    s = np.linspace(0, 1, 400)[:, None]
    points = np.column_stack([60 * np.cos(7 * s) * s, 50 * np.sin(5 * s), 1 + 100 * s**2])
    q = kin.inverse(points)
    rng = np.random.default_rng(5)
    dq, ddq = rng.normal(size=q.shape), rng.normal(scale=10, size=q.shape)
    ref = path_coefficients(lambda *x: kin.inverse_dynamics(m, *x), q, dq, ddq)
    fast = kin.torque_coefficients(m, points, q, dq, ddq)
    assert type(kin).torque_coefficients is not type(kin).__mro__[1].torque_coefficients  # its own, compiled
    for a, b in zip(fast, ref):
        assert np.all(np.isfinite(b))
        assert np.abs(a - b).max() < 1e-9 * np.abs(b).max()


def test_the_rotary_coefficients_are_nan_where_the_geometry_is():
    """Where the forearms' matrix is singular (q = 0 with the tool at the shoulders' height: every
    forearm level), overflows or is not finite, A, B and C are all NaN, as the full form's 0 x inf
    makes them: the compiled kernel leaves the zero velocity terms of A and C out only where the
    geometry is finite, and such a point must not come out as finite or infinite torques."""
    p = printer("delta_etitc")
    kin, m = p.kinematics(), p.dynamics.masses
    z = -kin._offsets[0, 2]
    points = np.array([[0.0, 0.0, z], [3.0, -2.0, z], [1e200, 0.0, 1e200], [np.nan, 0.0, 10.0], [5.0, 5.0, 10.0]])
    q = np.zeros((5, 3))
    q[3:] = kin.inverse(points[3:])
    q[4, 1] = np.nan
    rng = np.random.default_rng(3)
    dq, ddq = rng.normal(size=q.shape), rng.normal(size=q.shape)
    for coef in kin.torque_coefficients(m, points, q, dq, ddq):
        assert np.all(np.isnan(coef))
    finite = kin.inverse(np.array([[5.0, 5.0, 10.0]]))
    assert np.all(np.isfinite(np.concatenate(kin.torque_coefficients(m, points[4:], finite, dq[4:], ddq[4:]))))


@pytest.mark.parametrize("name", ["delta_etitc", "delta_ucb", "fivebar_atlas", "linear_kossel"])
def test_every_printer_gives_its_path_coefficients(name):
    """Printer.torque_path_coefficients (the family's torque_coefficients: compiled for the rotary
    delta, the numpy default elsewhere) is the model's torque along a path at any sd, sdd."""
    p = printer(name)
    kin = p.kinematics()
    s = np.linspace(0, 1, 50)[:, None]
    points = np.column_stack([20 * np.cos(5 * s), 15 * np.sin(3 * s), 5 + 20 * s])
    h = 1e-4
    q, qp, qm = kin.inverse(points), kin.inverse(points + h), kin.inverse(points - h)  # a path along (1, 1, 1)
    dq, ddq = (qp - qm) / (2 * h), (qp - 2 * q + qm) / h**2
    a, b, c = p.torque_path_coefficients(q, dq, ddq, points)
    sd, sdd = 37.0, -450.0
    direct = p.joint_torques(q, dq * sd, dq * sdd + ddq * sd**2)
    assert np.all(np.isfinite(direct))
    assert np.abs(a * sdd + b * sd**2 + c - direct).max() < 1e-9 * np.abs(direct).max()
    assert np.allclose(p.torque_path_coefficients(q, dq, ddq)[2], c, rtol=1e-9, atol=1e-12)


def test_a_stepper_defaults_to_a_pull_out_curve(tmp_path):
    text = (PRINTER_DIR / "linear_kossel.toml").read_text().replace('speed_torque_curve = "pull_out"\n', "")
    assert _load(tmp_path, text).dynamics.actuators.curve == "pull_out"
    with pytest.raises(PrinterFileError, match=r"\[dynamics\] corner_speed missing"):
        _load(tmp_path, text.replace("corner_speed = 133.0\n", ""))
