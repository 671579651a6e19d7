"""Dynamics: C (A.3), D (A.4), g(eta) against their printed forms; the fast path against f."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tiltrov_ros.core.dynamics import (
    RigidBody,
    coriolis_matrix,
    damping_matrix,
    eta_from_state,
    f,
    gvect,
    kinetic_energy,
    m2c,
    mass_matrix,
    potential_energy,
    relative_velocity,
    restoring_forces,
)
from tiltrov_ros.core.kinematics import Rquat, Rzyx, quat_from_euler, quat_normalize
from tiltrov_ros.core.params import RobotParams, load_robot_params


@pytest.fixture(scope='module')
def params() -> RobotParams:
    return load_robot_params()


def _C_as_printed(nu: np.ndarray) -> np.ndarray:
    """(A.3), typed in from the paper."""
    u, v, w, p, q, r = nu
    return np.array([
        [0, 0, 0, 0, 168.57 * w, -133.04 * v],
        [0, 0, 0, -168.57 * w, 0, 96.30 * u],
        [0, 0, 0, 133.04 * v, -96.30 * u, 0],
        [0, 168.57 * w, -133.04 * v, 0, 8.10 * r, -9.26 * q],
        [-168.57 * w, 0, 96.30 * u, -8.10 * r, 0, 4.47 * p],
        [133.04 * v, -96.30 * u, 0, 9.26 * q, -4.47 * p, 0],
    ])


def _D_as_printed(nu: np.ndarray) -> np.ndarray:
    """(A.4), typed in from the paper."""
    return np.diag([34.55, 104.40, 146.50, 0.68, 5.34, 3.07] * np.abs(nu))


def test_M_is_A2(params: RobotParams) -> None:
    np.testing.assert_array_equal(
        mass_matrix(params), np.diag([96.3, 133.04, 168.57, 4.47, 9.26, 8.1]))


@pytest.mark.parametrize('seed', range(3))
def test_m2c_reproduces_A3_element_wise(params: RobotParams, seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(50):
        nu = rng.normal(scale=2.0, size=6)
        np.testing.assert_allclose(coriolis_matrix(params, nu), _C_as_printed(nu),
                                   rtol=1e-14, atol=1e-12)


@pytest.mark.parametrize('seed', range(3))
def test_C_is_skew_so_it_does_no_work(params: RobotParams, seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(100):
        nu = rng.normal(scale=3.0, size=6)
        C = coriolis_matrix(params, nu)
        np.testing.assert_allclose(C, -C.T, atol=0)
        assert nu @ C @ nu == pytest.approx(0.0, abs=1e-11)
    # Also for a full symmetric positive-definite M (m2c is general).
    A = rng.normal(size=(6, 6))
    M = A @ A.T + 6 * np.eye(6)
    nu = rng.normal(size=6)
    assert nu @ m2c(M, nu) @ nu == pytest.approx(0.0, abs=1e-11)


def test_D_is_A4_plus_linear(params: RobotParams) -> None:
    rng = np.random.default_rng(4)
    nu = rng.normal(size=6)
    np.testing.assert_allclose(damping_matrix(params, nu), _D_as_printed(nu), rtol=1e-15)
    lin = (1.0, 2.0, 3.0, 0.1, 0.2, 0.3)
    p2 = dataclasses.replace(params, linear_damping=lin)
    np.testing.assert_allclose(damping_matrix(p2, nu), _D_as_printed(nu) + np.diag(lin),
                               rtol=1e-15)


def _g_fossen_euler(W: float, B: float, phi: float, th: float, rg: np.ndarray,
                    rb: np.ndarray) -> np.ndarray:
    """Fossen's closed form of g(eta) in Euler angles (Fossen 2021, Sec. 4.1)."""
    xg, yg, zg = rg
    xb, yb, zb = rb
    s, c = math.sin, math.cos
    return np.array([
        (W - B) * s(th),
        -(W - B) * c(th) * s(phi),
        -(W - B) * c(th) * c(phi),
        -(yg * W - yb * B) * c(th) * c(phi) + (zg * W - zb * B) * c(th) * s(phi),
        (zg * W - zb * B) * s(th) + (xg * W - xb * B) * c(th) * c(phi),
        -(xg * W - xb * B) * c(th) * s(phi) - (yg * W - yb * B) * s(th),
    ])


@pytest.mark.parametrize('seed', range(3))
def test_g_from_R_equals_fossens_euler_form(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(50):
        W, B = rng.uniform(100, 1000, size=2)
        rg, rb = rng.normal(scale=0.1, size=3), rng.normal(scale=0.1, size=3)
        phi, th, psi = rng.uniform(-3, 3), rng.uniform(-1.5, 1.5), rng.uniform(-3, 3)
        np.testing.assert_allclose(gvect(W, B, Rzyx(phi, th, psi), rg, rb),
                                   _g_fossen_euler(W, B, phi, th, rg, rb),
                                   rtol=1e-12, atol=1e-10)


def test_g_is_finite_and_right_at_pitch_90(params: RobotParams) -> None:
    g = restoring_forces(params, Rquat(quat_from_euler(0.0, math.pi / 2, 0.3)))
    W, B, zg = params.weight, params.buoyancy, params.center_of_gravity[2]
    np.testing.assert_allclose(g, [W - B, 0, 0, 0, zg * W, 0], atol=1e-12)


def test_relative_velocity_uses_the_current_in_the_body_frame() -> None:
    R = Rzyx(0.0, 0.0, math.pi / 2)    # heading east
    nu = np.array([1.0, 0.0, 0.0, 0.1, 0.2, 0.3])
    # For a robot heading east, a current flowing north flows toward its port
    # side: v_c in the body frame is (0, -0.5, 0).
    np.testing.assert_allclose(relative_velocity(nu, R, [0.5, 0.0, 0.0]),
                               [1.0, 0.5, 0.0, 0.1, 0.2, 0.3], atol=1e-15)
    np.testing.assert_array_equal(relative_velocity(nu, R, None), nu)


def _random_state(rng: np.random.Generator, unit: bool = True) -> np.ndarray:
    x = np.concatenate([rng.normal(scale=3, size=3), quat_normalize(rng.normal(size=4)),
                        rng.normal(scale=1.5, size=6)])
    if not unit:
        x[3:7] *= rng.uniform(0.9, 1.1)
    return x


@pytest.mark.parametrize('seed', range(5))
def test_fast_derivative_equals_reference_f(params: RobotParams, seed: int) -> None:
    rng = np.random.default_rng(seed)
    variants = [
        params,
        dataclasses.replace(params, linear_damping=tuple(rng.uniform(0, 20, 6)),
                            center_of_gravity=tuple(rng.normal(scale=0.05, size=3)),
                            center_of_buoyancy=tuple(rng.normal(scale=0.05, size=3)),
                            weight=700.0, buoyancy=650.0),
    ]
    for p in variants:
        body = RigidBody(p)
        for unit in (True, False):
            for _ in range(20):
                x = _random_state(rng, unit)
                tau = rng.normal(scale=50, size=6)
                current = rng.normal(scale=0.5, size=3)
                fast = np.array(body.derivative(list(x), list(tau), list(current)))
                np.testing.assert_allclose(fast, f(0.0, x, tau, p, current),
                                           rtol=1e-12, atol=1e-12)
                fast0 = np.array(body.derivative(list(x), list(tau), [0.0, 0.0, 0.0]))
                np.testing.assert_allclose(fast0, f(0.0, x, tau, p), rtol=1e-12, atol=1e-12)


def test_f_at_rest_level_is_the_net_buoyancy(params: RobotParams) -> None:
    x = np.zeros(13)
    x[3] = 1.0
    xdot = f(0.0, x, np.zeros(6), params)
    np.testing.assert_array_equal(xdot[:7], np.zeros(7))
    # Level, at rest: only -(W - B) along z: 5 N of net buoyancy pushes up (-z).
    np.testing.assert_allclose(xdot[7:], [0, 0, (params.weight - params.buoyancy) / 168.57,
                                          0, 0, 0], atol=1e-15)


def test_energy_rate_is_minus_damping_power(params: RobotParams) -> None:
    """d(T + V)/dt along f equals nu^T tau - nu^T D(nu) nu (no current)."""
    rng = np.random.default_rng(8)
    for _ in range(20):
        x = _random_state(rng)
        tau = rng.normal(scale=20, size=6)
        xdot = f(0.0, x, tau, params)
        nu, nu_dot = x[7:], xdot[7:]
        dt = 1e-6
        R_plus = Rquat(x[3:7] + dt * xdot[3:7])
        R_minus = Rquat(x[3:7] - dt * xdot[3:7])
        dV = (potential_energy(params, x[:3] + dt * xdot[:3], R_plus)
              - potential_energy(params, x[:3] - dt * xdot[:3], R_minus)) / (2 * dt)
        dT = nu @ params.M @ nu_dot
        expected = nu @ tau - nu @ damping_matrix(params, nu) @ nu
        assert dT + dV == pytest.approx(expected, rel=1e-6, abs=1e-6)
    assert kinetic_energy(params, np.ones(6)) == pytest.approx(0.5 * sum(params.mass_matrix))


def test_eta_from_state() -> None:
    x = np.zeros(13)
    x[:3] = [1.0, 2.0, 3.0]
    x[3:7] = quat_from_euler(0.1, -0.2, 0.3)
    np.testing.assert_allclose(eta_from_state(x), [1.0, 2.0, 3.0, 0.1, -0.2, 0.3], atol=1e-14)
