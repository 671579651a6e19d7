"""Thrusters (saturation, first order) and tilt servos (angle and rate limits)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tiltrov_ros.core.actuators import ThrusterBank, TiltServos
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.params import load_robot_params


@pytest.mark.parametrize('rate_deg', [150.0, 60.0, 37.0])
@pytest.mark.parametrize('h', [0.01, 0.003])
def test_servo_0_to_90_deg_takes_90_over_rate_never_less(rate_deg: float, h: float) -> None:
    rate = math.radians(rate_deg)
    servos = TiltServos(-math.pi / 2, math.pi / 2, rate)
    target = math.pi / 2
    assert servos.command([target, 0.0])
    angles, times = [0.0], [0.0]
    for k in range(1, round(3.0 / h)):
        servos.step(h)
        angles.append(servos.angles[0])
        times.append(k * h)
        assert servos.angles[1] == 0.0
        assert abs(servos.velocities[0]) <= rate * (1 + 1e-12)
    a, t = np.array(angles), np.array(times)
    # Never faster than the rate limit, and exactly as fast while moving.
    assert np.all(a <= rate * t + 1e-12)
    np.testing.assert_allclose(a, np.minimum(rate * t, target), atol=1e-12)
    reached = t[np.argmax(a >= target - 1e-12)]   # float sums may need a last 1e-16
    assert a[-1] == target
    assert target / rate - 1e-9 <= reached < target / rate + h


def test_servo_velocity_is_backward_difference() -> None:
    servos = TiltServos(-1.0, 1.0, 2.0)
    assert servos.velocities == (0.0, 0.0)
    servos.command([0.5, -0.015])
    servos.step(0.01)
    np.testing.assert_allclose(servos.velocities, [2.0, -1.5], rtol=1e-12)
    np.testing.assert_allclose(servos.angles, [0.02, -0.015], rtol=1e-12)
    servos.step(0.01)
    np.testing.assert_allclose(servos.velocities, [2.0, 0.0], atol=1e-12)


def test_servo_command_is_clipped_to_the_angle_limits() -> None:
    p = load_robot_params()
    servos = TiltServos.from_params(p)
    servos.command([3.0, -3.0])
    assert servos.command_held == (p.tilt_max, p.tilt_min)
    for _ in range(200):
        servos.step(0.01)
        assert p.tilt_min <= min(servos.angles) and max(servos.angles) <= p.tilt_max
    assert servos.angles == (p.tilt_max, p.tilt_min)


def test_thrust_saturates_at_the_limit() -> None:
    bank = ThrusterBank(40.0, 0.1)
    bank.command([100.0, -100.0, 39.0, -1e9])
    assert bank.command_held == (40.0, -40.0, 39.0, -40.0)
    peak = 0.0
    for _ in range(300):
        bank.step(0.01)
        peak = max(peak, max(abs(v) for v in bank.thrusts))
    assert peak <= 40.0
    np.testing.assert_allclose(bank.thrusts, [40.0, -40.0, 39.0, -40.0], rtol=1e-12)


@pytest.mark.parametrize('T', [0.1, 0.37])
def test_thruster_first_order_response_is_one_minus_exp(T: float) -> None:
    h = 0.01
    bank = ThrusterBank(40.0, T)
    c = np.array([30.0, -20.0, 5.0, 0.0])
    bank.command(c)
    for k in range(1, 200):
        bank.step(h)
        np.testing.assert_allclose(bank.thrusts, c * (1.0 - math.exp(-k * h / T)),
                                   rtol=1e-12, atol=1e-12)


def test_thruster_time_constant_zero_is_ideal() -> None:
    bank = ThrusterBank(40.0, 0.0)
    bank.command([1.0, 2.0, 3.0, 50.0])
    bank.step(0.01)
    assert bank.thrusts == (1.0, 2.0, 3.0, 40.0)


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_non_finite_commands_hold_the_previous_one(bad: float) -> None:
    bank = ThrusterBank(40.0, 0.1)
    servos = TiltServos(-1.5, 1.5, 2.0)
    assert bank.command([10.0, 10.0, 10.0, 10.0])
    assert servos.command([0.5, 0.5])
    assert not bank.command([bad, 1.0, 1.0, 1.0])
    assert not servos.command([0.0, bad])
    assert (bank.rejected, servos.rejected) == (1, 1)
    assert bank.command_held == (10.0,) * 4
    assert servos.command_held == (0.5, 0.5)
    for _ in range(100):
        bank.step(0.01)
        servos.step(0.01)
    assert all(math.isfinite(v) for v in bank.thrusts + servos.angles + servos.velocities)
    np.testing.assert_allclose(bank.thrusts, [10.0] * 4, rtol=1e-4)
    assert servos.angles == (0.5, 0.5)


def test_wrong_lengths_and_invalid_set_up_raise() -> None:
    with pytest.raises(ValueError, match='expected 4'):
        ThrusterBank(40.0, 0.1).command([1.0, 2.0])
    with pytest.raises(ValueError, match='expected 2'):
        TiltServos(-1.0, 1.0, 1.0).command([1.0, 2.0, 3.0])
    with pytest.raises(ParameterError, match='initial thrusts'):
        ThrusterBank(40.0, 0.1, initial=[50.0, 0.0, 0.0, 0.0])
    with pytest.raises(ParameterError, match='initial tilts'):
        TiltServos(-1.0, 1.0, 1.0, initial=[0.0, 1.5])
    with pytest.raises(ParameterError, match='max_thrust'):
        ThrusterBank(-1.0, 0.1)
    with pytest.raises(ParameterError, match='tilt_rate_limit'):
        TiltServos(-1.0, 1.0, 0.0)
