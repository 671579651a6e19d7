"""The stack in one process (``tiltrov launch --single-process``)."""

from __future__ import annotations

import io
import threading

import pytest
from ros_stack import MS, Probe

from tiltrov_ros.stack.launch import launch
from tiltrov_ros.stack.specs import LaunchOptions


@pytest.mark.slow
def test_single_process_launch_in_a_namespace(ros) -> None:
    """``--single-process --namespace robot1``: every topic moves under /robot1."""
    probe = Probe(ros.node('ns_probe', namespace='/robot1'), ['odom', 'thrust_cmd'])
    root = Probe(ros.node('root_probe'), ['odom'])
    stream = io.StringIO()
    result: list[int] = []
    # The plant waits for the probe's odom reader too (as for the controller's): a
    # run of 1 s of sim time takes a fraction of a second, over before a late probe.
    options = LaunchOptions(scenario='pitch_hold', duration=1.0, single_process=True,
                            namespace='robot1',
                            params=('plant_simulator:startup_subscribers:=2',))
    thread = threading.Thread(target=lambda: result.append(launch(options, stream)))
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
