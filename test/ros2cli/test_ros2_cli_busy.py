"""The real ``ros2`` command line against a busy stack: during a recorded lockstep run at
full speed (every process busy, the recorder pacing the plant), ``ros2 node list`` shows
every node, the recorder included, and ``ros2 param get`` and ``ros2 param set`` on each
answer with the command line's own defaults (its daemon, its timeouts), each once: no
retry (``node list`` is asked until the daemon has discovered every node: the test's
probe seeing them does not mean the daemon has). (The nodes announce themselves every
0.1 s, config/fastdds.xml: a command line started later finds them within its window.)"""

from __future__ import annotations

import os
from pathlib import Path
import subprocess
import time
from typing import Any

import pytest
from ros2_cli import Ros2, ctrl_c, wait_nodes, without_dds_log
import yaml

NODES = ('plant_simulator', 'wrench_controller', 'thrust_allocator', 'reference_publisher',
         'bag_recorder')
#: A parameter each node lets change at run time, and the value it has (set to itself).
SETTABLE = {'plant_simulator': ('stall_timeout', '1.0'),
            'wrench_controller': ('input_timeout', '1.0'),
            'thrust_allocator': ('input_timeout', '1.0'),
            'reference_publisher': ('max_catch_up', '100')}


#: Each command run, its wall time and the load then: a failure shows them (a command
#: that timed out waiting for a node's services, and how loaded the machine was).
RUNS: list[str] = []


def _plain(ros2: Ros2, *args: str) -> subprocess.CompletedProcess[str]:
    """``ros2 args...`` exactly as typed: the command line's defaults, one attempt."""
    started = time.monotonic()
    done = without_dds_log(subprocess.run([ros2.exe, *args], cwd=ros2.workspace.root,
                                          env=ros2.env, capture_output=True, text=True,
                                          timeout=120))
    RUNS.append(f'{" ".join(args[:3])}: exit {done.returncode} in '
                f'{time.monotonic() - started:.1f} s, load {os.getloadavg()[0]:.1f}')
    return done


#: s: this test's bound against a hang: 13 commands (and node list until the daemon has
#: discovered every node), each a new Python process that
#: imports rclpy and discovers the graph (10-15 s apiece beside two busy loops: 116-200 s
#: in all, over the suite's 180 s), each command bounded on its own (120 s).
BOUND = 20 * 120


def _start_daemon(ros2: Ros2) -> None:
    """``ros2 daemon start``, the setup of the commands under test. It waits 10 s for the
    daemon to be ready and leaves it starting when a loaded machine takes longer (seen
    beside two busy loops): then wait until ``ros2 daemon status`` says it runs."""
    started = _plain(ros2, 'daemon', 'start')
    if started.returncode != 0:
        assert 'Timed out waiting for daemon' in started.stderr, started
        while 'The daemon is running' not in _plain(ros2, 'daemon', 'status').stdout:
            pass


@pytest.mark.slow
@pytest.mark.timeout(BOUND)
def test_node_list_param_get_and_set_answer_on_a_busy_recorded_run(
        ros: Any, ros2: Ros2, tmp_path: Path) -> None:
    # The daemon first: it discovers the nodes as they come up, as the test's probe
    # does (a daemon started after them could answer node list before it had seen all).
    _start_daemon(ros2)
    proc = ros2.start(['ros2', 'launch', 'tiltrov_ros', 'tiltrov.launch.py',
                       'duration:=3600', 'record:=bag'], tmp_path, tmp_path / 'launch.log')
    try:
        wait_nodes(ros, {f'/{n}' for n in NODES}, [proc])
        # The daemon's own side of discovery: the probe's view does not imply it (a quiet
        # run once listed four of the five just after the probe had seen all five). Every
        # listing answers; the wait is for the daemon to have discovered the fifth node.
        listings = 0
        while True:
            listed = _plain(ros2, 'node', 'list')
            listings += 1
            assert listed.returncode == 0, listed.stdout + listed.stderr
            if {f'/{n}' for n in NODES} <= set(listed.stdout.split()):
                break
            assert proc.poll() is None, (tmp_path / 'launch.log').read_text()[-3000:]
        print(f'ros2 node list: every node in listing {listings}')
        for node in NODES:
            got = _plain(ros2, 'param', 'get', f'/{node}', 'use_sim_time')
            assert got.returncode == 0 and 'Boolean value is:' in got.stdout, (node, got, RUNS)
        got = _plain(ros2, 'param', 'get', '/bag_recorder', 'run_info')
        assert got.returncode == 0, got
        run_info = got.stdout.split('String value is: ', 1)[1].strip()
        quoted = yaml.safe_dump(run_info, width=1 << 20).splitlines()[0]   # a string, not YAML
        sets = {**SETTABLE, 'bag_recorder': ('run_info', quoted)}
        for node, (name, value) in sets.items():
            done = _plain(ros2, 'param', 'set', f'/{node}', name, value)
            assert done.stdout.strip() == 'Set parameter successful', (node, done, RUNS)
        assert proc.poll() is None, (tmp_path / 'launch.log').read_text()[-3000:]
    finally:
        _plain(ros2, 'daemon', 'stop')
        if proc.poll() is None:
            ctrl_c(proc)
