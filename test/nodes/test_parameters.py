"""Where parameter values come from: command-line order, sections, every value set.

rcl alone lets a node's own section of a parameter file beat a later ``-p``
and a launch file's ``parameters=[{...}]`` (both filed under ``/**``); the
nodes apply the command line in order instead (nodes/parameters.py).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from rclpy.parameter import Parameter

from tiltrov_ros.core.scenarios import load_scenario
from tiltrov_ros.nodes.bag_recorder import BagRecorder
from tiltrov_ros.nodes.parameters import (
    given_values,
    misdirected_sections,
    parameter_source,
    ros_arguments,
    section_matches,
)
from tiltrov_ros.nodes.plant_simulator import PlantSimulator
from tiltrov_ros.nodes.reference_publisher import ReferencePublisher
from tiltrov_ros.nodes.thrust_allocator import ThrustAllocatorNode
from tiltrov_ros.nodes.wrench_controller import WrenchController
from tiltrov_ros.paths import config_file

SHIPPED = ['--ros-args', '--params-file', str(config_file('robot.yaml')),
           '--params-file', str(config_file('plant_simulator.yaml'))]


def _write(path: Path, text: str) -> str:
    path.write_text(text, encoding='utf-8')
    return str(path)


@pytest.mark.parametrize(('key', 'node', 'expected'), [
    ('/**', '/plant_simulator', True), ('/**', '/a/b/plant_simulator', True),
    ('plant_simulator', '/plant_simulator', True), ('/plant_simulator', '/plant_simulator', True),
    ('plant_simulator', '/robot1/plant_simulator', False),
    ('/robot1/plant_simulator', '/robot1/plant_simulator', True),
    ('/*/plant_simulator', '/robot1/plant_simulator', True),
    ('/*/plant_simulator', '/plant_simulator', False),
    ('/**/plant_simulator', '/plant_simulator', True),
    ('/**/plant_simulator', '/a/b/plant_simulator', True),
    ('plant_simulater', '/plant_simulator', False), ('/*', '/plant_simulator', True),
])
def test_sections_match_nodes_as_rcl_matches_them(key: str, node: str, expected: bool) -> None:
    assert section_matches(key, node) is expected


def test_ros_arguments_reads_only_the_ros_args_parts_in_order() -> None:
    args = ['prog', '-p', 'not:=ros', '--ros-args', '--params-file', 'a.yaml', '-r',
            '__ns:=/x', '-p', 'mode:=lockstep', '--', '--params-file', 'ignored.yaml',
            '--ros-args', '--param', 'x:=1', '--params-file', 'b.yaml']
    assert ros_arguments(args) == [('file', 'a.yaml'), ('param', 'mode:=lockstep'),
                                   ('param', 'x:=1'), ('file', 'b.yaml')]


def test_later_values_win_and_a_node_section_wins_within_its_file(tmp_path: Path) -> None:
    first = _write(tmp_path / 'first.yaml', 'plant_simulator:\n  ros__parameters:\n'
                   '    mode: realtime\n    duration: 5.0\n'
                   '/**:\n  ros__parameters:\n    mode: wildcard\n    step_size: 0.02\n')
    later = _write(tmp_path / 'later.yaml', '/**:\n  ros__parameters:\n    duration: 7.0\n'
                   '    robot:\n      length: 0.7\n')
    args = ['--ros-args', '--params-file', first, '-p', 'mode:=lockstep', '-p',
            'other_node:mode:=ignored', '--params-file', later, '-p', 'real_time_factor:=1e1']
    given = given_values(args, '/plant_simulator')
    assert {name: g.value for name, g in given.items()} == {
        'mode': 'lockstep', 'duration': 7.0, 'step_size': 0.02, 'robot.length': 0.7,
        'real_time_factor': 10.0}
    assert given['duration'].source == later and given['mode'].source is None
    assert given_values(['--ros-args', '--params-file', first], '/plant_simulator')[
        'mode'].value == 'realtime'
    assert parameter_source('length', 'plant_simulator', args) == later
    assert parameter_source('mode', '/plant_simulator', args) is None


def test_misdirected_sections_are_named_once_each(tmp_path: Path) -> None:
    typo = _write(tmp_path / 'typo.yaml', 'plant_simulater:\n  ros__parameters:\n    x: 1\n'
                  'wrench_controller:\n  ros__parameters:\n    x: 1\n'
                  '/**:\n  ros__parameters:\n    x: 1\n')
    lines = misdirected_sections(['--ros-args', '--params-file', typo], '/plant_simulator')
    assert len(lines) == 1 and "'plant_simulater' names no node of tiltrov_ros" in lines[0]
    assert typo in lines[0]
    shipped = ['--ros-args', '--params-file', str(config_file('plant_simulator.yaml'))]
    lines = misdirected_sections(shipped, '/robot1/plant_simulator')
    assert len(lines) == 1 and "does not reach this node (/robot1/plant_simulator)" in lines[0]
    assert misdirected_sections(shipped, '/plant_simulator') == []
    # A respawn's overrides have a section for the node and one for its standby: the
    # node taking over reads both without a word.
    both = _write(tmp_path / 'respawn.yaml', ''.join(
        f'{name}:\n  ros__parameters:\n    x: 1\n'
        for name in ('thrust_allocator', 'thrust_allocator_standby')))
    assert misdirected_sections(['--ros-args', '--params-file', both],
                                '/thrust_allocator') == []


def test_p_overrides_the_shipped_node_section(ros) -> None:
    args = [*SHIPPED, '-p', 'mode:=lockstep', '-p', 'scenario:=pitch_hold']
    node = ros.add(PlantSimulator(context=ros.context, cli_args=args))
    assert node.config.mode == 'lockstep' and node.config.scenario == 'pitch_hold'


def test_a_launch_file_dict_after_the_shipped_file_wins(ros, tmp_path: Path) -> None:
    # launch_ros writes parameters=[{...}] as a '/**' file after the files before it.
    launch_dict = _write(tmp_path / 'launch_params.yaml',
                         '/**:\n  ros__parameters:\n    mode: lockstep\n    use_sim_time: true\n')
    args = [*SHIPPED, '--params-file', launch_dict]
    node = ros.add(PlantSimulator(context=ros.context, cli_args=args))
    assert node.config.mode == 'lockstep'
    assert node.get_parameter('use_sim_time').value is True


def test_constructor_overrides_win_over_the_command_line(ros) -> None:
    node = ros.add(PlantSimulator(context=ros.context, cli_args=[*SHIPPED, '-p',
                                                                 'mode:=lockstep'],
                                  parameter_overrides={'mode': 'realtime'}))
    assert node.config.mode == 'realtime'


NODES = [PlantSimulator, WrenchController, ThrustAllocatorNode, ReferencePublisher,
         BagRecorder]


@pytest.mark.parametrize('cls', NODES, ids=lambda c: c.__name__)
def test_every_parameter_has_a_value_and_arrays_their_element_type(ros, cls, tmp_path) -> None:
    extra = {'output': str(tmp_path / 'bag')} if cls is BagRecorder else {}
    node = ros.add(cls(context=ros.context, parameter_overrides=extra))
    names = node.list_parameters([], 10).names
    assert len(names) > 5
    for param in node.get_parameters(names):
        assert param.type_ != Parameter.Type.NOT_SET, param.name
        assert param.type_ != Parameter.Type.BYTE_ARRAY, param.name


def test_typed_empty_arrays_and_the_scenario_disturbances(ros) -> None:
    plant = ros.add(PlantSimulator(context=ros.context,
                                   parameter_overrides={'scenario': 'pitch_hold'}))
    failed = plant.get_parameter('failed_thrusters')
    assert failed.type_ == Parameter.Type.INTEGER_ARRAY and list(failed.value) == []
    scenario = load_scenario('pitch_hold').disturbances
    assert tuple(plant.get_parameter('com_error').value) == scenario.com_error != (0, 0, 0)
    assert tuple(plant.get_parameter('current').value) == scenario.current
    given = ros.add(PlantSimulator(context=ros.context, node_name='plant_given',
                                   parameter_overrides={'scenario': 'pitch_hold',
                                                        'com_error': [0.0, 0.0, 0.0]}))
    assert given.config.disturbances.com_error == (0.0, 0.0, 0.0)


def test_a_launch_files_list_values_written_as_python_tuples_are_read(tmp_path) -> None:
    """launch_ros writes a launch file's list values as ``!!python/tuple`` (rcl reads them
    as arrays): the command-line order is still applied from that file, list and all."""
    from tiltrov_ros.nodes.parameters import file_sections
    path = tmp_path / 'launch_params'
    path.write_text("/**:\n  ros__parameters:\n    mode: lockstep\n"
                    "    run_nodes: !!python/tuple\n    - plant_simulator\n    - bag_recorder\n")
    assert file_sections(str(path)) == {
        '/**': {'mode': 'lockstep', 'run_nodes': ['plant_simulator', 'bag_recorder']}}
