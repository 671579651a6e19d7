"""``tiltrov replay BAG --through allocator``: the recorded wrenches through the allocator
again, offline, compared with what was recorded."""

from __future__ import annotations

from functools import cache
import json
import math
from pathlib import Path
import sys

from harness import run_while_progressing
import numpy as np
import pytest

from tiltrov_ros import cli
from tiltrov_ros.analysis.reallocate import AllocatorSettings, compare, read_control
from tiltrov_ros.bag.bagfile import RUN_INFO_KEY
from tiltrov_ros.bag.export import _Messages, write_runlog_bag
from tiltrov_ros.bag.writer import BagWriter
from tiltrov_ros.core.allocation import (
    BatchResult,
    ThrustAllocator,
    allocate_sequence,
    load_allocator_config,
)
from tiltrov_ros.core.metrics import compute_metrics
from tiltrov_ros.core.params import load_robot_params
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.runner import run_scenario, stack_config


@cache
def headless(controller: str = 'pd', duration: float = 2.0) -> RunLog:
    return run_scenario(stack_config('pitch_hold', controller), duration=duration)


def replay_through(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = cli.main(['replay', *args])
    out, err = capsys.readouterr()
    return code, out, err


def shipped(mode: str) -> ThrustAllocator:
    """The shipped robot's allocator in ``mode``, built here by hand."""
    robot = load_robot_params()
    return ThrustAllocator(robot.length, robot.width, robot.max_thrust,
                           (robot.tilt_min, robot.tilt_max), robot.tilt_rate_limit * 0.05,
                           mode, load_allocator_config().weights)


def test_recorded_robust_run_is_reproduced_and_compared_with_paper(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    log = headless()
    bag = write_runlog_bag(log, tmp_path / 'bag')
    out = tmp_path / 'out'
    code, stdout, err = replay_through(capsys, str(bag), '--through', 'allocator', '--out',
                                       str(out))
    assert code == 0, err
    summary = json.loads((out / 'allocation.json').read_text())
    n = len(log.tc)
    assert summary['ticks'] == n and summary['tilt_requests'] is False
    assert summary['run'] == {'scenario': 'pitch_hold', 'controller': 'pd',
                              'allocator_mode': 'robust'}
    assert summary['reproduction'] == {'mode': 'robust', 'ticks': n,
                                       'max_thrust_difference': 0.0,
                                       'max_tilt_difference': 0.0, 'reproduced': True}
    assert 'recorded vs robust re-run' in stdout and '(reproduced)' in stdout
    allocations = summary['allocations']
    assert allocations['robust'] == allocations['recorded']

    # The recorded allocation's numbers, computed here from the RunLog.
    weights = np.array(load_allocator_config().weights)
    rec = allocations['recorded']
    err_w = np.linalg.norm((log.wrench_achieved - log.wrench_cmd) * weights, axis=1)
    assert rec['rms_weighted_wrench_error'] == pytest.approx(
        math.sqrt(np.mean(err_w**2)), rel=1e-6, abs=1e-12)
    metrics = compute_metrics(log)
    assert rec['wrench_error_rms'] == pytest.approx(metrics['wrench_error_rms'], rel=1e-6,
                                                    abs=1e-12)
    assert rec['infeasible_fraction'] == metrics['infeasible_fraction']
    assert rec['thrust_saturation_fraction'] == metrics['thrust_saturation_fraction']
    steps = np.abs(np.diff(log.tilt_cmd, axis=0))
    assert rec['servo_travel'] == pytest.approx(dict(zip(('front', 'rear'), steps.sum(axis=0))))
    assert rec['max_tilt_step'] == pytest.approx(dict(zip(('front', 'rear'), steps.max(axis=0))))
    assert max(rec['max_tilt_step'].values()) <= summary['allocator']['max_tilt_step'] + 1e-12

    # The paper mode re-run: the shipped allocator in paper mode, previous chained.
    paper = BatchResult.stack(allocate_sequence(shipped('paper'), log.wrench_cmd))
    table = np.loadtxt(out / 'allocation.csv', delimiter=',', skiprows=1)
    header = (out / 'allocation.csv').read_text().splitlines()[0].split(',')
    col = {name: i for i, name in enumerate(header)}
    np.testing.assert_allclose(table[:, col['paper_tilt_front [rad]']], paper.tilt_front,
                               rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(table[:, [col[f'paper_thrust_{i} [N]'] for i in range(1, 5)]],
                               paper.thrusts, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(table[:, col['t [s]']], log.tc)
    assert allocations['paper']['infeasible_fraction'] == pytest.approx(
        float(np.mean(~paper.feasible)))
    assert (out / 'allocation.png').stat().st_size > 0


def test_limits_come_from_run_info_else_from_the_shipped_config(tmp_path: Path) -> None:
    robot = load_robot_params()
    settings = AllocatorSettings.from_run_info({})
    assert set(settings.sources.values()) == {'config'}
    assert settings.robot.max_thrust == robot.max_thrust
    assert settings.max_tilt_step == pytest.approx(robot.tilt_rate_limit * 0.05)

    info = {'max_thrust': 25.0, 'tilt_min': -1.0, 'tilt_max': 1.2, 'tilt_rate_limit': 1.0,
            'control_period': 0.1, 'max_tilt_step': 0.02}
    settings = AllocatorSettings.from_run_info(info)
    assert set(settings.sources.values()) == {'run_info'}
    alloc = settings.build('robust')
    assert (alloc.max_thrust, alloc.tilt_limits, alloc.max_tilt_step) == (25.0, (-1.0, 1.2),
                                                                          0.02)
    assert (alloc.length, alloc.width) == (robot.length, robot.width)
    # Without max_tilt_step, the servo reach of the recorded rate and period.
    settings = AllocatorSettings.from_run_info({'tilt_rate_limit': 1.0, 'control_period': 0.1})
    assert settings.max_tilt_step == pytest.approx(0.1)
    assert settings.sources['max_tilt_step'] == 'config'

    log = headless()
    bag = write_runlog_bag(log, tmp_path / 'bag', run_info={**log.meta, **info})
    comparison = compare(read_control(bag))
    steps = np.abs(np.diff(comparison.tilts['robust'], axis=0))
    assert steps.max() <= 0.02 + 1e-12
    assert np.abs(comparison.thrusts['paper']).max() <= 25.0
    assert comparison.summary['reproduction']['reproduced'] is False


def test_tilt_requests_hold_the_tilts_as_the_node_holds_them(tmp_path: Path) -> None:
    """A switching run's tilt_request: the one with the tick's stamp, else the latest."""
    m = _Messages()
    store = m.store
    wrenches = np.array([[10.0, 0, -20, 0, 1, 0], [12.0, 1, -18, 0, 1, 0],
                         [8.0, 0, -25, 0.5, 0, 0], [9.0, -1, -22, 0, 2, 0]])
    tick = 50_000_000
    requests = {0: (0.0, 0.0), 2 * tick: (math.pi / 2, math.pi / 2)}   # none at ticks 1, 3
    with BagWriter(tmp_path / 'bag', custom_data={RUN_INFO_KEY: json.dumps(
            {'controller': 'switching', 'allocator_mode': 'robust'})}) as bag:
        w = bag.add_topic('/rov/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
        r = bag.add_topic('/rov/tilt_request', 'sensor_msgs/msg/JointState')
        for k, wrench in enumerate(wrenches):
            bag.write(w, k * tick, store.serialize_cdr(m.wrench(k * tick, wrench),
                                                       'geometry_msgs/msg/WrenchStamped'))
            if k * tick in requests:
                bag.write(r, k * tick, store.serialize_cdr(
                    m.joints(k * tick, ('tilt_front', 'tilt_rear'),
                             position=requests[k * tick]), 'sensor_msgs/msg/JointState'))
    control = read_control(tmp_path / 'bag')
    assert control.namespace == '/rov'
    expected_requests = [requests[0], requests[0], requests[2 * tick], requests[2 * tick]]
    np.testing.assert_array_equal(control.tilt_request, expected_requests)
    assert np.isnan(control.thrust_cmd).all()        # nothing recorded to compare with
    comparison = compare(control)
    for mode in ('paper', 'robust'):
        expected = allocate_sequence(shipped(mode), wrenches, np.array(expected_requests))
        np.testing.assert_array_equal(comparison.tilts[mode], [r.tilts for r in expected])
        np.testing.assert_array_equal(comparison.thrusts[mode], [r.thrusts for r in expected])
    assert comparison.summary['tilt_requests'] is True
    assert comparison.summary['allocations']['recorded']['ticks'] == 0
    assert comparison.summary['allocations']['recorded']['missing_ticks'] == 4


@pytest.mark.parametrize(('args', 'code', 'message'), [
    (['--through', 'allocator', '--rate', '2'], 2,
     'tiltrov replay: error: --through allocator replays offline; --rate do not apply'),
    (['--through', 'allocator', '--namespace', 'nobody'], 2,
     'tiltrov replay: error: {bag} has no /nobody/wrench_cmd messages'),
])
def test_bad_options(tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str],
                     code: int, message: str) -> None:
    bag = write_runlog_bag(headless(), tmp_path / 'bag')
    result, _, err = replay_through(capsys, str(bag), *args, '--out', str(tmp_path / 'o'))
    assert result == code
    assert err.splitlines() == [message.format(bag=bag)]


def test_bad_bags_and_out_without_through(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = replay_through(capsys, str(tmp_path / 'none'), '--through', 'allocator')
    assert code == 2 and err.splitlines() == [f'tiltrov replay: error: no bag at '
                                              f'{tmp_path / "none"}']
    with BagWriter(tmp_path / 'odom_only') as bag:
        bag.add_topic('/odom', 'nav_msgs/msg/Odometry')
    code, _, err = replay_through(capsys, str(tmp_path / 'odom_only'), '--through',
                                  'allocator')
    assert code == 2 and err.splitlines() == [
        'tiltrov replay: error: the bag has no wrench_cmd topic '
        '(geometry_msgs/msg/WrenchStamped)']
    code, out, _ = replay_through(capsys, str(tmp_path / 'odom_only'), '--out', 'x')
    assert code == 1 and out.strip() == 'tiltrov replay: --out needs --through'


def test_through_allocator_needs_no_ros(tmp_path: Path) -> None:
    bag = write_runlog_bag(headless(), tmp_path / 'bag')
    script = ('import sys; from tiltrov_ros import cli; '
              f'code = cli.main(["replay", {str(bag)!r}, "--through", "allocator", '
              f'"--no-figures", "--out", {str(tmp_path / "out")!r}]); '
              'assert code == 0, code; '
              'assert not [m for m in sys.modules if m.startswith(("rclpy", "rosgraph_msgs"))]')
    result = run_while_progressing([sys.executable, '-c', script])
    assert result.returncode == 0, result.stderr
    assert (tmp_path / 'out' / 'allocation.json').is_file()
    assert not (tmp_path / 'out' / 'allocation.png').exists()
