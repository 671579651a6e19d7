"""``tiltrov launch`` as a user runs it: real processes, dying nodes, Ctrl-C, recording,
respawn."""

from __future__ import annotations

import os
from pathlib import Path
import re
import signal
import sys
from typing import Any

from harness import run_while_progressing
import numpy as np
import pytest
from ros_stack import (
    HANG_BOUND,
    MS,
    NS,
    assert_same_run,
    ended_by,
    joined_sim_time,
    kill_now,
    killed_in_run,
)
from ros_stack import LaunchProcess as _Launch
from ros_stack import alive as _alive
from ros_stack import ready as _ready

from tiltrov_ros.core.runner import run_scenario, stack_config
from tiltrov_ros.stack.specs import LaunchOptions

NODES = ('thrust_allocator', 'wrench_controller', 'reference_publisher', 'plant_simulator')


# --------------------------------------------------------------------------- processes


def _tiltrov(*args: str) -> list[str]:
    return [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', *args]


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_launch_runs_separate_processes_to_the_end(tmp_path: Path) -> None:
    result = run_while_progressing(_tiltrov('--scenario', 'pitch_hold', '--duration', '2'),
                                   cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    lines = result.stdout.splitlines()
    for name in NODES:
        assert any(line.startswith(f'[{name}]') for line in lines), name
        assert any(line.startswith('[launch]') and f'started {name} (pid' in line
                   for line in lines)
    assert any('reached the end of the run at 2.000 s' in line for line in lines)
    assert any(line.startswith('[launch]') and 'done in' in line for line in lines)


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_node_failing_at_start_stops_the_launch(tmp_path: Path) -> None:
    # 1 where 1.0 is declared: the controller refuses to start.
    result = run_while_progressing(
        _tiltrov('--duration', '2', '--param', 'wrench_controller:switching.dwell_time:=1'),
        cwd=tmp_path)
    assert result.returncode == 1
    assert 'wrench_controller died (exit code 1)' in result.stdout
    assert 'switching.dwell_time' in result.stdout
    assert 'wrench_controller' in result.stderr


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_node_dying_mid_run_stops_the_others(ros: Any, tmp_path: Path) -> None:
    launch = _Launch(tmp_path, '--realtime', '--duration', '600')
    try:
        pids = launch.wait_running()
        assert set(pids) == set(NODES)
        _ready(ros, NODES, launch)
        os.kill(pids['wrench_controller'], signal.SIGKILL)
        assert launch.finish() == 1
        out = launch.output
        assert f'wrench_controller died (exit code {-signal.SIGKILL})' in out
        assert not any(_alive(pid) for pid in pids.values())
        assert launch.status()['state'] == 'ended' and launch.status()['exit_code'] == 1
    finally:
        launch.cleanup()


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_dying_standby_stops_the_launch(tmp_path: Path) -> None:
    """A standby is a node of the run's handshake (the run waits for it): its death ends
    the launch as a node's does, naming it, and every process stops."""
    launch = _Launch(tmp_path, '--realtime', '--duration', '600',
                     '--respawn', 'wrench_controller')
    try:
        pids = launch.wait_running()
        assert set(pids) == {*NODES, 'wrench_controller_standby'}
        os.kill(pids['wrench_controller_standby'], signal.SIGKILL)
        assert launch.finish() == 1, launch.output
        assert (f'wrench_controller_standby died (exit code {-signal.SIGKILL}); stopping '
                'the other nodes') in launch.output
        assert not any(_alive(pid) for pid in pids.values())
    finally:
        launch.cleanup()


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_ctrl_c_stops_every_node_cleanly(ros: Any, tmp_path: Path) -> None:
    """Ctrl-C of a recorded realtime launch: every node stops cleanly, the recorder once it
    has every node's final report, and the bag is closed, readable and loses nothing."""
    from tiltrov_ros.bag.losses import losses

    bag = tmp_path / 'bag'
    launch = _Launch(tmp_path, '--realtime', '--duration', '600', '--record', str(bag))
    try:
        pids = launch.wait_running()
        _ready(ros, (*NODES, 'bag_recorder'), launch)
        launch.process.send_signal(signal.SIGINT)
        assert launch.finish() == 130, launch.output
        out = launch.output
        assert 'SIGINT: stopping every node' in out
        assert 'SIGTERM' not in out and 'SIGKILL' not in out     # SIGINT was enough
        assert not any(_alive(pid) for pid in pids.values())
    finally:
        launch.cleanup()
    assert not losses(bag), losses(bag).lines()


@pytest.mark.slow
@pytest.mark.parametrize('single_process', [False, True])
@pytest.mark.timeout(HANG_BOUND)
def test_record_gives_a_bag_equal_to_the_headless_run(tmp_path: Path,
                                                      single_process: bool) -> None:
    from tiltrov_ros.bag.reader import read_runlog

    bag = tmp_path / 'bag'
    args = ['--scenario', 'trajectory', '--controller', 'switching', '--duration', '2',
            '--record', str(bag), '--namespace', 'r1']
    result = run_while_progressing(
        _tiltrov(*args, *(['--single-process'] if single_process else [])), cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    recorded = read_runlog(bag, namespace='/r1')
    expected = run_scenario(stack_config('trajectory', 'switching'), duration=2.0)
    assert_same_run(recorded, expected)


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_recorded_run_starts_on_the_handshake_with_one_message_per_step_and_tick(
        tmp_path: Path) -> None:
    """The plant publishes t = 0 once every node of the run (the recorder included) has
    matched every other, seen from both sides: nothing is published twice, nothing is
    lost, whatever the order and speed of the nodes' starts."""
    from tiltrov_ros.bag.bagfile import bag_info
    from tiltrov_ros.bag.losses import final_diagnostics

    bag = tmp_path / 'bag'
    result = run_while_progressing(_tiltrov('--duration', '2', '--record', str(bag)),
                                   cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.count('every node of the run is ready') == 1, result.stdout
    counts = {name: topic.count for name, topic in bag_info(bag).topics.items()}
    plant = final_diagnostics(bag)[0]['/plant_simulator']
    assert plant['republished_states'] == '0', plant      # (a slow tick may be a stall)
    for topic in ('/odom', '/joint_states', '/clock'):
        assert counts[topic] == 201, counts
    for topic in ('/setpoint', '/setpoint_velocity', '/wrench_cmd', '/thrust_cmd',
                  '/tilt_cmd', '/wrench_achieved'):
        assert counts[topic] == 40, counts
    assert '/handshake' not in counts and '/recorder_progress' not in counts


def _seeded_moments(seed: int, count: int) -> tuple[float, ...]:
    """``count`` kill moments (s of sim time) drawn with ``seed`` over 5-100 s."""
    return tuple(sorted(float(t) for t in np.random.default_rng(seed).uniform(5, 100, count)))


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
@pytest.mark.parametrize(('victims', 'kill_at', 'duration'), [
    (('thrust_allocator',), _seeded_moments(3, 1), 120.0),
    (('wrench_controller', 'thrust_allocator'), _seeded_moments(11, 2), 120.0),
    # At the run's first ticks: the run started only once both standbys kept the handoff.
    (('wrench_controller', 'thrust_allocator'), (0.2, 0.2), 10.0),
], ids=['allocator-seed3', 'both-seed11', 'both-first-ticks'])
def test_killed_nodes_are_taken_over_bit_for_bit(ros: Any, tmp_path: Path,
                                                 victims: tuple[str, ...],
                                                 kill_at: tuple[float, ...],
                                                 duration: float) -> None:
    """kill -9 of the allocator (and the controller) at seeded random moments of a
    recorded 120 s lockstep pid run with --respawn, or at its first ticks: each one's
    standby (a node of the run's handshake, so the run started only once it had matched
    the handoff's writers) takes over with the state its predecessor handed over (the
    pid's integral, the allocator's last answer and servo travel), joins the run's
    handshake, and the plant publishes the waited tick again once every node has
    matched it. The run ends normally and the bag is the headless run without kills to
    the last bit, every step and tick in it (the plant used no command before the bag
    had it). A try whose kills came after the run had ended is made again, longer
    (``killed_in_run``)."""
    from tiltrov_ros.bag.losses import missing_stamps
    from tiltrov_ros.bag.reader import read_runlog

    run_dir, duration, out = killed_in_run(
        tmp_path, duration,
        lambda run_dir, length, probe: _killed_run(ros, run_dir, victims, kill_at, length,
                                                   probe))
    for victim in victims:
        assert f'{victim} died (exit code {-signal.SIGKILL}); its standby' in out, out
        kept = re.search(rf'{victim}: taking over \((\d+) handoff messages kept\)', out)
        assert kept is not None and int(kept[1]) > 0, out
    # One resume per kill moment (kills at one moment may be resumed from together).
    assert len(set(kill_at)) <= out.count('every node of the run is ready again') \
        <= len(victims), out
    assert 'resumed from its predecessor' in out or 'resumed the pid' in out
    assert 'not bumpless' not in out and 'starts from zero' not in out, out
    bag = run_dir / 'bag'
    assert missing_stamps(bag, int(duration * NS), 10 * MS, 50 * MS) == {}
    assert_same_run(read_runlog(bag), run_scenario(stack_config('current_hold', 'pid'),
                                                   duration=duration), atol=0.0)


def _killed_run(ros: Any, run_dir: Path, victims: tuple[str, ...],
                kill_at: tuple[float, ...], duration: float, probe: str) -> str | None:
    """One recorded lockstep ``tiltrov launch`` with ``victims`` respawned, each killed
    once the probe (a node of the run, so the run waits for it at the start) has seen
    ``kill_at``: the launch's output, or None when the plant had reached the run's end
    before the last victim was dead."""
    bag = run_dir / 'bag'
    respawn = [arg for v in victims for arg in ('--respawn', v)]
    sim = joined_sim_time(ros, LaunchOptions(record=bag, respawn=victims, join=(probe,)),
                          probe)
    launch = _Launch(run_dir, '--scenario', 'current_hold', '--controller', 'pid',
                     '--duration', str(duration), '--record', str(bag), *respawn,
                     '--join', probe)
    dead = 0.0
    try:
        launch.wait_running()

        def progress() -> tuple[int, tuple[int, int]]:   # sim time, or the launch moving
            return sim.ns, launch.progress()

        for victim, at in zip(victims, kill_at):
            assert ros.spin_while_progressing(lambda at=at: sim.reached(at), progress), \
                launch.output
            dead = kill_now(launch.pids()[victim])
        assert ros.spin_while_progressing(lambda: launch.process.poll() is not None,
                                          progress), launch.output
        code = launch.finish()
        if ended_by(launch.output, dead):
            return None
        assert code == 0, launch.output
    finally:
        launch.cleanup()
    return launch.output
