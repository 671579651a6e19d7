"""metrics.json from a RunLog: each metric on a hand-built log, and against the runner."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from tiltrov_ros.core.controllers import make_controller, tracking_error
from tiltrov_ros.core.kinematics import quat_from_euler
from tiltrov_ros.core.metrics import (
    SETTLING_FLOOR,
    compute_metrics,
    control_errors,
    metric_differences,
    write_metrics,
)
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.runner import run, stack_config

DEG = math.pi / 180.0
H, T = 0.01, 0.05


def _log(duration: float = 30.0, *, max_thrust: float | None = 40.0) -> RunLog:
    """A still robot at the origin, a zero setpoint, zero commands: edit the arrays."""
    n = round(duration / H)
    m = round(duration / T)
    t = np.arange(n + 1) * 1e7 / 1e9                 # as timebase.seconds(ns) computes it
    tc = np.arange(m) * 5e7 / 1e9
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (n + 1, 1))
    meta = {'scenario': 'synthetic', 'controller': 'pd', 'allocator_mode': 'robust'}
    if max_thrust is not None:
        meta['max_thrust'] = max_thrust
    return RunLog(t=t, position=np.zeros((n + 1, 3)), quaternion=identity,
                  nu=np.zeros((n + 1, 6)), tilt_position=np.zeros((n + 1, 2)),
                  tilt_velocity=np.zeros((n + 1, 2)), thrust=np.zeros((n + 1, 4)), tc=tc,
                  setpoint_position=np.zeros((m, 3)),
                  setpoint_quaternion=np.tile([1.0, 0.0, 0.0, 0.0], (m, 1)),
                  setpoint_velocity=np.zeros((m, 6)), wrench_cmd=np.zeros((m, 6)),
                  thrust_cmd=np.zeros((m, 4)), tilt_cmd=np.zeros((m, 2)),
                  wrench_achieved=np.zeros((m, 6)), meta=meta)


def test_errors_use_the_odometry_sample_at_the_tick() -> None:
    log = _log(2.0)
    log.position[:, 0] = log.t                      # x = t on the plant grid
    log.setpoint_position[:, 0] = log.tc            # x_d = t on the control grid
    err = control_errors(log)
    # The sample at the tick (not the one 10 ms before or after) gives e = 0.
    np.testing.assert_array_equal(err.e[:, 0], 0.0)
    np.testing.assert_array_equal(err.t, log.tc)
    assert len(err.t) == 40


def test_rms_final_and_max_error_with_angle_wrapping() -> None:
    log = _log(30.0)
    early = log.tc < 20.0
    # x: 1 m error for t < 20 s, 0.1 m after: rms over all, final over the last 10 s only.
    log.setpoint_position[:, 0] = np.where(early, 1.0, 0.1)
    # yaw: setpoint -179 deg, robot at +179 deg: +2 deg, not -358 deg.
    log.setpoint_quaternion[:] = quat_from_euler(0.0, 0.0, -179 * DEG)
    log.quaternion[:] = quat_from_euler(0.0, 0.0, 179 * DEG)
    # z: the robot is 5 cm above the setpoint (NED: z = -0.05): e_z = +0.05.
    log.position[:, 2] = -0.05
    m = compute_metrics(log)
    assert m['rms_error']['x'] == pytest.approx(math.sqrt((400 * 1.0 + 200 * 0.01) / 600))
    assert m['final_error']['x'] == pytest.approx(0.1)
    assert m['max_error']['x'] == pytest.approx(1.0)
    assert m['rms_error']['yaw'] == pytest.approx(2 * DEG)
    assert m['final_error']['yaw'] == pytest.approx(2 * DEG)
    assert m['final_error']['z'] == pytest.approx(0.05)
    assert m['rms_error']['z'] == pytest.approx(0.05)
    assert m['rms_error']['y'] == 0.0 and m['final_error']['pitch'] == 0.0
    assert control_errors(log).e[0, 5] == pytest.approx(2 * DEG)      # signed: +2 deg


def test_final_window_is_the_last_10_seconds_of_the_run() -> None:
    log = _log(30.0)
    # Only the tick at 19.95 s (just before the window) and 20.0 s (its first) differ.
    log.setpoint_position[log.tc == 19.95, 1] = 100.0
    log.setpoint_position[log.tc == 20.0, 1] = 2.0
    m = compute_metrics(log)
    assert m['final_error']['y'] == pytest.approx(2.0 / 200)          # 200 ticks in 10 s


def test_tilt_rate_and_servo_travel() -> None:
    log = _log(1.0)
    log.tilt_position[:, 0] = np.concatenate([np.linspace(0, 1, 51), np.linspace(1, 0.5, 50)])
    log.tilt_velocity[:, 0] = np.gradient(log.tilt_position[:, 0], H)
    log.tilt_velocity[17, 1] = -2.5
    m = compute_metrics(log)
    assert m['servo_travel']['front'] == pytest.approx(1.5)
    assert m['servo_travel']['rear'] == 0.0
    assert m['max_tilt_rate']['front'] == pytest.approx(1.0 / 0.5)
    assert m['max_tilt_rate']['rear'] == 2.5


def test_saturation_fraction_duty_and_infeasible_fraction() -> None:
    log = _log(1.0)                                              # 20 ticks
    log.thrust_cmd[0] = [40.0, 0, 0, 0]                          # at the limit
    log.thrust_cmd[1] = [0, -40.0 * (1 - 1e-12), 0, 0]           # within the tolerance
    log.thrust_cmd[2] = [0, 0, 39.99, 0]                         # below
    log.thrust_cmd[3] = [40.0, 0, 0, -40.0]                      # two at once: one tick
    # Wrench misses: 3-4-5 on 5 ticks; a rounding-size miss on one (feasible).
    log.wrench_cmd[:5] = [3.0, 4.0, 0, 0, 0, 0]
    log.wrench_cmd[5] = [10.0, 0, 0, 0, 0, 0]
    log.wrench_achieved[5] = [10.0 + 1e-9, 0, 0, 0, 0, 0]
    m = compute_metrics(log)
    assert m['thrust_saturation_fraction'] == pytest.approx(3 / 20)
    assert m['saturation_duty'] == pytest.approx({'thruster_1': 2 / 20, 'thruster_2': 1 / 20,
                                                  'thruster_3': 0.0, 'thruster_4': 1 / 20})
    assert m['wrench_error_rms'] == pytest.approx(math.sqrt((5 * 25.0 + 1e-18) / 20))
    assert m['infeasible_fraction'] == pytest.approx(5 / 20)
    # Without a thrust limit the saturation and feasibility keys are null, not guesses.
    m = compute_metrics(_log(1.0, max_thrust=None))
    assert m['thrust_saturation_fraction'] is None and m['infeasible_fraction'] is None
    assert compute_metrics(log, max_thrust=39.0)['thrust_saturation_fraction'] == 4 / 20


def test_settling_time() -> None:
    log = _log(30.0)
    # pitch: ramp 0 -> -30 deg (span 30 deg: band 0.6 deg); error 2 deg until 5 s,
    # 0.3 deg after: settled at 5 s.
    pitch_d = np.where(log.tc < 10.0, -3.0 * log.tc, -30.0) * DEG
    pitch_err = np.where(log.tc < 5.0, 2.0, 0.3) * DEG
    for k in range(len(log.tc)):
        log.setpoint_quaternion[k] = quat_from_euler(0.0, pitch_d[k], 0.0)
    idx = np.arange(0, len(log.t), 5)
    for k, i in enumerate(idx[:-1]):
        log.quaternion[i] = quat_from_euler(0.0, pitch_d[k] - pitch_err[k], 0.0)
    # x: leaves its 10 mm band at the very end: not settled. y: never leaves: 0.
    log.setpoint_position[-1, 0] = 0.02
    # z: out of band until 25.5 s, in band for the last 4.45 s only (< 5 s): not settled;
    # roll: the same until 24.9 s (in band for 5.05 s): settled.
    log.setpoint_position[:, 2] = np.where(log.tc < 25.5, 0.02, 0.0)
    roll_d = np.where(log.tc < 24.9, 1.0, 0.0) * DEG
    for k in range(len(log.tc)):
        log.setpoint_quaternion[k] = quat_from_euler(roll_d[k], pitch_d[k], 0.0)
    m = compute_metrics(log)
    assert m['settling_band']['pitch'] == pytest.approx(0.02 * 30 * DEG)
    assert m['settling_band']['x'] == pytest.approx(SETTLING_FLOOR[0])
    assert m['settling_time']['pitch'] == pytest.approx(5.0)
    assert m['settling_time']['x'] is None
    assert m['settling_time']['y'] == 0.0
    assert m['settling_time']['z'] is None
    assert m['settling_time']['roll'] == pytest.approx(24.9)


def test_oscillation_over_the_last_20_seconds() -> None:
    log = _log(40.0)
    # x: a 1 Hz oscillation of 10 mm amplitude from 20 s on (before: a 1 m offset);
    # z: a constant 5 cm offset (not an oscillation).
    late = log.tc >= 20.0
    log.setpoint_position[:, 0] = np.where(late, 0.01 * np.sin(2 * np.pi * log.tc + 0.3), 1.0)
    log.setpoint_position[:, 2] = 0.05
    m = compute_metrics(log)
    assert m['oscillation_std']['x'] == pytest.approx(0.01 / math.sqrt(2), rel=1e-3)
    assert m['oscillation_peak_to_peak']['x'] == pytest.approx(0.02, rel=1e-2)
    assert m['oscillation_std']['z'] == pytest.approx(0.0, abs=1e-15)
    assert m['oscillation_peak_to_peak']['z'] == 0.0


def test_thrust_energy_proxy() -> None:
    log = _log(2.0)
    log.thrust[:] = [10.0, -10.0, 10.0, -10.0]
    # sum_i |f_i|^1.5 = 4 * 10^1.5 N^1.5, held over 2 s.
    assert compute_metrics(log)['thrust_energy_proxy'] == pytest.approx(4 * 10**1.5 * 2.0)


def test_missing_odometry_samples_are_counted_not_guessed() -> None:
    log = _log(1.0)
    keep = np.ones(len(log.t), dtype=bool)
    keep[[10, 15]] = False                      # ticks at 0.10 s and 0.15 s lose their odom
    plant = {name: getattr(log, name)[keep] for name in
             ('t', 'position', 'quaternion', 'nu', 'tilt_position', 'tilt_velocity', 'thrust')}
    control = {name: getattr(log, name) for name in
               ('tc', 'setpoint_position', 'setpoint_quaternion', 'setpoint_velocity',
                'wrench_cmd', 'thrust_cmd', 'tilt_cmd', 'wrench_achieved')}
    m = compute_metrics(RunLog(**plant, **control, meta=log.meta))
    assert (m['ticks'], m['unmatched_ticks']) == (18, 2)


def test_empty_log_gives_nulls_and_valid_json(tmp_path: Path) -> None:
    m = compute_metrics(RunLog.empty({'max_thrust': 40.0}))
    assert m['rms_error']['x'] is None and m['wrench_error_rms'] is None
    assert m['ticks'] == 0
    path = write_metrics(m, tmp_path / 'metrics.json')
    assert json.loads(path.read_text())['final_error']['yaw'] is None


def test_interfaces_keys_and_json(tmp_path: Path) -> None:
    m = compute_metrics(_log(1.0))
    dofs = ['x', 'y', 'z', 'roll', 'pitch', 'yaw']
    assert list(m['rms_error']) == dofs and list(m['final_error']) == dofs
    assert list(m['max_tilt_rate']) == ['front', 'rear']
    assert isinstance(m['thrust_saturation_fraction'], float)
    assert isinstance(m['wrench_error_rms'], float)
    assert m['run'] == {'scenario': 'synthetic', 'controller': 'pd', 'allocator_mode': 'robust',
                        'backend': None}
    assert json.loads(write_metrics(m, tmp_path / 'm.json').read_text()) == m


# --------------------------------------------------------------------------- with the runner


class Recording:
    """Wraps a controller and keeps the error it computed at each tick."""

    def __init__(self, inner) -> None:
        self.inner = inner
        self.errors: list[np.ndarray] = []

    def update(self, t, position, quaternion, nu, reference):
        self.errors.append(tracking_error(position, quaternion, nu, reference).e)
        return self.inner.update(t, position, quaternion, nu, reference)


def test_errors_are_those_the_controller_saw_and_npz_round_trip_agrees(tmp_path: Path) -> None:
    config = stack_config('pitch_hold_slow_servo', 'pid')
    controller = Recording(make_controller(config.controller, config.robot))
    log = run(config.build_plant(), controller, config.build_allocator(),
              config.scenario.reference.at, 3.0, control_period_ns=config.control_period_ns,
              meta=config.describe())
    np.testing.assert_allclose(control_errors(log).e, np.array(controller.errors),
                               rtol=0, atol=1e-12)
    m = compute_metrics(log)
    assert m['infeasible_fraction'] * m['ticks'] == pytest.approx(log.meta['infeasible_ticks'])
    assert m['max_tilt_rate']['front'] <= config.robot.tilt_rate_limit * (1 + 1e-12)
    # A RunLog read back (as tiltrov analyze reads one from a bag) gives the same numbers.
    log.save_npz(tmp_path / 'run.npz')
    assert compute_metrics(RunLog.load_npz(tmp_path / 'run.npz')) == m


def test_metric_differences_names_each_difference_and_nothing_else() -> None:
    base = {'ticks': 10, 'run': {'controller': 'pd'}, 'rms_error': {'x': 0.5, 'y': None}}
    assert metric_differences(base, json.loads(json.dumps(base))) == []
    near = {'ticks': 10, 'run': {'controller': 'pd'}, 'rms_error': {'x': 0.5 + 1e-12, 'y': None}}
    assert metric_differences(near, base) == []
    far = {'ticks': 11, 'run': {'controller': 'pid'}, 'rms_error': {'x': 0.6, 'y': 0.0}}
    assert metric_differences(far, base) == [
        'metrics.ticks: 11 != 10', "metrics.run.controller: 'pid' != 'pd'",
        'metrics.rms_error.x: 0.6 != 0.5', 'metrics.rms_error.y: float 0.0 != NoneType None']
    assert metric_differences({'b': 1, 'a': 2}, {'a': 2, 'b': 1}) == [
        "metrics: keys ['b', 'a'] != ['a', 'b']"]
    assert metric_differences({'x': 0.6}, {'x': 0.5}, rtol=0.25) == []
