"""The shipped Foxglove and PlotJuggler layouts name what the stack publishes.

Neither tool runs here: the layouts are checked against the formats those
tools read (Foxglove's layout JSON: configById, the panel tree, userNodes;
PlotJuggler's XML: tabs, docks, curves, custom math) and every topic and
field they plot against the stack's topics and message types (a misspelt
path shows an empty plot, silently).
"""

from __future__ import annotations

import json
import re
from typing import Any
import xml.etree.ElementTree as ET

from tiltrov_ros.bag.msgdefs import message_class
from tiltrov_ros.core.names import (
    DIAGNOSTICS,
    FRAME_EARTH,
    ROBOT_DESCRIPTION,
    STACK_TOPICS,
    TF,
    TF_STATIC,
    TF_TOPICS,
    THRUSTERS,
    TILTS,
)
from tiltrov_ros.paths import config_file

FOXGLOVE = config_file('foxglove/tiltrov.json')
PLOTJUGGLER = config_file('plotjuggler/tiltrov.xml')
#: Topic (absolute, no namespace) -> message type, as a bag of `tiltrov launch --record`.
TOPICS = {(t if t.startswith('/') else f'/{t}'): msgtype for t, msgtype in STACK_TOPICS.items()}
#: JointState topics -> (joint names, the arrays the stack fills).
JOINTS = {'/joint_states': (TILTS + THRUSTERS, ('position', 'velocity', 'effort')),
          '/tilt_cmd': (TILTS, ('position',)), '/thrust_cmd': (THRUSTERS, ('effort',))}
_PART = re.compile(r'^(?P<name>[a-z_0-9]+)(?:\[(?P<index>\d+)\])?$')


def _field_type(msgtype: str, parts: list[str], topic: str) -> str:
    """The type of the field ``parts`` leads to in ``msgtype`` (AssertionError if none)."""
    current: Any = message_class(msgtype)
    kind = msgtype
    for part in parts:
        match = _PART.match(part)
        assert match, (topic, part)
        fields = current.get_fields_and_field_types()
        assert match['name'] in fields, (topic, parts, sorted(fields))
        kind = fields[match['name']]
        if match['index'] is not None:
            sequence = re.match(r'^sequence<(.+?)(?:, \d+)?>$', kind)
            assert sequence, (topic, part, kind)
            kind = sequence[1]
            if topic in JOINTS:
                names, filled = JOINTS[topic]
                assert match['name'] in filled and int(match['index']) < len(names), (topic, part)
        if '/' in kind:
            current = message_class(kind)
    return kind


def _mosaic_leaves(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    assert set(node) >= {'first', 'second', 'direction'}
    assert node['direction'] in ('row', 'column')
    return _mosaic_leaves(node['first']) + _mosaic_leaves(node['second'])


def _foxglove() -> dict[str, Any]:
    return json.loads(FOXGLOVE.read_text(encoding='utf-8'))


def test_foxglove_layout_has_the_layout_data_shape() -> None:
    layout = _foxglove()
    assert set(layout) == {'configById', 'globalVariables', 'userNodes', 'playbackConfig',
                           'layout'}
    leaves = _mosaic_leaves(layout['layout'])
    assert sorted(leaves) == sorted(layout['configById'])
    kinds = [panel_id.split('!')[0] for panel_id in leaves]
    assert sorted(set(kinds)) == ['3D', 'DiagnosticSummary', 'Plot']
    assert kinds.count('Plot') == 5


def test_foxglove_3d_panel_shows_the_markers_odometry_tree_and_urdf_in_odom_ned() -> None:
    """odom_ned is a frame with or without the tree (the markers' and odom's frame); the
    tree places the URDF that robot_description carries (the plant's, or
    robot_state_publisher's)."""
    three_d = _foxglove()['configById']['3D!robot']
    assert three_d['followTf'] == FRAME_EARTH
    assert three_d['followMode'] in ('follow-pose', 'follow-position', 'follow-none')
    assert set(three_d['topics']) == {'/robot_markers', '/odom', TF, TF_STATIC}
    assert all(t in TOPICS or t in TF_TOPICS for t in three_d['topics'])
    (urdf,) = [layer for layer in three_d['layers'].values()
               if layer['layerId'] == 'foxglove.Urdf']
    assert urdf['sourceType'] == 'topic' and urdf['topic'] == f'/{ROBOT_DESCRIPTION}'
    assert urdf['framePrefix'] == '' and urdf['visible'] is True
    assert {'distance', 'phi', 'thetaOffset', 'perspective'} <= set(three_d['cameraState'])
    diagnostics = _foxglove()['configById']['DiagnosticSummary!stack']
    assert diagnostics['topicToRender'] == DIAGNOSTICS and diagnostics['pinnedIds'] == []


def _script() -> tuple[list[str], str, set[str]]:
    """The user script's inputs, output topic and output fields."""
    (node,) = _foxglove()['userNodes'].values()
    source = node['sourceCode']
    inputs = json.loads(re.search(r'export const inputs = (\[.*?\]);', source)[1])
    output = re.search(r'export const output = "(.+?)";', source)[1]
    body = re.search(r'type Output = \{(.*?)\};', source, re.S)[1]
    fields = set(re.findall(r'(\w+): number;', body))
    return inputs, output, fields


def test_foxglove_user_script_reads_stack_topics_and_writes_a_studio_script_topic() -> None:
    inputs, output, fields = _script()
    assert set(inputs) <= set(TOPICS)
    assert output.startswith('/studio_script/')
    assert fields == {'x', 'y', 'z', 'roll_deg', 'pitch_deg', 'yaw_deg'}


def test_every_foxglove_plot_path_is_a_numeric_field_of_a_stack_topic() -> None:
    _, output, fields = _script()
    plots = {k: v for k, v in _foxglove()['configById'].items() if k.startswith('Plot!')}
    for panel in plots.values():
        assert panel['xAxisVal'] == 'timestamp' and panel['paths']
        for path in panel['paths']:
            assert path['enabled'] is True
            assert path['timestampMethod'] in ('receiveTime', 'headerStamp')
            topic, _, rest = path['value'].partition('.')
            if topic == output:
                assert rest in fields, path
                continue
            assert topic in TOPICS, path
            assert _field_type(TOPICS[topic], rest.split('.'), topic) in ('double', 'float'), path


def _plotjuggler_series(curve: str, snippets: set[str]) -> None:
    """A PlotJuggler series name of a stack topic (its ROS 2 parsers' naming: JointState
    by joint name, quaternions also as roll_deg, pitch_deg, yaw_deg)."""
    if curve in snippets:
        return
    topic = next((t for t in sorted(TOPICS, key=len, reverse=True)
                  if curve.startswith(t + '/')), None)
    assert topic is not None, curve
    parts = curve[len(topic) + 1:].split('/')
    if topic in JOINTS:
        names, filled = JOINTS[topic]
        assert len(parts) == 2 and parts[0] in names and parts[1] in filled, curve
        return
    if parts[-1] in ('roll_deg', 'pitch_deg', 'yaw_deg'):
        kind = _field_type(TOPICS[topic], parts[:-1], topic)
        assert kind == 'geometry_msgs/Quaternion', curve
        return
    assert _field_type(TOPICS[topic], parts, topic) in ('double', 'float'), curve


def test_plotjuggler_layout_plots_series_of_stack_topics() -> None:
    root = ET.parse(PLOTJUGGLER).getroot()
    assert root.tag == 'root'
    tabs = root.find('tabbed_widget')
    assert tabs is not None and tabs.get('parent') == 'main_window'
    snippets = {s.get('name'): s for s in root.iter('snippet')}
    assert set(snippets) == {'error_x', 'error_z', 'error_pitch_deg'}
    for snippet in snippets.values():
        sources = [snippet.findtext('linked_source')]
        sources += [s.text for s in snippet.find('additional_sources')]
        assert 'v1' in snippet.findtext('function')
        for source in sources:
            _plotjuggler_series(source, set())
    for splitter in root.iter('DockSplitter'):
        areas = splitter.findall('DockArea')
        assert int(splitter.get('count')) == len(areas) == len(splitter.get('sizes').split(';'))
    curves = [c.get('name') for c in root.iter('curve')]
    assert len(curves) == 31
    for curve in curves:
        _plotjuggler_series(curve, set(snippets))
