"""The plant: step semantics, equality with the numpy reference, and physics that a wrong
model would get wrong (energy, terminal speeds, restoring, equilibria, pitch through 90 deg)."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from tiltrov_ros.core.actuators import ThrusterBank, TiltServos
from tiltrov_ros.core.disturbances import PAPER_COM_ERROR, Disturbances
from tiltrov_ros.core.dynamics import f, kinetic_energy, potential_energy
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.kinematics import (
    Rquat,
    Rzyx,
    euler_from_quat,
    quat_from_euler,
    quat_normalize,
    ssa,
)
from tiltrov_ros.core.params import RobotParams, load_robot_params
from tiltrov_ros.core.plant import (
    Plant,
    euler_step,
    normalize_state_quaternion,
    rk4_step,
)
from tiltrov_ros.core.thrust_map import thrust_wrench
from tiltrov_ros.core.timebase import seconds


@pytest.fixture(scope='module')
def shipped() -> RobotParams:
    return load_robot_params()


@pytest.fixture(scope='module')
def neutral(shipped: RobotParams) -> RobotParams:
    """W = B and r_g = r_b: no restoring forces at all."""
    return dataclasses.replace(shipped, buoyancy=shipped.weight, center_of_gravity=(0.0, 0.0, 0.0))


def _energy(p: RobotParams, plant: Plant) -> float:
    return kinetic_energy(p, plant.nu) + potential_energy(p, plant.position, plant.rotation)


# -- equality with the reference and step semantics ---------------------------------

@pytest.mark.parametrize('integrator', ['rk4', 'euler'])
def test_plant_equals_numpy_reference_step_by_step(shipped: RobotParams, integrator: str) -> None:
    """The documented step, written out with the reference f, thrust_map and the
    actuator models; the plant's float fast path must agree to 1e-10 over 300 steps."""
    rng = np.random.default_rng(0)
    dist = Disturbances(com_error=PAPER_COM_ERROR, current=(0.2, -0.1, 0.05),
                        external_wrench=lambda t: [3 * math.sin(t), 0, 1.0, 0, 0.5 * t, 0])
    x0 = np.concatenate([[1.0, -2.0, 3.0], quat_normalize(rng.normal(size=4)),
                         rng.normal(scale=0.3, size=6)])
    plant = Plant(shipped, dist, integrator=integrator,  # type: ignore[arg-type]
                  position=x0[:3], quaternion=x0[3:7], nu=x0[7:], tilts=(0.2, -0.4),
                  thrusts=(5.0, -3.0, 2.0, 1.0))
    true = dist.true_params(shipped)
    thr = ThrusterBank.from_params(true, (5.0, -3.0, 2.0, 1.0))
    srv = TiltServos.from_params(true, (0.2, -0.4))
    step = rk4_step if integrator == 'rk4' else euler_step
    x, h = x0.copy(), 0.01
    for i in range(300):
        if i % 5 == 0:
            cmd_f, cmd_t = rng.uniform(-50, 50, 4), rng.uniform(-2, 2, 2)
            plant.command(cmd_f, cmd_t)
            thr.command(cmd_f)
            srv.command(cmd_t)
        t = seconds(i * 10_000_000)
        tau = (thrust_wrench(thr.thrusts, *srv.angles, true.length, true.width)
               + np.asarray(dist.external_wrench(t)))           # type: ignore[operator]
        x = normalize_state_quaternion(
            step(lambda _t, xx, tau=tau: f(_t, xx, tau, true, dist.current), t, x, h))
        thr.step(h)
        srv.step(h)
        plant.step()
        np.testing.assert_allclose(plant.state, x, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(plant.thrusts, thr.thrusts, rtol=1e-13, atol=1e-13)
        np.testing.assert_allclose(plant.tilts, srv.angles, rtol=1e-13, atol=1e-13)
    assert plant.time_ns == 300 * 10_000_000


def test_fast_thrust_wrench_is_eq4(shipped: RobotParams) -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        f0 = rng.uniform(-40, 40, 4)
        tilts = rng.uniform(-1.5, 1.5, 2)
        plant = Plant(shipped, thrusts=f0, tilts=tilts)
        np.testing.assert_allclose(plant.thrust_wrench(),
                                   thrust_wrench(f0, *tilts, shipped.length, shipped.width),
                                   rtol=1e-12, atol=1e-12)


def test_a_command_first_acts_one_step_later(neutral: RobotParams) -> None:
    ideal = dataclasses.replace(neutral, thruster_time_constant=0.0)
    plant = Plant(ideal)
    plant.command([10.0, 10.0, 10.0, 10.0], [0.0, 0.0])
    np.testing.assert_array_equal(plant.applied_wrench(), np.zeros(6))
    plant.step()                     # [t0, t1): actuators still at a_0 = 0
    np.testing.assert_array_equal(plant.nu, np.zeros(6))
    np.testing.assert_array_equal(plant.thrusts, [10.0] * 4)
    plant.step()                     # [t1, t2): the new thrusts push
    assert plant.nu[0] > 0.0
    np.testing.assert_allclose(plant.applied_wrench()[0], 40.0 / math.sqrt(2.0), rtol=1e-14)


def test_external_wrench_is_sampled_at_each_step_start(neutral: RobotParams) -> None:
    calls: list[float] = []

    def wrench(t: float) -> list[float]:
        calls.append(t)
        return [0.0] * 6

    plant = Plant(neutral, Disturbances(external_wrench=wrench), step_ns=20_000_000)
    plant.step(5)
    assert calls == [seconds(i * 20_000_000) for i in range(5)]
    assert plant.time_ns == 100_000_000
    assert plant.time == 0.1


def test_non_finite_commands_never_reach_the_state(shipped: RobotParams) -> None:
    plant = Plant(shipped)
    assert plant.command([10.0, 0.0, 0.0, 0.0], [0.3, 0.3])
    assert not plant.command([math.nan, 0.0, 0.0, 0.0], [math.inf, 0.0])
    plant.step(100)
    assert np.all(np.isfinite(plant.state))
    assert plant.thrusters.command_held == (10.0, 0.0, 0.0, 0.0)
    assert plant.servos.command_held == (0.3, 0.3)
    assert plant.thrusters.rejected == 1 and plant.servos.rejected == 1


def test_same_seed_same_run(shipped: RobotParams) -> None:
    dist = Disturbances(current=(0.1, 0.0, 0.0), current_std=(0.05, 0.05, 0.02),
                        current_time_constant=(5.0, 5.0, 5.0), seed=42)

    def run() -> np.ndarray:
        plant = Plant(shipped, dist)
        plant.command([5.0, 5.0, 5.0, 5.0], [0.2, 0.2])
        plant.step(300)
        return plant.state

    a, b = run(), run()
    np.testing.assert_array_equal(a, b)
    other = Plant(shipped, dataclasses.replace(dist, seed=43))
    other.command([5.0, 5.0, 5.0, 5.0], [0.2, 0.2])
    other.step(300)
    assert not np.array_equal(a, other.state)


def test_initial_state_is_validated(shipped: RobotParams) -> None:
    with pytest.raises(ParameterError, match='initial quaternion'):
        Plant(shipped, quaternion=(0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ParameterError, match='initial nu'):
        Plant(shipped, nu=(0.0, math.nan, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(ParameterError, match='initial tilts'):
        Plant(shipped, tilts=(2.0, 0.0))
    with pytest.raises(ParameterError, match='step_ns'):
        Plant(shipped, step_ns=0)
    with pytest.raises(ParameterError, match='integrator'):
        Plant(shipped, integrator='rk45')  # type: ignore[arg-type]
    plant = Plant(shipped, quaternion=(2.0, 0.0, 0.0, 0.0))
    np.testing.assert_array_equal(plant.quaternion, [1.0, 0.0, 0.0, 0.0])
    json.dumps(plant.describe())


# -- energy --------------------------------------------------------------------

@pytest.mark.parametrize('which', ['neutral', 'shipped'])
def test_energy_never_grows_in_free_decay(which: str, request: pytest.FixtureRequest) -> None:
    """No input, no current: T + V is non-increasing (W = B, r_g = r_b: V constant;
    shipped robot: CG below CB and 5 N of net buoyancy)."""
    p: RobotParams = request.getfixturevalue(which)
    rng = np.random.default_rng(2)
    for _ in range(3):
        plant = Plant(p, nu=rng.normal(scale=[0.5, 0.5, 0.5, 1.5, 1.5, 1.5]),
                      quaternion=quat_normalize(rng.normal(size=4)))
        energy = [_energy(p, plant)]
        for _ in range(1500):
            plant.step()
            energy.append(_energy(p, plant))
        e = np.array(energy)
        assert np.all(np.diff(e) <= 1e-12 * max(1.0, abs(e[0])))
        assert e[-1] < e[0] - 1.0       # and damping does take energy out


# -- terminal speeds -------------------------------------------------------------

def _run_to_steady(plant: Plant, seconds_: float) -> None:
    plant.step(round(seconds_ / plant.step_size))


@pytest.mark.parametrize('X', [20.0, 50.0, 100.0])
def test_constant_surge_force_gives_sqrt_X_over_d_u(neutral: RobotParams, X: float) -> None:
    # All four thrusters at tilt 0 with equal thrust f: X = 4 f / sqrt(2), nothing else.
    f_each = X * math.sqrt(2.0) / 4.0
    plant = Plant(neutral, thrusts=[f_each] * 4)
    plant.command([f_each] * 4, [0.0, 0.0])
    np.testing.assert_allclose(plant.applied_wrench(), [X, 0, 0, 0, 0, 0], atol=1e-12)
    _run_to_steady(plant, 40.0)
    expected = math.sqrt(X / 34.55)
    assert plant.nu[0] == pytest.approx(expected, rel=0.005)
    np.testing.assert_allclose(plant.nu[1:], 0.0, atol=1e-12)
    # And it is the steady state, not a passing value.
    u_before = plant.nu[0]
    _run_to_steady(plant, 5.0)
    assert abs(plant.nu[0] - u_before) < 1e-3 * expected


@pytest.mark.parametrize('Z', [30.0, -60.0])
def test_constant_heave_force_gives_sqrt_Z_over_d_w(neutral: RobotParams, Z: float) -> None:
    # Tilts at +90 deg: Z = -(f1 + f2 + f3 + f4).
    f_each = -Z / 4.0
    plant = Plant(neutral, tilts=(math.pi / 2, math.pi / 2), thrusts=[f_each] * 4)
    np.testing.assert_allclose(plant.applied_wrench(), [0, 0, Z, 0, 0, 0], atol=1e-12)
    _run_to_steady(plant, 40.0)
    assert plant.nu[2] == pytest.approx(math.copysign(math.sqrt(abs(Z) / 146.5), Z), rel=0.005)
    np.testing.assert_allclose(np.delete(plant.nu, 2), 0.0, atol=1e-12)


def test_heave_speed_of_the_shipped_robot_includes_net_buoyancy(shipped: RobotParams) -> None:
    """W - B = -5 N: a downward Z must first cancel 5 N of net buoyancy."""
    Z = 40.0
    plant = Plant(shipped, Disturbances(external_wrench=(0.0, 0.0, Z, 0.0, 0.0, 0.0)))
    _run_to_steady(plant, 40.0)
    net = Z + (shipped.weight - shipped.buoyancy)
    assert plant.nu[2] == pytest.approx(math.sqrt(net / 146.5), rel=0.005)
    np.testing.assert_allclose(plant.euler, 0.0, atol=1e-12)


# -- restoring forces -------------------------------------------------------------

def test_released_tilted_with_cg_below_cb_it_returns_to_level(shipped: RobotParams) -> None:
    """Quadratic damping only (the paper's model): the oscillation decays slowly
    about level; with some linear damping it settles to level."""
    q0 = quat_from_euler(math.radians(20.0), math.radians(-30.0), 0.5)
    plant = Plant(shipped, quaternion=q0)
    rp = []
    for _ in range(12000):
        plant.step()
        rp.append(plant.euler[:2])
    rp_arr = np.array(rp)
    first, last = np.abs(rp_arr[:1000]).max(axis=0), np.abs(rp_arr[-1000:]).max(axis=0)
    assert np.all(last < 0.3 * first)
    # The oscillation is about level (CG right below CB), not about a tilt.
    np.testing.assert_allclose(rp_arr[-1000:].mean(axis=0), 0.0, atol=0.01)

    damped = dataclasses.replace(shipped, linear_damping=(20.0, 20.0, 20.0, 3.0, 5.0, 5.0))
    plant = Plant(damped, quaternion=q0)
    _run_to_steady(plant, 60.0)
    np.testing.assert_allclose(plant.euler[:2], 0.0, atol=1e-4)


@pytest.mark.parametrize(('axis', 'moment'), [(4, 5.0), (4, -9.0), (3, 4.0)])
def test_equilibrium_under_a_constant_moment_matches_z_g_W_sin(
        neutral: RobotParams, axis: int, moment: float) -> None:
    """r_b = 0, r_g = (0, 0, z_g), W = B: a pitch moment M is held at
    z_g W sin(theta) = M (roll: z_g W sin(phi) = K)."""
    z_g = 0.02
    p = dataclasses.replace(neutral, center_of_gravity=(0.0, 0.0, z_g),
                            linear_damping=(20.0, 20.0, 20.0, 3.0, 5.0, 5.0))
    wrench = [0.0] * 6
    wrench[axis] = moment
    plant = Plant(p, Disturbances(external_wrench=tuple(wrench)))
    _run_to_steady(plant, 60.0)
    angle = plant.euler[axis - 3]
    assert angle == pytest.approx(math.asin(moment / (z_g * p.weight)), abs=1e-6)
    np.testing.assert_allclose(plant.nu, 0.0, atol=1e-6)


def test_com_error_tilts_the_plant_but_not_the_nominal(neutral: RobotParams) -> None:
    """With the paper's CoM error the true CG is 1 cm ahead of and 2.5 cm below the
    CB: at rest the robot pitches to tan(theta) = -x_g / z_g."""
    p = dataclasses.replace(neutral, center_of_gravity=(0.0, 0.0, 0.02),
                            linear_damping=(20.0, 20.0, 20.0, 3.0, 5.0, 5.0))
    plant = Plant(p, Disturbances(com_error=PAPER_COM_ERROR))
    assert plant.nominal_params.center_of_gravity == (0.0, 0.0, 0.02)
    np.testing.assert_allclose(plant.params.center_of_gravity, [0.01, 0.0, 0.025])
    _run_to_steady(plant, 60.0)
    assert plant.euler[1] == pytest.approx(-math.atan2(0.01, 0.025), abs=1e-6)
    assert plant.euler[0] == pytest.approx(0.0, abs=1e-9)


# -- attitude through pitch +-90 deg ------------------------------------------------

@pytest.mark.parametrize('rate', [1.0, -1.3])
def test_constant_pitch_rate_goes_through_90_deg(neutral: RobotParams, rate: float) -> None:
    """A torque-free spin about the principal y axis (no damping, no restoring)
    keeps q constant; the attitude must stay R0 Ry(q t) through the singularity."""
    p = dataclasses.replace(neutral, quadratic_damping=(0.0,) * 6)
    yaw = 0.7
    plant = Plant(p, quaternion=quat_from_euler(0.0, 0.0, yaw), nu=(0, 0, 0, 0, rate, 0))
    R0 = Rzyx(0.0, 0.0, yaw)
    crossed = False
    for k in range(1, 301):
        plant.step()
        t = k * 0.01
        angle = rate * t
        R_expected = R0 @ Rzyx(0.0, angle, 0.0)
        R = plant.rotation
        np.testing.assert_allclose(R, R_expected, atol=1e-9)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
        assert np.linalg.norm(plant.quaternion) == pytest.approx(1.0, abs=1e-15)
        assert plant.nu[4] == pytest.approx(rate, rel=1e-12)
        phi, theta, psi = plant.euler
        if abs(angle) < math.pi / 2 - 1e-3:
            np.testing.assert_allclose([phi, theta, psi], [0.0, angle, yaw], atol=1e-8)
        elif abs(angle) > math.pi / 2 + 1e-3:
            crossed = True
            # Past the vertical: the same attitude reads roll pi, pitch pi - angle, yaw + pi.
            np.testing.assert_allclose(
                [abs(phi), theta, ssa(psi - yaw - math.pi)],
                [math.pi, math.copysign(math.pi, angle) - angle, 0.0], atol=1e-8)
    assert crossed


def test_quaternion_stays_unit_in_a_tumble(shipped: RobotParams) -> None:
    plant = Plant(shipped, nu=(0.3, -0.2, 0.1, 3.0, -2.5, 2.0))
    for _ in range(500):
        plant.step()
        assert abs(np.linalg.norm(plant.quaternion) - 1.0) < 1e-15
        R = Rquat(plant.quaternion)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(plant.euler, euler_from_quat(plant.quaternion))


# -- current --------------------------------------------------------------------

@pytest.mark.parametrize('current', [(0.3 * math.cos(1.0), 0.3 * math.sin(1.0), 0.0),
                                     (0.0, 0.0, 0.05)])
def test_a_free_robot_drifts_with_the_current(neutral: RobotParams,
                                              current: tuple[float, float, float]) -> None:
    """Heading 1 rad: the current is rotated into the body frame (along x, or z).

    From rest, along one body axis: the relative flow is along that axis during
    the spin-up, so no Munk moment arises and the attitude stays. (An oblique
    relative flow does turn a body: that moment is physical.)"""
    p = dataclasses.replace(neutral, linear_damping=(50.0, 50.0, 50.0, 3.0, 5.0, 5.0))
    plant = Plant(p, Disturbances(current=current),
                  quaternion=quat_from_euler(0.0, 0.0, 1.0))
    _run_to_steady(plant, 40.0)
    np.testing.assert_allclose(plant.rotation @ plant.nu[:3], current, atol=1e-6)
    # The current pushes through the damping only: no moment, the attitude stays.
    np.testing.assert_allclose(plant.euler, [0.0, 0.0, 1.0], atol=1e-9)


@pytest.mark.parametrize('current', [(0.3, 0.0, 0.0), (0.2, -0.15, 0.05), (0.0, 0.25, -0.1)])
def test_a_robot_drifting_with_the_water_feels_nothing(neutral: RobotParams,
                                                      current: tuple[float, float, float]
                                                      ) -> None:
    """nu_r = 0: no drag and no Munk moment, whatever the direction (C(nu_r), not C(nu))."""
    attitude = quat_from_euler(0.2, -0.3, 1.0)
    nu_c = Rquat(attitude).T @ np.array(current)
    plant = Plant(neutral, Disturbances(current=current), quaternion=attitude,
                  nu=(*nu_c, 0.0, 0.0, 0.0))
    plant.step(2000)                                          # 20 s
    np.testing.assert_allclose(plant.nu, [*nu_c, 0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(plant.quaternion, attitude, atol=1e-12)
    np.testing.assert_allclose(plant.position, 20.0 * np.array(current), atol=1e-9)
