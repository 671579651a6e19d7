"""The headless runner: time grids, call order, zero-order hold, fixed-tilt requests.

The controller and allocator here are small test-local stand-ins (the real ones
live in core/controllers.py and core/allocation.py): a depth/attitude PD and a
least-squares allocator at fixed tilts.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.kinematics import Rquat
from tiltrov_ros.core.params import RobotParams, load_robot_params
from tiltrov_ros.core.plant import Plant
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.runner import Reference, hold_reference, run
from tiltrov_ros.core.thrust_map import allocation_matrix, thrust_wrench


@dataclass
class Output:
    wrench: np.ndarray
    tilt_request: tuple[float, float] | None = None


@dataclass
class Result:
    thrusts: np.ndarray
    tilt_front: float
    tilt_rear: float
    achieved: np.ndarray
    feasible: bool


@dataclass
class LstsqAllocator:
    """Stand-in: thrusts by least squares on eq. (5) at fixed tilts, then saturated."""

    params: RobotParams
    tilts: tuple[float, float] = (math.pi / 2, math.pi / 2)
    calls: list[tuple[str, np.ndarray, Any, Any]] = field(default_factory=list)

    def _solve(self, wrench: np.ndarray, tf: float, tr: float) -> Result:
        sa, ca, sb, cb = math.sin(tf), math.cos(tf), math.sin(tr), math.cos(tr)
        G = np.zeros((8, 4))       # q = G f at fixed tilts, eq. (5)
        G[[0, 1, 4, 5], [0, 1, 0, 1]] = [sa, sa, ca, ca]
        G[[2, 3, 6, 7], [2, 3, 2, 3]] = [sb, sb, cb, cb]
        B = allocation_matrix(self.params.length, self.params.width) @ G
        f, *_ = np.linalg.lstsq(B, wrench, rcond=None)
        f = np.clip(f, -self.params.max_thrust, self.params.max_thrust)
        achieved = B @ f
        return Result(f, tf, tr, achieved, bool(np.allclose(achieved, wrench, atol=1e-9)))

    def allocate(self, wrench: np.ndarray, previous: Any = None) -> Result:
        self.calls.append(('allocate', wrench.copy(), None, previous))
        return self._solve(wrench, *self.tilts)

    def allocate_fixed(self, wrench: np.ndarray, tilt_front: float, tilt_rear: float,
                       previous: Any = None) -> Result:
        self.calls.append(('allocate_fixed', wrench.copy(), (tilt_front, tilt_rear), previous))
        return self._solve(wrench, tilt_front, tilt_rear)


@dataclass
class DepthPD:
    """Stand-in: PD on depth (in NED, rotated into the body) and on roll and pitch."""

    kp_z: float = 100.0
    kd_z: float = 150.0
    kp_att: float = 40.0
    kd_att: float = 20.0
    tilt_request: tuple[float, float] | None = None
    seen: list[tuple[float, np.ndarray, np.ndarray, np.ndarray, Reference]] = field(
        default_factory=list)

    def update(self, t: float, position: np.ndarray, quaternion: np.ndarray, nu: np.ndarray,
               reference: Reference) -> Output:
        self.seen.append((t, position, quaternion, nu, reference))
        R = Rquat(quaternion)
        z_dot = (R @ nu[:3])[2]
        force_ned = np.array([0.0, 0.0, self.kp_z * (reference.position[2] - position[2])
                              - self.kd_z * z_dot])
        # Small-angle attitude error from the rotation matrix: roll and pitch back to level.
        K = -self.kp_att * R[2, 1] - self.kd_att * nu[3]
        M = self.kp_att * R[2, 0] - self.kd_att * nu[4]
        wrench = np.concatenate([R.T @ force_ned, [K, M, 0.0]])
        return Output(wrench, self.tilt_request)


@pytest.fixture(scope='module')
def params() -> RobotParams:
    return load_robot_params()


def _depth_ref(t: float) -> tuple[list[float], list[float], list[float]]:
    return [0.0, 0.0, 1.0 if t >= 0.5 else 0.0], [1.0, 0.0, 0.0, 0.0], [0.0] * 6


def test_grids_stamps_and_call_order(params: RobotParams) -> None:
    plant = Plant(params)
    controller, allocator = DepthPD(), LstsqAllocator(params)
    ref_times: list[float] = []

    def reference(t: float) -> tuple[list[float], list[float], list[float]]:
        ref_times.append(t)
        return _depth_ref(t)

    log = run(plant, controller, allocator, reference, 2.0)
    # Plant grid: every step including t = 0; control grid: ticks every 50 ms before the end.
    np.testing.assert_array_equal(log.t, [i * 10_000_000 / 1e9 for i in range(201)])
    np.testing.assert_array_equal(log.tc, [i * 50_000_000 / 1e9 for i in range(40)])
    assert ref_times == list(log.tc)
    assert plant.time_ns == 2_000_000_000
    # The controller saw, at each tick, the plant row stamped with that tick.
    assert [s[0] for s in controller.seen] == list(log.tc)
    for k, (_, position, quaternion, nu, reference_seen) in enumerate(controller.seen):
        i = 5 * k
        np.testing.assert_array_equal(position, log.position[i])
        np.testing.assert_array_equal(quaternion, log.quaternion[i])
        np.testing.assert_array_equal(nu, log.nu[i])
        np.testing.assert_array_equal(reference_seen.position, log.setpoint_position[k])
    np.testing.assert_array_equal(log.setpoint_position[:10, 2], 0.0)
    np.testing.assert_array_equal(log.setpoint_position[10:, 2], 1.0)
    # Allocation: allocate() every tick, previous = the last result (None first).
    assert [c[0] for c in allocator.calls] == ['allocate'] * 40
    assert allocator.calls[0][3] is None
    for k in range(1, 40):
        np.testing.assert_array_equal(allocator.calls[k][3].thrusts, log.thrust_cmd[k - 1])
    np.testing.assert_array_equal(log.wrench_cmd, [c[1] for c in allocator.calls])
    np.testing.assert_allclose(
        log.wrench_achieved,
        thrust_wrench(log.thrust_cmd, log.tilt_cmd[:, 0], log.tilt_cmd[:, 1],
                      params.length, params.width), atol=1e-12)
    assert log.meta['control_period'] == 0.05 and log.meta['max_thrust'] == 40.0


def test_commands_are_held_between_ticks(params: RobotParams) -> None:
    """With ideal thrusters the actual thrust over (t_i, t_i + T] is the tick's command."""
    ideal = dataclasses.replace(params, thruster_time_constant=0.0)
    log = run(Plant(ideal), DepthPD(), LstsqAllocator(ideal), _depth_ref, 1.0)
    for i in range(1, len(log.t)):
        k = (i - 1) // 5          # the tick in force over the step that ended at t_i
        np.testing.assert_array_equal(log.thrust[i], log.thrust_cmd[k])
    # Tilts: commanded 90 deg at t = 0, reached at the rate limit, 0.6 s later.
    rate = ideal.tilt_rate_limit
    np.testing.assert_allclose(log.tilt_position[:, 0], np.minimum(rate * log.t, math.pi / 2),
                               atol=1e-12)
    assert np.all(np.abs(log.tilt_velocity) <= rate * (1 + 1e-12))


def test_tilt_request_goes_to_allocate_fixed(params: RobotParams) -> None:
    allocator = LstsqAllocator(params, tilts=(0.0, 0.0))
    controller = DepthPD(tilt_request=(math.pi / 2, 1.2))
    log = run(Plant(params), controller, allocator, _depth_ref, 0.5)
    assert {c[0] for c in allocator.calls} == {'allocate_fixed'}
    assert all(c[2] == (math.pi / 2, 1.2) for c in allocator.calls)
    np.testing.assert_array_equal(log.tilt_cmd, [[math.pi / 2, 1.2]] * 10)


def test_closed_loop_reaches_the_depth(params: RobotParams) -> None:
    """PD on depth at vertical tilts: z -> 1 m, less the offset of 5 N net buoyancy / kp."""
    controller = DepthPD()
    log = run(Plant(params), controller, LstsqAllocator(params), _depth_ref, 20.0)
    offset = (params.buoyancy - params.weight) / controller.kp_z
    assert log.position[-1, 2] == pytest.approx(1.0 - offset, abs=2e-3)
    assert np.max(np.abs(log.thrust)) <= params.max_thrust
    # Heave, roll and pitch are controlled and settle (surge, sway and yaw are not:
    # the thrust during the first 0.6 s of tilting leaves a slowly damped drift).
    np.testing.assert_allclose(log.nu[-1, 2:5], 0.0, atol=1e-4)


def test_same_inputs_same_log_and_npz_round_trip(params: RobotParams, tmp_path: Path) -> None:
    a = run(Plant(params), DepthPD(), LstsqAllocator(params), _depth_ref, 1.0)
    b = run(Plant(params), DepthPD(), LstsqAllocator(params), _depth_ref, 1.0)
    for name in ('position', 'quaternion', 'nu', 'thrust', 'tilt_position', 'wrench_cmd'):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    a.save_npz(tmp_path / 'run.npz')
    c = RunLog.load_npz(tmp_path / 'run.npz')
    np.testing.assert_array_equal(c.position, a.position)
    assert c.meta['robot']['mass_matrix'] == list(params.mass_matrix)


def test_progress_callback(params: RobotParams) -> None:
    fractions: list[float] = []
    run(Plant(params), DepthPD(), LstsqAllocator(params), hold_reference(), 3.0,
        progress=fractions.append)
    assert 50 <= len(fractions) <= 101
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and fractions[0] > 0.0


def test_invalid_timing_is_rejected(params: RobotParams) -> None:
    args = (DepthPD(), LstsqAllocator(params), hold_reference())
    with pytest.raises(ParameterError, match='duration'):
        run(Plant(params), *args, 0.015)
    with pytest.raises(ParameterError, match='control_period_ns'):
        run(Plant(params), *args, 1.0, control_period_ns=25_000_000)
    plant = Plant(params)
    plant.step()
    with pytest.raises(ParameterError, match='time_ns'):
        run(plant, *args, 1.0)
    with pytest.raises(ValueError, match='hold_reference'):
        hold_reference(quaternion=(2.0, 0.0, 0.0, 0.0))


def test_bad_shapes_from_the_controller_raise(params: RobotParams) -> None:
    class Broken:
        def update(self, *args: Any) -> Output:
            return Output(np.zeros(5))

    with pytest.raises(ValueError, match='controller wrench'):
        run(Plant(params), Broken(), LstsqAllocator(params), hold_reference(), 0.1)


def test_run_scenario_assembles_the_shipped_stack() -> None:
    from tiltrov_ros.core.runner import run_scenario, stack_config

    config = stack_config('pitch_hold', 'pid')
    assert config.robot.max_thrust == 40.0 and config.control_period == 0.05
    assert config.controller.kind == 'pid' and config.allocator.mode == 'robust'
    log = run_scenario(config, duration=2.0)
    assert len(log.t) == 201 and len(log.tc) == 40
    assert log.meta['scenario'] == 'pitch_hold' and log.meta['controller'] == 'pid'
    # The plant carries the scenario's center-of-mass error, the controller not.
    assert log.meta['true_center_of_gravity'] == pytest.approx([0.01, 0.0, 0.025])
    # The reference is the scenario's: pitch ramps to -30 deg in 30 s.
    from tiltrov_ros.core.kinematics import euler_from_quat
    assert euler_from_quat(log.setpoint_quaternion[-1])[1] == pytest.approx(
        math.radians(-30.0) * 1.95 / 30.0)
    again = run_scenario(stack_config('pitch_hold', 'pid'), duration=2.0)
    np.testing.assert_array_equal(log.position, again.position)   # deterministic
