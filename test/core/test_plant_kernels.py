"""The compiled plant step against its float reference (``Plant.compiled`` False), and
``step(n, log=...)``: n steps in one call, one sample row per step, the same numbers as
n calls (the lockstep ROS run steps one by one, the runner n at a time)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tiltrov_ros.core import jit
from tiltrov_ros.core.disturbances import Disturbances
from tiltrov_ros.core.kinematics import quat_normalize
from tiltrov_ros.core.params import RobotParams, load_robot_params
from tiltrov_ros.core.plant import SAMPLE_COLUMNS, SAMPLE_WIDTH, Plant, PlantSample
from tiltrov_ros.core.timebase import seconds

#: The comparisons need the kernels compiled; the API checks run on either backend.
needs_kernels = pytest.mark.skipif(not jit.compiled(), reason='the numpy backend has no kernels')


@pytest.fixture(scope='module')
def shipped() -> RobotParams:
    return load_robot_params()


def _random_plants(params: RobotParams, seed: int, integrator: str = 'rk4'
                   ) -> tuple[Plant, Plant, np.random.Generator]:
    """A compiled plant and its reference twin from one seeded random set-up: initial
    state, a com error, a current with a Gauss-Markov part, a constant or a callable
    external wrench."""
    rng = np.random.default_rng(seed)
    if seed % 2:
        a, w = rng.uniform(-20, 20, 6), rng.uniform(0.2, 3.0)
        wrench = (lambda t: a * math.sin(w * t))            # noqa: E731
    else:
        wrench = tuple(rng.uniform(-20, 20, 6))
    dist = Disturbances(com_error=tuple(rng.uniform(-0.02, 0.02, 3)),
                        current=tuple(rng.uniform(-0.3, 0.3, 3)),
                        current_std=tuple(rng.uniform(0.0, 0.1, 3)) if seed % 3 else (0.0,) * 3,
                        current_time_constant=tuple(rng.uniform(1.0, 60.0, 3)),
                        seed=seed, external_wrench=wrench)
    robot = dataclasses.replace(params, linear_damping=tuple(rng.uniform(0, 10, 6)))
    init = dict(position=rng.uniform(-3, 3, 3), quaternion=quat_normalize(rng.normal(size=4)),
                nu=rng.normal(scale=[0.5, 0.5, 0.5, 1.0, 1.0, 1.0]),
                tilts=rng.uniform(robot.tilt_min, robot.tilt_max, 2),
                thrusts=rng.uniform(-robot.max_thrust, robot.max_thrust, 4))
    kernel = Plant(robot, dist, integrator=integrator, **init)   # type: ignore[arg-type]
    reference = Plant(robot, dist, integrator=integrator, **init)  # type: ignore[arg-type]
    reference.compiled = False
    assert kernel.compiled
    return kernel, reference, rng


def _drive(plants: tuple[Plant, ...], rng: np.random.Generator, steps: int) -> None:
    """Random commands every 5 steps (some beyond the limits, some not finite) and
    thruster failures coming and going, the same for every plant."""
    for i in range(steps):
        if i % 5 == 0:
            f = rng.uniform(-60, 60, 4)
            a = rng.uniform(-2.5, 2.5, 2)
            if rng.uniform() < 0.1:
                f[rng.integers(4)] = math.nan
            for p in plants:
                p.command(f, a)
        if i % 97 == 0:
            failed = tuple(int(k) for k in np.flatnonzero(rng.uniform(size=4) < 0.3))
            for p in plants:
                p.set_failed_thrusters(failed)
        for p in plants:
            p.step()


def _assert_same_state(a: Plant, b: Plant, rtol: float) -> None:
    np.testing.assert_allclose(a.state, b.state, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(a.thrusts, b.thrusts, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(a.tilts, b.tilts, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(a.tilt_velocities, b.tilt_velocities, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(a.current_velocity, b.current_velocity, rtol=rtol, atol=rtol)
    assert a.time_ns == b.time_ns


@needs_kernels
@pytest.mark.parametrize('seed', range(12))
def test_kernel_equals_the_float_reference(shipped: RobotParams, seed: int) -> None:
    kernel, reference, rng = _random_plants(shipped, seed)
    _drive((kernel, reference), rng, 500)
    _assert_same_state(kernel, reference, 1e-12)
    assert kernel.thrusters.rejected == reference.thrusters.rejected


@needs_kernels
@pytest.mark.parametrize('seed', range(3))
def test_kernel_equals_the_reference_with_forward_euler(shipped: RobotParams, seed: int) -> None:
    kernel, reference, rng = _random_plants(shipped, seed, 'euler')
    _drive((kernel, reference), rng, 300)
    _assert_same_state(kernel, reference, 1e-12)


@needs_kernels
@pytest.mark.parametrize('seed', range(6))
def test_n_steps_in_one_call_equal_n_calls_and_log_every_sample(shipped: RobotParams,
                                                               seed: int) -> None:
    one, many, rng = _random_plants(shipped, seed)
    many.compiled = True
    one.command([20.0, -10.0, 5.0, 40.0], [0.5, -1.0])
    many.command([20.0, -10.0, 5.0, 40.0], [0.5, -1.0])
    log = np.full((240, SAMPLE_WIDTH), np.nan)
    done = 0
    while done < 240:
        n = int(rng.integers(1, 12))
        n = min(n, 240 - done)
        many.step(n, log=log[done:done + n])
        for k in range(n):
            one.step()
            row = log[done + k]
            sample = one.sample()
            assert row[SAMPLE_COLUMNS['t']] == seconds(sample.t_ns)
            for name in PlantSample._fields[1:]:
                np.testing.assert_array_equal(row[SAMPLE_COLUMNS[name]], getattr(sample, name))
        done += n
    np.testing.assert_array_equal(many.state, one.state)
    assert many.time_ns == one.time_ns


@needs_kernels
def test_the_reference_logs_the_same_rows(shipped: RobotParams) -> None:
    kernel, reference, _ = _random_plants(shipped, 4)
    logs = [np.zeros((50, SAMPLE_WIDTH)), np.zeros((50, SAMPLE_WIDTH))]
    for plant, log in zip((kernel, reference), logs):
        plant.command([10.0, 10.0, -10.0, 0.0], [0.2, 0.4])
        plant.step(50, log=log)
    np.testing.assert_allclose(logs[0], logs[1], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize('compiled', [True, False])
def test_a_bad_external_wrench_stops_after_the_steps_before_it(shipped: RobotParams,
                                                              compiled: bool) -> None:
    def wrench(t: float) -> list[float]:
        return [0.0, 0.0, 0.0, 0.0, 0.0, math.nan if t >= 0.03 else 1.0]

    plant = Plant(shipped, Disturbances(external_wrench=wrench))
    plant.compiled = compiled
    with pytest.raises(ValueError, match=r'external wrench at t = 0\.03'):
        plant.step(10)
    assert plant.time_ns == 30_000_000
    assert plant.nu[5] > 0.0 and np.all(np.isfinite(plant.state))


def test_a_wrong_log_is_refused(shipped: RobotParams) -> None:
    plant = Plant(shipped)
    for bad in (np.zeros((2, SAMPLE_WIDTH)), np.zeros((5, SAMPLE_WIDTH - 1)),
                np.zeros((5, SAMPLE_WIDTH), dtype=np.float32),
                np.zeros((SAMPLE_WIDTH, 5)).T):
        with pytest.raises(ValueError, match='log'):
            plant.step(3, log=bad)
    assert plant.time_ns == 0
    plant.step(0)
    assert plant.time_ns == 0
