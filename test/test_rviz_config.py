"""The shipped RViz config (config/rviz/tiltrov.rviz) names what the stack publishes.

RViz does not run here: the file is checked as RViz 2 reads it (YAML, the
displays of rviz_default_plugins) against the stack's topics, the transform
tree's frames and the QoS each topic is offered with (a reader asking for more
than the writer offers receives nothing, silently).
"""

from __future__ import annotations

from typing import Any

import yaml

from tiltrov_ros.core.names import (
    FRAME_BODY,
    FRAME_BODY_FLU,
    FRAME_EARTH,
    FRAME_EARTH_ENU,
    ODOM,
    ROBOT_DESCRIPTION,
    ROBOT_MARKERS,
)
from tiltrov_ros.paths import config_file

RVIZ = config_file('rviz/tiltrov.rviz')
FRAMES = {FRAME_EARTH_ENU, FRAME_EARTH, FRAME_BODY_FLU, FRAME_BODY}


def _displays() -> dict[str, dict[str, Any]]:
    config = yaml.safe_load(RVIZ.read_text(encoding='utf-8'))
    return {d['Class'].rsplit('/', 1)[-1]: d for d in config['Visualization Manager']['Displays']}


def test_rviz_shows_the_tree_the_robot_model_the_markers_and_odom_in_odom() -> None:
    config = yaml.safe_load(RVIZ.read_text(encoding='utf-8'))
    manager = config['Visualization Manager']
    assert manager['Global Options']['Fixed Frame'] == FRAME_EARTH_ENU
    assert manager['Views']['Current']['Target Frame'] in FRAMES
    displays = _displays()
    assert set(displays) == {'Grid', 'TF', 'RobotModel', 'MarkerArray', 'Odometry'}
    assert all(d['Enabled'] is True for d in displays.values())


def test_rviz_readers_match_the_stacks_writers() -> None:
    """robot_description is transient local (RViz started after the stack still gets it);
    the markers and odometry are reliable volatile writers (any reader matches)."""
    displays = _displays()
    model = displays['RobotModel']
    assert model['Description Source'] == 'Topic'
    topic = model['Description Topic']
    assert topic['Value'] == f'/{ROBOT_DESCRIPTION}'
    assert topic['Durability Policy'] == 'Transient Local'
    assert displays['MarkerArray']['Topic']['Value'] == f'/{ROBOT_MARKERS}'
    assert displays['Odometry']['Topic']['Value'] == f'/{ODOM}'
    for name in ('MarkerArray', 'Odometry'):
        assert displays[name]['Topic']['Durability Policy'] == 'Volatile'
    # The robot model draws the hull and the thrusters: the markers add the arrows.
    namespaces = displays['MarkerArray']['Namespaces']
    assert namespaces.pop('body') is False and namespaces.pop('thrusters') is False
    assert all(namespaces.values())
