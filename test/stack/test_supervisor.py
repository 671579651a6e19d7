"""``tiltrov launch``: the node specifications, real processes, dying nodes, Ctrl-C."""

from __future__ import annotations

import io
import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from ros_stack import MS, Probe
import yaml

from tiltrov_ros.core.runner import run_scenario, stack_config
from tiltrov_ros.stack import supervisor as launcher
from tiltrov_ros.stack.supervisor import LaunchError, LaunchOptions, stack_specs

NODES = ('thrust_allocator', 'wrench_controller', 'reference_publisher', 'plant_simulator')


def _spec(specs, name):
    return next(s for s in specs if s.name == name)


# --------------------------------------------------------------------------- specifications


def test_specs_carry_mode_scenario_duration_and_robot_overrides() -> None:
    specs, config, duration = stack_specs(LaunchOptions(scenario='pitch_hold_slow_servo',
                                                        controller='switching'))
    assert [s.name for s in specs] == list(NODES)
    assert duration == 60.0 and config.controller.kind == 'switching'
    plant = _spec(specs, 'plant_simulator').overrides
    assert (plant['mode'], plant['scenario'], plant['duration'], plant['exit_at_end']) == (
        'lockstep', 'pitch_hold_slow_servo', 60.0, True)
    assert _spec(specs, 'thrust_allocator').overrides['tilt_request'] == 'required'
    assert _spec(specs, 'wrench_controller').overrides['controller'] == 'switching'
    for spec in specs:   # the scenario's robot override reaches every node
        assert spec.overrides['robot.tilt_rate_limit'] == config.robot.tilt_rate_limit
        assert [p.name for p in spec.params_files] == ['robot.yaml', f'{spec.name}.yaml']
        if spec.name != 'plant_simulator':
            assert spec.overrides['use_sim_time'] is True

    specs, _, _ = stack_specs(LaunchOptions(controller='pd', allocator='paper', duration=2.0,
                                            lockstep=False, real_time_factor=5.0))
    assert _spec(specs, 'thrust_allocator').overrides['tilt_request'] == 'ignored'
    assert _spec(specs, 'thrust_allocator').overrides['mode'] == 'paper'
    assert _spec(specs, 'plant_simulator').overrides['real_time_factor'] == 5.0
    assert _spec(specs, 'wrench_controller').overrides['mode'] == 'realtime'


def test_scenario_file_paths_are_resolved(tmp_path: Path, repo_root: Path) -> None:
    scenario = tmp_path / 'mine.yaml'
    scenario.write_text((repo_root / 'config/scenarios/pitch_hold.yaml').read_text())
    specs, _config, _ = stack_specs(LaunchOptions(scenario=str(scenario)))
    assert _spec(specs, 'plant_simulator').overrides['scenario'] == str(scenario)
    assert _spec(specs, 'reference_publisher').overrides['scenario'] == str(scenario)


@pytest.mark.parametrize(('options', 'message'), [
    (LaunchOptions(duration=0.015), 'whole number'),
    (LaunchOptions(params=('wrench_controller:gains.kp',)), 'NODE:NAME:=VALUE'),
    (LaunchOptions(params=('nobody:x:=1',)), 'unknown node'),
])
def test_bad_options_are_refused_before_anything_starts(options, message) -> None:
    with pytest.raises(LaunchError, match=message):
        stack_specs(options)


def test_overrides_file_is_keyed_by_the_full_node_name(tmp_path: Path) -> None:
    specs, _, _ = stack_specs(LaunchOptions(
        duration=1.0, params=('wrench_controller:gains.kp:=[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]',
                              "wrench_controller:input_timeout:=2.5")))
    spec = _spec(specs, 'wrench_controller')
    document = yaml.safe_load(spec.write_overrides(tmp_path, '/robot1').read_text())
    values = document['/robot1/wrench_controller']['ros__parameters']
    assert values['gains.kp'] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert values['input_timeout'] == 2.5 and values['mode'] == 'lockstep'
    args = spec.ros_args(tmp_path / 'x.yaml', '/robot1')
    assert args[:3] == ['--ros-args', '-r', '__ns:=/robot1']
    assert args[-2:] == ['--params-file', str(tmp_path / 'x.yaml')]


def test_namespaced_config_renames_node_sections(tmp_path: Path) -> None:
    specs, _, _ = stack_specs(LaunchOptions(duration=1.0))
    launcher.namespaced_config(specs, '/robot1', tmp_path)
    controller = yaml.safe_load((tmp_path / 'wrench_controller.yaml').read_text())
    assert list(controller) == ['/robot1/wrench_controller']
    robot = yaml.safe_load((tmp_path / 'robot.yaml').read_text())
    assert list(robot) == ['/**']


def test_record_starts_the_recorder_first(tmp_path: Path) -> None:
    options = LaunchOptions(duration=1.0, record=tmp_path / 'bag')
    specs, _, _ = stack_specs(options)
    recorder = specs[0]
    assert recorder.name == 'bag_recorder'
    assert recorder.overrides['use_sim_time'] is True
    # The plant waits for the recorder too before it starts the run.
    assert _spec(specs, 'plant_simulator').overrides['startup_subscribers'] == 2


# --------------------------------------------------------------------------- processes


def _tiltrov(*args: str) -> list[str]:
    return [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', *args]


@pytest.mark.slow
def test_launch_runs_separate_processes_to_the_end(tmp_path: Path) -> None:
    result = subprocess.run(_tiltrov('--scenario', 'pitch_hold', '--duration', '2'),
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    for name in NODES:
        assert any(line.startswith(f'[{name}]') for line in lines), name
        assert any(line.startswith('[launch]') and f'started {name} (pid' in line
                   for line in lines)
    assert any('reached the end of the run at 2.000 s' in line for line in lines)
    assert any(line.startswith('[launch]') and 'done in' in line for line in lines)


@pytest.mark.slow
def test_a_node_failing_at_start_stops_the_launch(tmp_path: Path) -> None:
    # 1 where 1.0 is declared: the controller refuses to start.
    result = subprocess.run(_tiltrov('--duration', '2',
                                     '--param', 'wrench_controller:switching.dwell_time:=1'),
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 1
    assert 'wrench_controller died (exit code 1)' in result.stdout
    assert 'switching.dwell_time' in result.stdout
    assert 'wrench_controller' in result.stderr


def _start(tmp_path: Path, *args: str) -> tuple[subprocess.Popen[str], dict[str, int]]:
    process = subprocess.Popen(_tiltrov(*args), stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    pids: dict[str, int] = {}
    assert process.stdout is not None
    for line in process.stdout:
        if line.startswith('[launch]') and 'started ' in line:
            name = line.split('started ')[1].split()[0]
            pids[name] = int(line.rsplit('pid ', 1)[1].rstrip(')\n'))
        if line.startswith('[plant_simulator]') and 'realtime' in line:
            break
    return process, pids


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _cleanup(process: subprocess.Popen[str], pids: dict[str, int]) -> None:
    """Whatever a failed test left running: the launcher and the nodes it started."""
    if process.poll() is None:
        process.kill()
        process.wait(timeout=10)
    for pid in pids.values():
        if _alive(pid):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_a_node_dying_mid_run_stops_the_others(tmp_path: Path) -> None:
    process, pids = _start(tmp_path, '--realtime', '--duration', '600')
    try:
        assert set(pids) == set(NODES)
        os.kill(pids['wrench_controller'], signal.SIGKILL)
        out, _ = process.communicate(timeout=60)
        assert process.returncode == 1
        assert f'wrench_controller died (exit code {-signal.SIGKILL})' in out
        assert not any(_alive(pid) for pid in pids.values())
    finally:
        _cleanup(process, pids)


@pytest.mark.slow
def test_ctrl_c_stops_every_node_cleanly(tmp_path: Path) -> None:
    process, pids = _start(tmp_path, '--realtime', '--duration', '600')
    try:
        time.sleep(0.5)
        process.send_signal(signal.SIGINT)
        out, _ = process.communicate(timeout=60)
        assert process.returncode == 130, out
        assert 'SIGINT: stopping every node' in out
        assert 'SIGTERM' not in out and 'SIGKILL' not in out     # SIGINT was enough
        assert not any(_alive(pid) for pid in pids.values())
    finally:
        _cleanup(process, pids)


# --------------------------------------------------------------------------- in process


@pytest.mark.slow
def test_single_process_launch_in_a_namespace(ros) -> None:
    """``--single-process --namespace robot1``: every topic moves under /robot1."""
    probe = Probe(ros.node('ns_probe', namespace='/robot1'), ['odom', 'thrust_cmd'])
    root = Probe(ros.node('root_probe'), ['odom'])
    stream = io.StringIO()
    result: list[int] = []
    options = LaunchOptions(scenario='pitch_hold', duration=1.0, single_process=True,
                            namespace='robot1')
    thread = threading.Thread(target=lambda: result.append(launcher.launch(options, stream)))
    thread.start()
    try:
        ros.spin_until(lambda: not thread.is_alive(), timeout=120.0)
    finally:
        thread.join(timeout=120.0)
    assert result == [0], stream.getvalue()
    assert ros.spin_until(lambda: 100 * 10 * MS in probe.stamps('odom'))
    assert probe.stamps('thrust_cmd')
    assert root['odom'] == []
    assert 'in /robot1' in stream.getvalue()


@pytest.mark.slow
@pytest.mark.parametrize('single_process', [False, True])
def test_record_gives_a_bag_equal_to_the_headless_run(tmp_path: Path,
                                                      single_process: bool) -> None:
    from tiltrov_ros.bag.reader import read_runlog

    bag = tmp_path / 'bag'
    args = ['--scenario', 'trajectory', '--controller', 'switching', '--duration', '2',
            '--record', str(bag), '--namespace', 'r1']
    result = subprocess.run(_tiltrov(*args, *(['--single-process'] if single_process else [])),
                            capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    recorded = read_runlog(bag, namespace='/r1')
    expected = run_scenario(stack_config('trajectory', 'switching'), duration=2.0)
    assert recorded.meta['bag']['missing'] == {}
    for name in ('t', 'position', 'quaternion', 'nu', 'thrust', 'tc', 'wrench_cmd',
                 'thrust_cmd', 'tilt_cmd', 'wrench_achieved'):
        np.testing.assert_allclose(getattr(recorded, name), getattr(expected, name),
                                   rtol=0, atol=1e-9, err_msg=name)


@pytest.mark.slow
@pytest.mark.parametrize('victim', ['thrust_allocator', 'wrench_controller'])
def test_a_killed_node_is_respawned_and_the_loop_resumes(tmp_path: Path, victim: str) -> None:
    """kill -9 of the allocator (or the controller) mid-run (lockstep, recorded,
    --respawn): the plant keeps its state and waits at its tick (a stall,
    re-published), the new process answers it, the run ends normally; the bag has
    every step and tick of every node's topics, the restarted node's included (it
    holds its answers until the recorder reads its topics)."""
    from tiltrov_ros.bag.bagfile import iter_raw
    from tiltrov_ros.bag.cdr import leading_stamp_ns

    bag = tmp_path / 'bag'
    duration = 120.0           # some 8 s wall in lockstep: the kill lands mid-run
    process = subprocess.Popen(
        _tiltrov('--duration', str(duration), '--record', str(bag), '--respawn', victim,
                 '--stall-timeout', '0.5'),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(process.stdout or ()), daemon=True)
    reader.start()
    pids: dict[str, int] = {}
    try:
        deadline = time.monotonic() + 60
        while not any('[plant_simulator]' in line and 'lockstep' in line for line in lines):
            assert time.monotonic() < deadline and process.poll() is None, ''.join(lines)
            time.sleep(0.05)
        time.sleep(3.0)       # the plant is stepping by now (start-up takes about 1 s)
        for line in list(lines):
            if line.startswith('[launch]') and 'started ' in line:
                pids[line.split('started ')[1].split()[0]] = int(
                    line.rsplit('pid ', 1)[1].rstrip(')\n'))
        os.kill(pids[victim], signal.SIGKILL)
        assert process.wait(timeout=120) == 0, ''.join(lines)
    finally:
        _cleanup(process, pids)
    reader.join(timeout=5)
    out = ''.join(lines)
    assert f'{victim} died (exit code {-signal.SIGKILL}); starting it again' in out
    assert out.count(f'started {victim}') == 2
    stalls = [float(line.split('stall at ')[1].split(' s:')[0]) for line in lines
              if 'stall at ' in line]
    assert stalls and 0.0 < stalls[0] < duration, out        # it waited mid-run

    stamps: dict[str, set[int]] = {}
    for raw in iter_raw(bag):
        stamp = leading_stamp_ns(raw.data, raw.msgtype)
        if stamp is not None:
            stamps.setdefault(raw.topic, set()).add(stamp // MS)
    steps = set(range(0, int(duration * 1000) + 1, 10))
    ticks = set(range(0, int(duration * 1000), 50))
    for topic in ('/odom', '/joint_states', '/clock'):
        assert stamps[topic] == steps, topic
    # The new allocator holds its answers until the recorder reads its topics
    # (wait_for_recorder): every tick is recorded on every topic, the killed
    # allocator's own included.
    for topic in ('/setpoint', '/setpoint_velocity', '/wrench_cmd', '/thrust_cmd',
                  '/tilt_cmd', '/wrench_achieved'):
        assert stamps[topic] >= ticks, (topic, sorted(ticks - stamps[topic])[:10])
    assert 'bag_recorder reads every topic of this node' in out
