"""``ros2 launch tiltrov_ros tiltrov.launch.py``: its arguments as docs/launch.md
lists them, a recorded lockstep run giving the headless numbers, Ctrl-C."""

from __future__ import annotations

import os
from pathlib import Path
import re
import signal
from typing import Any

from harness import TreeProgress
import numpy as np
import pytest
from ros2_cli import Ros2, ctrl_c, doc_commands, wait_nodes
from ros_stack import (
    HANG_BOUND,
    assert_same_run,
    ended_by,
    joined_sim_time,
    kill_now,
    killed_in_run,
)

from tiltrov_ros.core.runner import run_scenario, stack_config
from tiltrov_ros.stack.specs import LaunchOptions

REPO = Path(__file__).resolve().parents[2]
LAUNCH = ('launch', 'tiltrov_ros', 'tiltrov.launch.py')
NODES = ('plant_simulator', 'wrench_controller', 'thrust_allocator', 'reference_publisher')


def test_show_args_lists_the_documented_arguments(ros2: Ros2) -> None:
    shown = ros2.run(*LAUNCH, '--show-args')
    assert shown.returncode == 0, shown.stdout + shown.stderr
    names = set(re.findall(r"^    '(\w+)':$", shown.stdout, re.M))
    assert {'scenario', 'controller', 'allocator', 'mode', 'duration', 'namespace',
            'record', 'markers'} <= names, names
    documented = set(re.findall(r'^\| `(\w+):=', (REPO / 'docs' / 'launch.md').read_text(),
                                re.M))
    assert names == documented, (names, documented)


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_recorded_lockstep_launch_gives_the_headless_numbers(ros2: Ros2,
                                                              tmp_path: Path) -> None:
    """README's command, with a short run: exit 0, and the bag's run is ``tiltrov
    sim``'s to 1e-9; the markers are recorded."""
    from tiltrov_ros.bag.bagfile import bag_info
    from tiltrov_ros.bag.reader import read_runlog

    command, = doc_commands(REPO / 'README.md', 'ros2 launch tiltrov_ros tiltrov.launch.py')
    assert command[4:] == ['scenario:=pitch_hold', 'controller:=pid', 'record:=runs/x']
    ran = ros2.run_to_end(*command[1:], 'duration:=2', cwd=tmp_path)
    assert ran.returncode == 0, ran.stdout[-3000:] + ran.stderr[-3000:]
    assert 'Traceback' not in ran.stdout + ran.stderr
    bag = tmp_path / 'runs' / 'x'
    recorded = read_runlog(bag)
    expected = run_scenario(stack_config('pitch_hold', 'pid'), duration=2.0)
    assert_same_run(recorded, expected)
    # One marker array per 0.1 s of the 2 s run (t = 0 included).
    assert bag_info(str(bag)).topics['/robot_markers'].count == 21


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_ctrl_c_ends_a_launch_cleanly(ros: Any, ros2: Ros2, tmp_path: Path) -> None:
    """Ctrl-C in the terminal of a recorded realtime launch in a namespace (SIGINT to every
    process, and launch's own SIGINT to the nodes): exit code 0, no traceback, every
    node clean, the bag closed, readable and whole (the recorder stops once it has every
    node's final report)."""
    from tiltrov_ros.bag.losses import losses

    log = tmp_path / 'launch.log'
    proc = ros2.start(['ros2', *LAUNCH, 'mode:=realtime', 'namespace:=rov1', 'record:=bag'],
                      tmp_path, log)
    wait_nodes(ros, {f'/rov1/{n}' for n in (*NODES, 'bag_recorder')}, [proc])
    assert ctrl_c(proc) == 0, log.read_text()
    assert not losses(tmp_path / 'bag'), losses(tmp_path / 'bag').lines()
    output = log.read_text()
    assert 'Traceback' not in output and 'KeyboardInterrupt' not in output, output
    for node in (*NODES, 'bag_recorder'):
        assert re.search(rf'\[{node}-\d+\]: process has finished cleanly', output), output


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
@pytest.mark.parametrize(('kill_at', 'duration'), [
    (tuple(sorted(float(t) for t in np.random.default_rng(7).uniform(5.0, 100.0, 2))), 120),
    # At the run's first ticks: the run started only once both standbys kept the handoff.
    ((0.2, 0.2), 10),
], ids=['seed7', 'first-ticks'])
def test_respawned_nodes_are_taken_over_bit_for_bit(ros: Any, ros2: Ros2, tmp_path: Path,
                                                     kill_at: tuple[float, float],
                                                     duration: int) -> None:
    """``respawn:=wrench_controller,thrust_allocator`` in a recorded lockstep pid run
    (120 s, or 10 s): both killed (SIGKILL) at seeded random moments, or at the first
    ticks; each one's standby (a node of the run's handshake) takes over with the state
    handed over, the launch goes on (a respawned node's exit does not end it), ends with
    exit code 0, and the bag is the headless run without kills to the last bit, every
    step and tick in it. A try whose kills came after the run had ended is made again,
    longer (``killed_in_run``)."""
    from tiltrov_ros.bag.losses import missing_stamps
    from tiltrov_ros.bag.reader import read_runlog

    victims = ('wrench_controller', 'thrust_allocator')
    run_dir, duration, output = killed_in_run(
        tmp_path, duration,
        lambda run_dir, length, probe: _killed_run(ros, ros2, run_dir, victims, kill_at,
                                                   length, probe))
    for victim in victims:
        kept = re.search(rf'{victim}: taking over \((\d+) handoff messages kept\)', output)
        assert kept is not None and int(kept[1]) > 0, output[-5000:]
    assert len(set(kill_at)) <= output.count('every node of the run is ready again') \
        <= len(victims), output[-5000:]
    assert 'not bumpless' not in output and 'starts from zero' not in output
    bag = run_dir / 'bag'
    assert missing_stamps(bag, duration * 10**9, 10**7, 5 * 10**7) == {}
    assert_same_run(read_runlog(bag), run_scenario(stack_config('current_hold', 'pid'),
                                                   duration=float(duration)), atol=0.0)


def _killed_run(ros: Any, ros2: Ros2, run_dir: Path, victims: tuple[str, ...],
                kill_at: tuple[float, ...], duration: int, probe: str) -> str | None:
    """One recorded lockstep launch with ``victims`` respawned, each killed once the probe
    (a node of the run, so the run waits for it at the start) has seen ``kill_at``: the
    launch's output, or None when the plant had reached the run's end before the last
    victim was dead."""
    log = run_dir / 'launch.log'
    sim = joined_sim_time(ros, LaunchOptions(record=run_dir / 'bag', respawn=victims,
                                             join=(probe,)), probe)
    proc = ros2.start(['ros2', *LAUNCH, 'scenario:=current_hold', 'controller:=pid',
                       f'duration:={duration}', 'record:=bag',
                       f'respawn:={",".join(victims)}', f'join:={probe}'], run_dir, log)

    cpu = TreeProgress(proc.pid)

    def progress() -> tuple[int, int, int]:   # sim time, the launch saying or doing something
        return sim.ns, log.stat().st_size, cpu()

    dead = 0.0
    try:
        for victim, at in zip(victims, kill_at):
            assert ros.spin_while_progressing(lambda at=at: sim.reached(at), progress), \
                log.read_text()
            # The first process of the executable is the node (its standby starts after).
            pid = int(re.search(rf'\[{victim}-\d+\]: process started with pid \[(\d+)\]',
                                log.read_text())[1])
            dead = kill_now(pid)
        assert ros.spin_while_progressing(lambda: proc.poll() is not None, progress), \
            log.read_text()[-5000:]
        output = log.read_text()
        if ended_by(output, dead):
            return None
        assert proc.returncode == 0, output[-5000:]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return output

