"""The nodes ``tiltrov launch`` starts and their parameters (no process started)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from tiltrov_ros.core.errors import TiltrovError
from tiltrov_ros.paths import config_file
from tiltrov_ros.stack.specs import LaunchOptions, namespaced_config, stack_specs

NODES = ('thrust_allocator', 'wrench_controller', 'reference_publisher', 'plant_simulator')


def _spec(specs, name):
    return next(s for s in specs if s.name == name)


def test_specs_carry_mode_scenario_duration_and_robot_overrides() -> None:
    specs, config, duration = stack_specs(LaunchOptions(scenario='pitch_hold_slow_servo',
                                                        controller='switching'))
    assert [s.name for s in specs] == list(NODES)
    assert duration == 60.0 and config.controller.kind == 'switching'
    plant = _spec(specs, 'plant_simulator').overrides
    assert (plant['mode'], plant['scenario'], plant['duration'], plant['exit_at_end']) == (
        'lockstep', 'pitch_hold_slow_servo', 60.0, True)
    assert _spec(specs, 'thrust_allocator').overrides['tilt_request'] == 'required'
    assert _spec(specs, 'wrench_controller').overrides['controller'] == 'switching'
    for spec in specs:   # the scenario's robot override reaches every node
        assert spec.overrides['robot.tilt_rate_limit'] == config.robot.tilt_rate_limit
        assert [p.name for p in spec.params_files] == ['robot.yaml', f'{spec.name}.yaml']
        if spec.name != 'plant_simulator':
            assert spec.overrides['use_sim_time'] is True

    specs, _, _ = stack_specs(LaunchOptions(controller='pd', allocator='paper', duration=2.0,
                                            lockstep=False, real_time_factor=5.0))
    assert _spec(specs, 'thrust_allocator').overrides['tilt_request'] == 'ignored'
    assert _spec(specs, 'thrust_allocator').overrides['mode'] == 'paper'
    assert _spec(specs, 'plant_simulator').overrides['real_time_factor'] == 5.0
    assert _spec(specs, 'wrench_controller').overrides['mode'] == 'realtime'


def test_scenario_file_paths_are_resolved(tmp_path: Path, repo_root: Path) -> None:
    scenario = tmp_path / 'mine.yaml'
    scenario.write_text((repo_root / 'config/scenarios/pitch_hold.yaml').read_text())
    specs, _config, _ = stack_specs(LaunchOptions(scenario=str(scenario)))
    assert _spec(specs, 'plant_simulator').overrides['scenario'] == str(scenario)
    assert _spec(specs, 'reference_publisher').overrides['scenario'] == str(scenario)


def test_a_robot_file_reaches_every_node_and_the_run(tmp_path: Path) -> None:
    """--robot (robot:= in the launch file): a shipped name or a path; every node gets
    that file in place of config/robot.yaml, in a namespace too (under its own name)."""
    specs, config, _ = stack_specs(LaunchOptions(duration=1.0, robot='robot_past_vertical'))
    wide = config_file('robot_past_vertical.yaml').resolve()
    assert all(s.params_files[0] == wide for s in specs)
    assert (config.robot.tilt_min, config.robot.tilt_max) == pytest.approx((-math.pi, math.pi))
    namespaced_config(specs, '/robot1', tmp_path)
    specs, config, _ = stack_specs(LaunchOptions(duration=1.0, robot=str(wide)),
                                   config_dir=tmp_path)
    assert all(s.params_files[0] == tmp_path / 'robot_past_vertical.yaml' for s in specs)
    assert config.robot.tilt_max == pytest.approx(math.pi)


@pytest.mark.parametrize(('options', 'message'), [
    (LaunchOptions(robot='no_such_robot'), "'no_such_robot'; allowed: a robot parameter file"),
    (LaunchOptions(duration=0.015), 'whole number'),
    (LaunchOptions(params=('wrench_controller:gains.kp',)), 'NODE:NAME:=VALUE'),
    (LaunchOptions(params=('nobody:x:=1',)), 'unknown node'),
])
def test_bad_options_are_refused_before_anything_starts(options, message) -> None:
    with pytest.raises(TiltrovError, match=message):
        stack_specs(options)


def test_overrides_file_is_keyed_by_the_full_node_name(tmp_path: Path) -> None:
    specs, _, _ = stack_specs(LaunchOptions(
        duration=1.0, params=('wrench_controller:gains.kp:=[1.0, 2.0, 3.0, 4.0, 5.0, 6.0]',
                              "wrench_controller:input_timeout:=2.5")))
    spec = _spec(specs, 'wrench_controller')
    document = yaml.safe_load(spec.write_overrides(tmp_path, '/robot1').read_text())
    values = document['/robot1/wrench_controller']['ros__parameters']
    assert values['gains.kp'] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert values['input_timeout'] == 2.5 and values['mode'] == 'lockstep'
    args = spec.ros_args(tmp_path / 'x.yaml', '/robot1')
    assert args[:3] == ['--ros-args', '-r', '__ns:=/robot1']
    assert args[-2:] == ['--params-file', str(tmp_path / 'x.yaml')]


def test_namespaced_config_renames_node_sections(tmp_path: Path) -> None:
    specs, _, _ = stack_specs(LaunchOptions(duration=1.0))
    namespaced_config(specs, '/robot1', tmp_path)
    controller = yaml.safe_load((tmp_path / 'wrench_controller.yaml').read_text())
    assert list(controller) == ['/robot1/wrench_controller']
    robot = yaml.safe_load((tmp_path / 'robot.yaml').read_text())
    assert list(robot) == ['/**']


def test_record_starts_the_recorder_first(tmp_path: Path) -> None:
    options = LaunchOptions(duration=1.0, record=tmp_path / 'bag')
    specs, _, _ = stack_specs(options)
    recorder = specs[0]
    assert recorder.name == 'bag_recorder'
    assert recorder.overrides['use_sim_time'] is True
    # The plant waits for the recorder too before it starts the run.
    assert _spec(specs, 'plant_simulator').overrides['startup_subscribers'] == 2


def test_a_standby_file_written_again_is_never_seen_half_written(tmp_path: Path) -> None:
    """At every takeover the launcher writes the new standby's overrides file again while
    the node taking over reads that same file (its parameters in command-line order): a
    reader must always find the whole file, never a truncated one (which once built a
    taken-over pid controller as the config file's pd)."""
    import threading

    specs, _, _ = stack_specs(LaunchOptions(controller='pid', respawn=('wrench_controller',)))
    spec = _spec(specs, 'wrench_controller')
    path = spec.write_overrides(tmp_path, standby=True)
    whole = path.read_text()
    seen: list[str] = []
    done = threading.Event()

    def read() -> None:
        while not done.is_set():
            seen.append(path.read_text())

    reader = threading.Thread(target=read)
    reader.start()
    writes = 0
    try:
        # At least 300 writes, and on until the reader has read 50 times while they went
        # on (a condition, not a count: a busy machine may start the reader late).
        while reader.is_alive() and (writes < 300 or len(seen) < 50):
            spec.write_overrides(tmp_path, standby=True)
            writes += 1
    finally:
        done.set()
        reader.join()
    assert len(seen) >= 50 and all(text == whole for text in seen)
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]
