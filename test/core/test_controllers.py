"""The wrench controllers on hand-computed cases, and their configuration.

* pd, eq. (16): tau = J(eta)^T (Kp e + Kd e_dot), e = eta_d - eta (angles
  wrapped), e_dot = eta_d_dot - J(eta) nu. J^T is checked against rotation
  matrices written out by hand and against the Euler-angle rates of a
  numerically rotated quaternion (an independent route to J).
* pid: g_hat(eta) of the nominal robot + the PD + a clamped integral.
* switching: mode choice, hysteresis, dwell, servo travel, masking.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from tiltrov_ros.core.controllers import (
    ControllerConfig,
    Gains,
    PDController,
    PIDController,
    Reference,
    SwitchingController,
    SwitchingSettings,
    load_controller_config,
    make_controller,
    tracking_error,
)
from tiltrov_ros.core.dynamics import f as rigid_body_rhs
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.kinematics import Rquat, euler_from_quat, quat_from_euler, quat_multiply
from tiltrov_ros.core.params import load_robot_params

DEG = math.pi / 180.0
KP = (10.0, 20.0, 30.0, 4.0, 5.0, 6.0)
KD = (1.0, 2.0, 3.0, 0.4, 0.5, 0.6)
KI = (0.5, 1.0, 1.5, 0.2, 0.25, 0.3)
LIMIT = (2.0, 2.0, 2.0, 1.0, 1.0, 1.0)
GAINS = Gains(KP, KD, KI, LIMIT)


def _q(roll_deg: float = 0.0, pitch_deg: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    return quat_from_euler(roll_deg * DEG, pitch_deg * DEG, yaw_deg * DEG)


def _ref(position=(0.0, 0.0, 0.0), euler_deg=(0.0, 0.0, 0.0), velocity=(0.0,) * 6) -> Reference:
    return Reference(np.array(position, dtype=float), _q(*euler_deg),
                     np.array(velocity, dtype=float))


def _pd(position, quaternion, nu, reference) -> np.ndarray:
    out = PDController(GAINS).update(0.0, np.asarray(position, dtype=float), quaternion,
                                     np.asarray(nu, dtype=float), reference)
    assert out.tilt_request is None and out.mode == 'pd'
    return out.wrench


# --------------------------------------------------------------------------- PD (16)


def test_pd_at_zero_attitude_is_kp_e_minus_kd_nu() -> None:
    # J(0) = I: tau = Kp (eta_d - eta) - Kd nu, term by term.
    nu = np.array([0.1, -0.2, 0.3, 0.01, -0.02, 0.03])
    tau = _pd((0.5, 0.0, -0.25), _q(), nu, _ref((1.5, 2.0, 0.75), (3.0, -4.0, 5.0)))
    expected = [10.0 * 1.0 - 1.0 * 0.1,
                20.0 * 2.0 + 2.0 * 0.2,
                30.0 * 1.0 - 3.0 * 0.3,
                4.0 * 3.0 * DEG - 0.4 * 0.01,
                5.0 * -4.0 * DEG + 0.5 * 0.02,
                6.0 * 5.0 * DEG - 0.6 * 0.03]
    # The setpoint quaternion goes through Euler angles and back (rounding only).
    np.testing.assert_allclose(tau, expected, rtol=1e-12, atol=1e-12)


def test_pd_j_transpose_at_pitch_minus_30_yaw_90_by_hand() -> None:
    # Robot at roll 0, pitch -30 deg (nose down), yaw 90 deg (facing east).
    # R = Rz(90) Ry(-30): the body x axis points east and 0.5 down.
    # A north force F is the body's -y (to port when facing east): R^T (F, 0, 0)
    # = (0, -F, 0). A down force F is R^T (0, 0, F) = F (-sin(-30), 0, cos(30)).
    # Euler-rate map with roll 0: roll_dot = p + tan(theta) r, psi_dot = r / cos(theta),
    # so T^T maps an "Euler moment" (m_phi, m_theta, m_psi) to
    # (m_phi, m_theta, tan(theta) m_phi + m_psi / cos(theta)).
    theta = -30 * DEG
    q = _q(0.0, -30.0, 90.0)
    ref = Reference(np.array([1.0, 0.0, 0.0]), q, np.zeros(6))     # only e_x = 1 m
    np.testing.assert_allclose(_pd((0, 0, 0), q, np.zeros(6), ref),
                               [0.0, -10.0, 0.0, 0.0, 0.0, 0.0], atol=1e-12)
    ref = Reference(np.array([0.0, 0.0, 1.0]), q, np.zeros(6))     # only e_z = 1 m
    np.testing.assert_allclose(_pd((0, 0, 0), q, np.zeros(6), ref),
                               [30.0 * 0.5, 0.0, 30.0 * math.sqrt(3) / 2, 0.0, 0.0, 0.0],
                               atol=1e-12)
    # A roll error of 2 deg at that attitude: K = kp e, N = tan(theta) kp e.
    ref = _ref((0, 0, 0), (2.0, -30.0, 90.0))
    e = 2.0 * DEG
    np.testing.assert_allclose(_pd((0, 0, 0), q, np.zeros(6), ref),
                               [0, 0, 0, 4.0 * e, 0.0, math.tan(theta) * 4.0 * e],
                               atol=1e-12)
    # A yaw error of 2 deg: only N = kp e / cos(theta).
    ref = _ref((0, 0, 0), (0.0, -30.0, 92.0))
    np.testing.assert_allclose(_pd((0, 0, 0), q, np.zeros(6), ref),
                               [0, 0, 0, 0, 0, 6.0 * e / math.cos(theta)], atol=1e-12)


def _numerical_J(position: np.ndarray, q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d(eta)/dt for each unit body velocity, by moving the pose a little (no J(eta) used)."""
    eta0 = np.concatenate([position, euler_from_quat(q)])
    R = Rquat(q)
    out = np.zeros((6, 6))
    for j in range(6):
        nu = np.zeros(6)
        nu[j] = 1.0
        p1 = position + h * R @ nu[:3]
        w = nu[3:] * h                                     # body rotation vector
        angle = float(np.linalg.norm(w))
        dq = (np.array([1.0, 0.0, 0.0, 0.0]) if angle == 0.0 else
              np.concatenate([[math.cos(angle / 2)], math.sin(angle / 2) * w / angle]))
        q1 = quat_multiply(q, dq)                          # rotation about body axes
        eta1 = np.concatenate([p1, euler_from_quat(q1)])
        out[:, j] = (eta1 - eta0) / h
    return out


def test_pd_j_transpose_matches_power_equivalence_with_numerical_kinematics() -> None:
    # tau is the body wrench that does the same work as the earth-frame
    # generalized force F = Kp e: tau . nu = F . eta_dot for every nu, i.e.
    # tau = J_num^T F with J_num from finite differences of the pose.
    position = np.array([0.3, -0.2, 0.1])
    q = _q(20.0, -30.0, 90.0)
    ref = _ref((1.0, -0.5, 0.4), (25.0, -20.0, 80.0))
    e = np.array([0.7, -0.3, 0.3, 5.0 * DEG, 10.0 * DEG, -10.0 * DEG])
    force = np.array(KP) * e
    expected = _numerical_J(position, q).T @ force
    np.testing.assert_allclose(_pd(position, q, np.zeros(6), ref), expected, rtol=1e-5,
                               atol=1e-5)


@pytest.mark.parametrize(('yaw_d', 'yaw', 'expected_deg'),
                         [(-179.0, 179.0, 2.0), (179.0, -179.0, -2.0), (170.0, -10.0, 180.0)])
def test_angle_errors_are_wrapped(yaw_d: float, yaw: float, expected_deg: float) -> None:
    err = tracking_error((0, 0, 0), _q(0, 0, yaw), np.zeros(6), _ref(euler_deg=(0, 0, yaw_d)))
    assert err.e[5] == pytest.approx(expected_deg * DEG, abs=1e-12)
    # Level attitude: N = kp_yaw e_psi, no -358 deg.
    tau = _pd((0, 0, 0), _q(0, 0, yaw), np.zeros(6), _ref(euler_deg=(0, 0, yaw_d)))
    assert tau[5] == pytest.approx(6.0 * expected_deg * DEG, abs=1e-12)


def test_pd_feed_forward_velocity() -> None:
    v = np.array([0.1, 0.0, -0.05, 0.0, 0.02, 0.0])
    # Robot at rest at the setpoint: only the reference rate acts, tau = Kd v.
    tau = _pd((0, 0, 0), _q(), np.zeros(6), _ref(velocity=v))
    np.testing.assert_allclose(tau, np.array(KD) * v, atol=1e-15)
    # Robot moving exactly at the reference rate, at an attitude: e_dot = 0, so
    # the velocity terms cancel and only J^T Kp e is left.
    q = _q(10.0, -30.0, 45.0)
    ref = _ref((0.2, 0.0, 0.0), (10.0, -30.0, 45.0), v)
    err = tracking_error((0, 0, 0), q, np.zeros(6), ref)
    nu = np.linalg.solve(err.J, v)
    tau = _pd((0, 0, 0), q, nu, ref)
    np.testing.assert_allclose(tau, err.J.T @ (np.array(KP) * err.e), atol=1e-12)


def test_pd_at_pitch_90_gives_a_finite_wrench() -> None:
    tau = _pd((0, 0, 0), _q(0, 90, 0), np.zeros(6), _ref(euler_deg=(0, 80, 0)))
    assert np.all(np.isfinite(tau))
    assert tau[4] == pytest.approx(5.0 * -10.0 * DEG, rel=1e-6)


# --------------------------------------------------------------------------- PID


@pytest.fixture(scope='module')
def robot():
    return load_robot_params()


def test_pid_g_hat_cancels_the_nominal_restoring_forces_at_rest(robot) -> None:
    pid = PIDController(GAINS, robot)
    q = _q(0.0, -30.0, 0.0)
    out = pid.update(0.0, np.zeros(3), q, np.zeros(6), _ref(euler_deg=(0.0, -30.0, 0.0)))
    assert out.mode == 'pid' and out.tilt_request is None
    # By hand (Fossen's g(eta), roll 0, pitch -30 deg, r_g = (0, 0, 0.02), r_b = 0):
    # X = (W - B) sin(theta), Z = -(W - B) cos(theta), M = z_g W sin(theta).
    W, B, zg = robot.weight, robot.buoyancy, robot.center_of_gravity[2]
    s, c = math.sin(-30 * DEG), math.cos(-30 * DEG)
    np.testing.assert_allclose(out.wrench, [(W - B) * s, 0.0, -(W - B) * c, 0.0, zg * W * s,
                                            0.0], atol=1e-9)
    # So the nominal robot at rest under this wrench does not accelerate.
    state = np.concatenate([np.zeros(3), q, np.zeros(6)])
    np.testing.assert_allclose(rigid_body_rhs(0.0, state, out.wrench, robot)[7:], 0.0,
                               atol=1e-12)


def test_pid_integral_accumulates_with_the_update_interval_and_is_clamped(robot) -> None:
    pid = PIDController(GAINS, robot)
    ref = _ref((0.1, 0.0, 0.0))                                   # e_x = 0.1 m, level
    g_hat = pid.update(0.0, np.zeros(3), _q(), np.zeros(6), ref).wrench - 10.0 * 0.1 * np.eye(6)[0]
    assert pid.integral[0] == 0.0                      # first update: nothing to integrate
    out = pid.update(0.05, np.zeros(3), _q(), np.zeros(6), ref)
    assert pid.integral[0] == pytest.approx(0.1 * 0.05)
    assert out.wrench[0] - g_hat[0] == pytest.approx(10.0 * 0.1 + 0.5 * 0.1 * 0.05)
    for k in range(2, 11):
        pid.update(0.05 * k, np.zeros(3), _q(), np.zeros(6), ref)
    assert pid.integral[0] == pytest.approx(0.1 * 0.5)
    # A gap of 5 s counts as 1 s (integration step capped).
    pid.update(5.5, np.zeros(3), _q(), np.zeros(6), ref)
    assert pid.integral[0] == pytest.approx(0.1 * 1.5)
    # Long enough: |ki * integral| stops at integral_limit (2 N: integral 4 m s).
    for k in range(1, 400):
        out = pid.update(5.5 + k, np.zeros(3), _q(), np.zeros(6), ref)
    assert pid.integral[0] == pytest.approx(LIMIT[0] / KI[0])
    assert out.wrench[0] - g_hat[0] == pytest.approx(10.0 * 0.1 + LIMIT[0])
    # The clamp is symmetric and unwinds at once when the error changes sign.
    out = pid.update(500.0, np.zeros(3), _q(), np.zeros(6), _ref((-0.1, 0.0, 0.0)))
    assert pid.integral[0] == pytest.approx(LIMIT[0] / KI[0] - 0.1 * 1.0)
    pid.reset()
    assert np.all(pid.integral == 0.0)


def test_pid_without_integral_gain_keeps_no_integral(robot) -> None:
    pid = PIDController(Gains(KP, KD), robot)
    for k in range(5):
        pid.update(0.05 * k, np.zeros(3), _q(), np.zeros(6), _ref((1.0, 0.0, 0.0)))
    assert np.all(pid.integral == 0.0)


# --------------------------------------------------------------------------- switching

SETTINGS = SwitchingSettings(hysteresis=0.5, dwell_time=1.0, position_scale=0.1,
                             angle_scale=0.1, deadband=0.2, settle_time=0.1)


def _switching(robot) -> SwitchingController:
    return SwitchingController(GAINS, SETTINGS, robot)


def _update(ctrl: SwitchingController, t: float, position=(0.0, 0.0, 0.0), euler_deg=(0, 0, 0)):
    return ctrl.update(t, np.array(position, dtype=float), _q(*euler_deg), np.zeros(6), _ref())


def test_switching_starts_in_the_mode_of_the_larger_error(robot) -> None:
    ctrl = _switching(robot)
    out = _update(ctrl, 0.0, position=(0.0, 0.0, 0.05))              # depth error only
    assert ctrl.mode == 'vertical' and out.tilt_request == (math.pi / 2, math.pi / 2)
    ctrl = _switching(robot)
    out = _update(ctrl, 0.0, position=(0.05, 0.0, 0.0))              # surge error only
    assert ctrl.mode == 'horizontal' and out.tilt_request == (0.0, 0.0)


def test_switching_zero_wrench_while_the_servos_travel(robot) -> None:
    ctrl = _switching(robot)
    out = _update(ctrl, 0.0, position=(0.0, 0.0, 0.05))
    # From (0, 0) to (90, 90) deg at the robot's rate, plus the settle time.
    travel = (math.pi / 2) / robot.tilt_rate_limit + SETTINGS.settle_time
    assert out.mode == 'transition'
    np.testing.assert_array_equal(out.wrench, np.zeros(6))
    out = _update(ctrl, travel - 1e-3, position=(0.0, 0.0, 0.05))
    assert out.mode == 'transition' and np.all(out.wrench == 0.0)
    assert out.tilt_request == (math.pi / 2, math.pi / 2)
    out = _update(ctrl, travel + 1e-3, position=(0.0, 0.0, 0.05))
    assert out.mode == 'vertical' and out.wrench[2] != 0.0


def test_switching_masks_the_wrench_to_the_modes_dofs(robot) -> None:
    # An error in every DOF; each mode passes only its own three components of
    # the PD wrench (vertical: Z K M; horizontal: X Y N).
    position, euler = (0.02, -0.03, 0.2), (3.0, -4.0, 5.0)
    ref = _ref()
    pd = PDController(GAINS).update(0.0, np.array(position), _q(*euler), np.zeros(6), ref).wrench
    ctrl = _switching(robot)
    _update(ctrl, 0.0, position, euler)                     # large depth error: vertical
    out = _update(ctrl, 5.0, position, euler)
    assert out.mode == 'vertical'
    np.testing.assert_allclose(out.wrench, pd * [0, 0, 1, 1, 1, 0], atol=1e-12)
    ctrl = _switching(robot)
    _update(ctrl, 0.0, (0.5, -0.03, 0.02), euler)           # large surge error: horizontal
    pd = PDController(GAINS).update(0.0, np.array((0.5, -0.03, 0.02)), _q(*euler),
                                    np.zeros(6), ref).wrench
    out = _update(ctrl, 5.0, (0.5, -0.03, 0.02), euler)
    assert out.mode == 'horizontal' and out.tilt_request == (0.0, 0.0)
    np.testing.assert_allclose(out.wrench, pd * [1, 1, 0, 0, 0, 1], atol=1e-12)


def test_switching_hysteresis_and_deadband(robot) -> None:
    # Normalised errors with scale 0.1: vertical v = |e_z| / 0.1, horizontal h = |e_x| / 0.1.
    ctrl = _switching(robot)
    _update(ctrl, 0.0, position=(0.0, 0.0, 0.1))          # v = 1: vertical
    assert ctrl.mode == 'vertical' and ctrl.switches == 1
    # h = 1.4 v < (1 + 0.5) v: stays vertical, however long.
    for t in (5.0, 10.0, 20.0):
        _update(ctrl, t, position=(0.14, 0.0, 0.1))
        assert ctrl.mode == 'vertical'
    # h = 1.6 v: switches.
    _update(ctrl, 21.0, position=(0.16, 0.0, 0.1))
    assert ctrl.mode == 'horizontal' and ctrl.switches == 2
    # Deadband: the other group's error below 0.2 never triggers a switch, even
    # when the current group's error is zero.
    ctrl = _switching(robot)
    _update(ctrl, 0.0, position=(0.1, 0.0, 0.0))          # horizontal
    _update(ctrl, 5.0, position=(0.0, 0.0, 0.019))        # v = 0.19, h = 0
    assert ctrl.mode == 'horizontal'
    _update(ctrl, 6.0, position=(0.0, 0.0, 0.021))        # v = 0.21 > 0.2 and > 1.5 h
    assert ctrl.mode == 'vertical'


def test_switching_dwell_time(robot) -> None:
    ctrl = _switching(robot)
    _update(ctrl, 0.0, position=(0.1, 0.0, 0.0))           # horizontal; travel 0 + 0.1 s
    assert ctrl.mode == 'horizontal'
    _update(ctrl, 0.5, position=(0.0, 0.0, 1.0))           # vertical error huge, but 0.5 s < dwell
    assert ctrl.mode == 'horizontal'
    _update(ctrl, 0.999, position=(0.0, 0.0, 1.0))
    assert ctrl.mode == 'horizontal'
    out = _update(ctrl, 1.0, position=(0.0, 0.0, 1.0))
    assert ctrl.mode == 'vertical' and out.mode == 'transition'
    # Back again needs the servo travel to finish and the dwell time to pass.
    travel = (math.pi / 2) / robot.tilt_rate_limit + SETTINGS.settle_time
    assert travel < SETTINGS.dwell_time       # so the dwell, not the travel, decides here
    out = _update(ctrl, 1.0 + travel + 0.01, position=(1.0, 0.0, 0.0))
    assert ctrl.mode == 'vertical' and out.mode == 'vertical'    # servos there, dwell not
    _update(ctrl, 1.999, position=(1.0, 0.0, 0.0))
    assert ctrl.mode == 'vertical'
    _update(ctrl, 2.0, position=(1.0, 0.0, 0.0))
    assert ctrl.mode == 'horizontal' and ctrl.switches == 3
    # With a slow servo the travel decides: no switch before the tilts arrive.
    slow = SwitchingController(GAINS, SETTINGS, dataclasses.replace(robot,
                                                                   tilt_rate_limit=0.5))
    _update(slow, 0.0, position=(0.0, 0.0, 0.1))           # vertical: pi/2 / 0.5 + 0.1 s
    arrive = math.pi + 0.1
    out = _update(slow, arrive - 0.01, position=(1.0, 0.0, 0.0))
    assert slow.mode == 'vertical' and out.mode == 'transition'
    out = _update(slow, arrive + 0.01, position=(1.0, 0.0, 0.0))
    assert slow.mode == 'horizontal' and out.mode == 'transition'
    ctrl.reset()
    assert ctrl.mode is None and ctrl.switches == 0


# --------------------------------------------------------------------------- configuration


def test_shipped_config_follows_its_documented_tuning_rule() -> None:
    # config/wrench_controller.yaml: kp = M w^2, kd = 2 zeta M w, ki = kp w / 5,
    # zeta = 1, w = 1 rad/s (position) and 2.5 rad/s (attitude), M from (A.2).
    cfg = load_controller_config()
    robot = load_robot_params()
    w = np.array([1.0, 1.0, 1.0, 2.5, 2.5, 2.5])
    M = np.array(robot.mass_matrix)
    np.testing.assert_allclose(cfg.gains.kp, M * w**2, rtol=2e-3)
    np.testing.assert_allclose(cfg.gains.kd, 2.0 * M * w, rtol=2e-3)
    np.testing.assert_allclose(cfg.gains.ki, np.array(cfg.gains.kp) * w / 5.0, rtol=2e-3)
    assert cfg.kind in ('pd', 'pid', 'switching')
    assert cfg.source is not None and cfg.source.endswith('wrench_controller.yaml')


def test_make_controller_builds_each_kind() -> None:
    cfg = load_controller_config()
    robot = load_robot_params()
    kinds = {'pd': PDController, 'pid': PIDController, 'switching': SwitchingController}
    for kind, cls in kinds.items():
        assert isinstance(make_controller(cfg.with_kind(kind), robot), cls)
    with pytest.raises(ParameterError, match=r"'controller'.*'lqr'"):
        cfg.with_kind('lqr')


VALID = {'controller': 'pd', 'gains': {'kp': list(KP), 'kd': list(KD)}}


@pytest.mark.parametrize(('change', 'name'), [
    ({'controller': 'lqr'}, 'controller'),
    ({'gains': None}, 'gains'),
    ({'gains': {'kp': [1.0] * 5, 'kd': list(KD)}}, 'gains.kp'),
    ({'gains': {'kp': list(KP)}}, 'gains.kd'),
    ({'gains': {'kp': list(KP), 'kd': [1.0, -1.0, 1, 1, 1, 1]}}, 'gains.kd'),
    ({'gains': {'kp': list(KP), 'kd': list(KD), 'ki': [math.nan] * 6}}, 'gains.ki'),
    ({'gains': {'kp': list(KP), 'kd': list(KD), 'integral_limit': 'big'}},
     'gains.integral_limit'),
    ({'gains': {'kp': [True] * 6, 'kd': list(KD)}}, 'gains.kp'),
    ({'gains': {'kp': list(KP), 'kd': list(KD), 'kf': [1.0] * 6}}, 'gains.kf'),
    ({'switching': {'hysteresis': -0.1}}, 'switching.hysteresis'),
    ({'switching': {'position_scale': 0.0}}, 'switching.position_scale'),
    ({'switching': {'dwell_time': 'long'}}, 'switching.dwell_time'),
    ({'switching': {'dwel_time': 1.0}}, 'switching.dwel_time'),
    ({'switching': [1, 2]}, 'switching'),
])
def test_bad_controller_parameters_name_the_parameter(change: dict, name: str) -> None:
    values = {**VALID, **change}
    with pytest.raises(ParameterError) as info:
        ControllerConfig.from_mapping(values, source='ctrl.yaml')
    assert info.value.name == name
    assert f"'{name}'" in str(info.value) and 'ctrl.yaml' in str(info.value)


def test_load_controller_config_from_a_file(tmp_path: Path) -> None:
    path = tmp_path / 'ctrl.yaml'
    path.write_text('wrench_controller:\n  ros__parameters:\n    controller: pid\n'
                    '    gains: {kp: [1, 2, 3, 4, 5, 6], kd: [0, 0, 0, 0, 0, 0]}\n')
    cfg = load_controller_config(path)
    assert cfg.kind == 'pid' and cfg.gains.kp == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    assert cfg.gains.ki == (0.0,) * 6 and cfg.switching == SwitchingSettings()
    path.write_text('other_node:\n  ros__parameters: {}\n')
    with pytest.raises(ParameterError, match='wrench_controller') as info:
        load_controller_config(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize('compiled', [True, False])
def test_the_pid_integral_does_not_wind_up_against_a_reported_shortfall(
        robot, compiled: bool) -> None:
    """Given what the allocator achieved of its previous wrench, the integral of a DOF
    holds still while that wrench fell short beyond the tolerance in the direction the
    error pushes (here +x, 5 N short); it integrates on when the shortfall is small,
    of the other sign, or not reported."""
    shipped = load_controller_config().with_kind('pid')
    assert shipped.gains.antiwindup == 0.0            # off unless asked for
    config = dataclasses.replace(shipped, gains=dataclasses.replace(shipped.gains,
                                                                    antiwindup=1.0))
    ref = Reference.hold((1.0, 0.0, 0.0))            # e_x = 1 m: the integral grows in x
    cases = {'short in +X': (5.0, False), 'short in -X': (-5.0, True),
             'within the tolerance': (0.1, True), 'not reported': (None, True)}
    for name, (short, integrates) in cases.items():
        pid = make_controller(config, robot)
        assert isinstance(pid, PIDController)
        pid.compiled = compiled and pid.compiled
        first = pid.update(0.0, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(6), ref)
        achieved = None if short is None else first.wrench - np.array([short, 0, 0, 0, 0, 0])
        pid.update(0.05, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(6), ref,
                   achieved=achieved)
        assert (pid.integral[0] > 0.0) == integrates, name
        assert pid.integral[0] in (0.0, pytest.approx(0.05))
    off = make_controller(shipped, robot)                 # off: a shortfall changes nothing
    first = off.update(0.0, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(6), ref)
    off.update(0.05, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(6), ref,
               achieved=first.wrench - np.array([5.0, 0, 0, 0, 0, 0]))
    assert off.integral[0] == pytest.approx(0.05)    # type: ignore[attr-defined]


@pytest.mark.parametrize('antiwindup', [0.0, 1.0])
def test_a_resumed_pid_continues_its_predecessor_to_the_last_bit(robot, antiwindup) -> None:
    """``resume`` with the state a pid had after a tick (the integral after it, its time,
    its wrench: what a respawned controller gets handed, nodes/handoff.py) gives the very
    outputs the predecessor gives from then on, anti-windup included."""
    gains = dataclasses.replace(GAINS, antiwindup=antiwindup)
    rng = np.random.default_rng(5)
    states = [(rng.normal(0, 0.2, 3), _q(rng.normal(0, 0.1), rng.normal(0, 0.1), 0.0),
               rng.normal(0, 0.1, 6)) for _ in range(12)]
    ref = _ref((0.3, -0.2, 0.1))
    achieved = [rng.normal(0, 5.0, 6) for _ in states]
    first = PIDController(gains, robot)
    outs = [first.update(0.05 * k, *state, ref, achieved=achieved[k]).wrench
            for k, state in enumerate(states[:6])]
    successor = PIDController(gains, robot)
    successor.resume(0.05 * 5, first.integral.copy(), outs[-1])
    for k in range(6, len(states)):
        expected = first.update(0.05 * k, *states[k], ref, achieved=achieved[k]).wrench
        got = successor.update(0.05 * k, *states[k], ref, achieved=achieved[k]).wrench
        np.testing.assert_array_equal(got, expected)
        np.testing.assert_array_equal(successor.integral, first.integral)
