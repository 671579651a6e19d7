"""``tiltrov launch`` as a user runs it: real processes, dying nodes, Ctrl-C, recording,
respawn."""

from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from ros_stack import MS

from tiltrov_ros.core.runner import run_scenario, stack_config

NODES = ('thrust_allocator', 'wrench_controller', 'reference_publisher', 'plant_simulator')


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
