"""Kinematics: J(eta) of (A.1) as printed, ZYX Euler angles, quaternions, ssa."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tiltrov_ros.core.kinematics import (
    J,
    Rquat,
    Rzyx,
    Smtrx,
    Tquat,
    Tzyx,
    euler_from_quat,
    euler_from_rotation,
    quat_from_euler,
    quat_from_rotation,
    quat_multiply,
    quat_normalize,
    ssa,
)


def _random_eta(rng: np.random.Generator) -> np.ndarray:
    return np.concatenate([rng.uniform(-5, 5, 3),
                           [rng.uniform(-math.pi, math.pi), rng.uniform(-1.4, 1.4),
                            rng.uniform(-math.pi, math.pi)]])


def _J_as_printed(eta: np.ndarray) -> np.ndarray:
    """(A.1), typed in from the paper entry by entry."""
    _, _, _, phi, th, psi = eta
    c, s, t = math.cos, math.sin, math.tan
    out = np.zeros((6, 6))
    out[0, :3] = [c(psi) * c(th), -s(psi) * c(phi) + c(psi) * s(th) * s(phi),
                  s(psi) * s(phi) + c(psi) * c(phi) * s(th)]
    out[1, :3] = [s(psi) * c(th), c(psi) * c(phi) + s(th) * s(psi) * s(phi),
                  -c(psi) * s(phi) + s(th) * s(psi) * c(phi)]
    out[2, :3] = [-s(th), c(th) * s(phi), c(th) * c(phi)]
    out[3, 3:] = [1.0, s(phi) * t(th), c(phi) * t(th)]
    out[4, 3:] = [0.0, c(phi), -s(phi)]
    out[5, 3:] = [0.0, s(phi) / c(th), c(phi) / c(th)]
    return out


@pytest.mark.parametrize('seed', range(3))
def test_J_matches_A1_element_wise(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(50):
        eta = _random_eta(rng)
        np.testing.assert_allclose(J(eta), _J_as_printed(eta), rtol=1e-13, atol=1e-13)


def test_Rzyx_is_Rz_Ry_Rx_and_orthonormal() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        phi, th, psi = _random_eta(rng)[3:]
        Rx = np.array([[1, 0, 0], [0, math.cos(phi), -math.sin(phi)],
                       [0, math.sin(phi), math.cos(phi)]])
        Ry = np.array([[math.cos(th), 0, math.sin(th)], [0, 1, 0],
                       [-math.sin(th), 0, math.cos(th)]])
        Rz = np.array([[math.cos(psi), -math.sin(psi), 0],
                       [math.sin(psi), math.cos(psi), 0], [0, 0, 1]])
        R = Rzyx(phi, th, psi)
        np.testing.assert_allclose(R, Rz @ Ry @ Rx, atol=1e-15)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)
        assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)


def test_quaternion_and_euler_round_trips() -> None:
    rng = np.random.default_rng(2)
    for _ in range(100):
        euler = _random_eta(rng)[3:]
        q = quat_from_euler(*euler)
        assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-15)
        np.testing.assert_allclose(Rquat(q), Rzyx(*euler), atol=1e-15)
        np.testing.assert_allclose(euler_from_quat(q), euler, atol=1e-12)
        np.testing.assert_allclose(euler_from_rotation(Rzyx(*euler)), euler, atol=1e-12)
        # From a rotation matrix back to the same rotation (q and -q are one rotation).
        q2 = quat_from_rotation(Rquat(q))
        assert q2[0] >= 0.0
        np.testing.assert_allclose(q2, q if q[0] >= 0 else -q, atol=1e-14)


def test_quat_from_rotation_covers_every_branch() -> None:
    # 180 deg about x, y, z and identity: each picks a different pivot.
    for q in ([1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0],
              quat_normalize([0.1, -0.9, 0.3, 0.2]), quat_normalize([0.1, 0.2, -0.9, 0.3]),
              quat_normalize([0.1, 0.3, 0.2, -0.9])):
        q = np.asarray(q)
        q2 = quat_from_rotation(Rquat(q))
        assert min(np.max(np.abs(q2 - q)), np.max(np.abs(q2 + q))) < 1e-14


def test_Rquat_ignores_the_norm() -> None:
    q = quat_normalize([0.3, -0.2, 0.8, 0.1])
    R = Rquat(q)
    np.testing.assert_allclose(Rquat(1.7 * q), R, atol=1e-15)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-15)


def test_Tquat_is_half_q_times_omega() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = quat_normalize(rng.normal(size=4))
        w = rng.normal(size=3)
        np.testing.assert_allclose(Tquat(q) @ w,
                                   0.5 * quat_multiply(q, np.concatenate([[0.0], w])),
                                   atol=1e-15)


def test_quaternion_product_composes_rotations() -> None:
    rng = np.random.default_rng(4)
    a, b = quat_normalize(rng.normal(size=4)), quat_normalize(rng.normal(size=4))
    np.testing.assert_allclose(Rquat(quat_multiply(a, b)), Rquat(a) @ Rquat(b), atol=1e-14)


def test_Smtrx_is_the_cross_product() -> None:
    rng = np.random.default_rng(5)
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(Smtrx(a) @ b, np.cross(a, b), atol=1e-15)
    np.testing.assert_allclose(Smtrx(a), -Smtrx(a).T)


@pytest.mark.parametrize('seed', range(3))
def test_eta_dot_J_nu_agrees_with_quaternion_kinematics(seed: int) -> None:
    """At a generic attitude, d/dt of the Euler angles of q(t), with q_dot = T(q) omega,
    is Tzyx omega; and R(q) nu_1 is the position block of J nu."""
    rng = np.random.default_rng(seed)
    eta = _random_eta(rng)
    nu = rng.normal(size=6)
    q = quat_from_euler(*eta[3:])
    q_dot = Tquat(q) @ nu[3:]
    dt = 1e-6
    # Central difference of the Euler angles along the quaternion trajectory (O(dt^2)).
    euler_dot = (euler_from_quat(q + dt * q_dot) - euler_from_quat(q - dt * q_dot)) / (2 * dt)
    eta_dot = J(eta) @ nu
    np.testing.assert_allclose(euler_dot, eta_dot[3:], rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(Rquat(q) @ nu[:3], eta_dot[:3], atol=1e-14)


def test_Tzyx_and_J_refuse_the_singularity() -> None:
    with pytest.raises(ValueError, match='singular'):
        Tzyx(0.1, math.pi / 2)
    with pytest.raises(ValueError, match='singular'):
        J([0, 0, 0, 0.0, -math.pi / 2, 0.3])
    with pytest.raises(ValueError, match='shape'):
        J([0.0, 0.0, 0.0])


@pytest.mark.parametrize('pitch', [math.pi / 2, -math.pi / 2])
@pytest.mark.parametrize(('roll', 'yaw'), [(0.0, 0.4), (0.7, -2.0), (-3.0, 3.0)])
def test_euler_at_gimbal_lock_still_describes_the_rotation(pitch: float, roll: float,
                                                           yaw: float) -> None:
    q = quat_from_euler(roll, pitch, yaw)
    phi, theta, psi = euler_from_quat(q)
    assert theta == pytest.approx(pitch, abs=1e-7)
    assert phi == 0.0
    np.testing.assert_allclose(Rzyx(phi, theta, psi), Rquat(q), atol=1e-7)


@pytest.mark.parametrize(('angle', 'expected'), [
    (0.0, 0.0), (1.0, 1.0), (-1.0, -1.0), (math.pi, math.pi), (-math.pi, math.pi),
    (3 * math.pi, math.pi), (-3 * math.pi, math.pi), (2 * math.pi, 0.0),
    (1.5 * math.pi, -0.5 * math.pi), (-1.5 * math.pi, 0.5 * math.pi),
    (math.pi + 1e-9, -math.pi + 1e-9), (np.nextafter(math.pi, 4.0), math.pi),
])
def test_ssa_wraps_to_minus_pi_exclusive_pi_inclusive(angle: float, expected: float) -> None:
    assert ssa(angle) == pytest.approx(expected, abs=1e-12)
    np.testing.assert_allclose(ssa(np.array([angle])), [expected], atol=1e-12)


def test_ssa_random_angles() -> None:
    rng = np.random.default_rng(6)
    base = rng.uniform(-math.pi, math.pi, 1000)
    turns = rng.integers(-20, 21, 1000)
    wrapped = ssa(base + 2 * math.pi * turns)
    assert np.all(wrapped > -math.pi) and np.all(wrapped <= math.pi)
    np.testing.assert_allclose(wrapped, base, atol=1e-12)
    # Already in range: unchanged, bit for bit.
    assert np.array_equal(ssa(base), base)
    assert ssa(1e-300) == 1e-300


def test_euler_from_quat_rows_is_euler_from_quat_row_by_row() -> None:
    from tiltrov_ros.core.kinematics import euler_from_quat_rows

    rng = np.random.default_rng(11)
    q = rng.normal(size=(2000, 4))                   # any norm: R is that of q / |q|
    q[:5] = [quat_from_euler(0.3, math.pi / 2, -1.0), quat_from_euler(0.3, -math.pi / 2, 2.0),
             [1.0, 0, 0, 0], [0, 0, 0, 1.0], [0, 1.0, 0, 0]]   # gimbal lock, identity, flips
    expected = np.array([euler_from_quat(row) for row in q])
    got = euler_from_quat_rows(q)
    assert got.shape == (2000, 3)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    assert euler_from_quat_rows(np.zeros((0, 4))).shape == (0, 3)
