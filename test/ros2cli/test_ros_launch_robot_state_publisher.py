"""The launch file and robot_state_publisher: started with the URDF of the robot in use
where it is installed (a ROS install), the plant then leaving it the thruster links;
absent (the venv), the plant publishes them. robot_state_publisher itself does not run
here (no wheel of it): the launch description is checked, with the package's presence
as the ament index would report it."""

from __future__ import annotations

from typing import Any
import xml.etree.ElementTree as ET

import pytest
from ros2_cli import missing_cli

from tiltrov_ros.core.names import THRUSTER_LINKS, TILTS
from tiltrov_ros.core.runner import stack_config

if missing_cli():
    pytest.skip(missing_cli(), allow_module_level=True)

from launch import LaunchContext
from launch_ros.actions import Node

from tiltrov_ros.stack import ros_launch


def _nodes(monkeypatch: pytest.MonkeyPatch, installed: bool, **values: str) -> list[Any]:
    monkeypatch.setattr(ros_launch, 'robot_state_publisher_installed', lambda: installed)
    context = LaunchContext()
    for name, (default, _) in ros_launch.ARGUMENTS.items():
        context.launch_configurations[name] = values.get(name, default)
    return [a for a in ros_launch._stack(context) if isinstance(a, Node)]


@pytest.mark.parametrize('installed', [True, False])
def test_robot_state_publisher_is_started_where_installed(
        monkeypatch: pytest.MonkeyPatch, installed: bool) -> None:
    nodes = _nodes(monkeypatch, installed, duration='1.0')
    packages = [n.node_package for n in nodes]
    assert packages.count(ros_launch.ROBOT_STATE_PUBLISHER) == int(installed)
    assert packages.count(ros_launch.PACKAGE) == 4


def test_robot_state_publisher_gets_the_urdf_of_the_robot_in_use_at_the_step_rate() -> None:
    """The scenario's robot (its overrides applied), sim time, every joint_states (100 Hz)."""
    config = stack_config('pitch_hold_slow_servo')
    params = ros_launch.robot_state_publisher_parameters(config)
    assert params['use_sim_time'] is True and params['publish_frequency'] == 100.0
    robot = ET.fromstring(params['robot_description'])
    limits = {j.get('name'): float(j.find('limit').get('velocity'))
              for j in robot.iter('joint')}
    assert set(limits) >= set(TILTS)
    assert set(limits.values()) == {config.robot.tilt_rate_limit}
    assert sorted(link.get('name') for link in robot.iter('link'))[-4:] == sorted(THRUSTER_LINKS)


def test_the_robot_argument_chooses_the_robot_file() -> None:
    """robot:=NAME|FILE is --robot of tiltrov launch; empty: config/robot.yaml."""
    values = {name: default for name, (default, _) in ros_launch.ARGUMENTS.items()}
    assert ros_launch.options_from(values).robot is None
    chosen = ros_launch.options_from({**values, 'robot': 'robot_past_vertical'})
    assert chosen.robot == 'robot_past_vertical'
