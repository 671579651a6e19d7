"""``ros2 launch tiltrov_ros tiltrov.launch.py``: its arguments as docs/launch.md
lists them, a recorded lockstep run giving the headless numbers, Ctrl-C."""

from __future__ import annotations

from pathlib import Path
import re
from typing import Any

import pytest
from ros2_cli import Ros2, ctrl_c, doc_commands, wait_nodes
from ros_stack import assert_same_run

from tiltrov_ros.core.runner import run_scenario, stack_config

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
def test_a_recorded_lockstep_launch_gives_the_headless_numbers(ros2: Ros2,
                                                              tmp_path: Path) -> None:
    """README's command, with a short run: exit 0, and the bag's run is ``tiltrov
    sim``'s to 1e-9; the markers are recorded."""
    from tiltrov_ros.bag.bagfile import bag_info
    from tiltrov_ros.bag.reader import read_runlog

    command, = doc_commands(REPO / 'README.md', 'ros2 launch tiltrov_ros tiltrov.launch.py')
    assert command[4:] == ['scenario:=pitch_hold', 'controller:=pid', 'record:=runs/x']
    ran = ros2.run(*command[1:], 'duration:=2', cwd=tmp_path, timeout=150)
    assert ran.returncode == 0, ran.stdout[-3000:] + ran.stderr[-3000:]
    assert 'Traceback' not in ran.stdout + ran.stderr
    bag = tmp_path / 'runs' / 'x'
    recorded = read_runlog(bag)
    expected = run_scenario(stack_config('pitch_hold', 'pid'), duration=2.0)
    assert_same_run(recorded, expected)
    # One marker array per 0.1 s of the 2 s run (t = 0 included).
    assert bag_info(str(bag)).topics['/robot_markers'].count == 21


@pytest.mark.slow
def test_ctrl_c_ends_a_launch_cleanly(ros: Any, ros2: Ros2, tmp_path: Path) -> None:
    """Ctrl-C in the terminal of a realtime launch in a namespace (SIGINT to every
    process, and launch's own SIGINT to the nodes): exit code 0, no traceback, every
    node clean."""
    log = tmp_path / 'launch.log'
    proc = ros2.start(['ros2', *LAUNCH, 'mode:=realtime', 'namespace:=rov1'], tmp_path, log)
    wait_nodes(ros, {f'/rov1/{n}' for n in NODES}, [proc])
    assert ctrl_c(proc, timeout=60) == 0, log.read_text()
    output = log.read_text()
    assert 'Traceback' not in output and 'KeyboardInterrupt' not in output, output
    for node in NODES:
        assert re.search(rf'\[{node}-\d+\]: process has finished cleanly', output), output
