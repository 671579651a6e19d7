"""RobotParams: the shipped robot.yaml, and rejection of every kind of invalid value."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
import yaml

from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.params import RobotParams, load_robot_params
from tiltrov_ros.paths import config_file

# The paper's Appendix A: diagonal of M (A.2) and the quadratic damping of (A.4).
PAPER_M = (96.3, 133.04, 168.57, 4.47, 9.26, 8.1)
PAPER_D = (34.55, 104.40, 146.50, 0.68, 5.34, 3.07)


def _shipped_block() -> dict:
    document = yaml.safe_load(config_file('robot.yaml').read_text())
    return dict(document['/**']['ros__parameters']['robot'])


def test_shipped_config_gives_the_papers_values() -> None:
    p = load_robot_params()
    assert p.mass_matrix == PAPER_M
    assert p.quadratic_damping == PAPER_D
    assert p.source is not None and p.source.endswith('robot.yaml')
    # The estimates are the ones config/robot.yaml documents with their reasoning.
    assert p.linear_damping == (0.0,) * 6
    assert (p.weight, p.buoyancy) == (638.0, 643.0)
    assert p.center_of_gravity == (0.0, 0.0, 0.02)
    assert p.center_of_buoyancy == (0.0, 0.0, 0.0)
    assert (p.length, p.width, p.max_thrust, p.thruster_time_constant) == (0.6, 0.4, 40.0, 0.1)
    assert (p.tilt_min, p.tilt_max) == (-math.pi / 2, math.pi / 2)
    assert p.tilt_rate_limit == pytest.approx(math.radians(150.0), rel=1e-15)


def test_yaml_keys_are_exactly_the_dataclass_fields() -> None:
    names = {f.name for f in dataclasses.fields(RobotParams)} - {'source'}
    assert set(_shipped_block()) == names


def test_every_estimate_in_the_yaml_is_marked_with_reasoning() -> None:
    text = config_file('robot.yaml').read_text()
    lines = text.splitlines()
    for key in _shipped_block():
        index = next(i for i, line in enumerate(lines) if line.strip().startswith(f'{key}:'))
        # The nearest comment block above the key (a pair such as tilt_min and
        # tilt_max shares one) says where the value comes from.
        above = lines[:index]
        while above and not above[-1].strip().startswith('#'):
            above.pop()
        comment = []
        for line in reversed(above):
            if not line.strip().startswith('#'):
                break
            comment.append(line)
        joined = ' '.join(comment)
        assert '[paper]' in joined or '[estimate]' in joined, key


def test_derived_arrays_and_as_dict() -> None:
    p = load_robot_params()
    assert p.M.shape == (6, 6)
    assert list(p.M.diagonal()) == list(PAPER_M)
    assert p.as_dict()['mass_matrix'] == list(PAPER_M)
    assert RobotParams.from_mapping(p.as_dict()) == p


def test_frozen_and_replace_revalidates() -> None:
    p = load_robot_params()
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.weight = 1.0  # type: ignore[misc]
    assert dataclasses.replace(p, weight=650.0).weight == 650.0
    with pytest.raises(ParameterError, match=r'robot\.weight'):
        dataclasses.replace(p, weight=-650.0)


INVALID = [
    ('mass_matrix', [96.3, -133.04, 168.57, 4.47, 9.26, 8.1]),   # negative mass
    ('mass_matrix', [96.3, 133.04, 168.57, 0.0, 9.26, 8.1]),     # M not positive definite
    ('mass_matrix', [96.3, 133.04, 168.57, 4.47, 9.26]),         # wrong length
    ('mass_matrix', [[96.3, 0.0], [0.0, 1.0]]),                  # not a vector
    ('quadratic_damping', [34.55, 104.4, -146.5, 0.68, 5.34, 3.07]),
    ('linear_damping', [0.0, 0.0, 0.0]),
    ('weight', -638.0),
    ('weight', 0.0),
    ('weight', math.nan),
    ('weight', True),
    ('weight', '638'),
    ('buoyancy', -1.0),
    ('buoyancy', math.inf),
    ('center_of_gravity', [0.0, 0.02]),
    ('center_of_gravity', [0.0, math.nan, 0.02]),
    ('center_of_buoyancy', [0.0, 0.0, math.inf]),
    ('length', 0.0),
    ('length', -0.6),
    ('width', math.inf),
    ('max_thrust', 0.0),
    ('thruster_time_constant', -0.1),
    ('tilt_min', -4.0),
    ('tilt_max', 3.5),
    ('tilt_rate_limit', 0.0),
    ('tilt_rate_limit', math.inf),
]


@pytest.mark.parametrize(('name', 'value'), INVALID)
def test_invalid_value_names_parameter_value_and_range(name: str, value: object) -> None:
    block = _shipped_block()
    block[name] = value
    with pytest.raises(ParameterError) as info:
        RobotParams.from_mapping(block)
    err = info.value
    assert err.name == f'robot.{name}'
    message = str(err)
    assert f"'robot.{name}'" in message
    assert repr(value) in message
    assert 'allowed:' in message


@pytest.mark.parametrize(('tilt_min', 'tilt_max'), [(1.0, 0.5), (0.5, 0.5)])
def test_tilt_min_must_be_below_tilt_max(tilt_min: float, tilt_max: float) -> None:
    block = _shipped_block()
    block.update(tilt_min=tilt_min, tilt_max=tilt_max)
    with pytest.raises(ParameterError, match='tilt_min < tilt_max') as info:
        RobotParams.from_mapping(block)
    assert info.value.name == 'robot.tilt_min'
    assert str(tilt_min) in str(info.value)


def _write(tmp_path: Path, block: dict, top: str = '/**') -> Path:
    path = tmp_path / 'robot.yaml'
    path.write_text(yaml.safe_dump({top: {'ros__parameters': {'robot': block}}}))
    return path


def test_error_names_the_source_file(tmp_path: Path) -> None:
    block = _shipped_block()
    block['length'] = -1.0
    path = _write(tmp_path, block)
    with pytest.raises(ParameterError) as info:
        load_robot_params(path)
    assert info.value.source == str(path)
    assert str(path) in str(info.value)
    assert 'robot.length' in str(info.value)


def test_unknown_and_missing_keys_are_rejected(tmp_path: Path) -> None:
    block = _shipped_block()
    block['lenght'] = 0.6
    with pytest.raises(ParameterError, match='unknown') as info:
        load_robot_params(_write(tmp_path, block))
    assert info.value.name == 'robot.lenght'

    block = _shipped_block()
    del block['width']
    with pytest.raises(ParameterError, match='missing') as info:
        load_robot_params(_write(tmp_path, block))
    assert info.value.name == 'robot.width'


def test_linear_damping_may_be_omitted_and_node_sections_work(tmp_path: Path) -> None:
    block = _shipped_block()
    del block['linear_damping']
    p = load_robot_params(_write(tmp_path, block, top='plant_simulator'))
    assert p.linear_damping == (0.0,) * 6
    assert p == load_robot_params()


def test_file_without_robot_block(tmp_path: Path) -> None:
    path = tmp_path / 'other.yaml'
    path.write_text('plant_simulator:\n  ros__parameters:\n    step_size: 0.01\n')
    with pytest.raises(ParameterError, match='no <node>') as info:
        load_robot_params(path)
    assert info.value.source == str(path)


def test_the_robot_past_vertical_is_the_papers_robot_but_for_the_servo_range() -> None:
    """config/robot_past_vertical.yaml: +-180 deg, every other value config/robot.yaml's
    (and the same control period); found by name or by path."""
    from tiltrov_ros.core.params import load_control_period, robot_file

    paper = load_robot_params()
    wide = load_robot_params(robot_file('robot_past_vertical'))
    assert (wide.tilt_min, wide.tilt_max) == (-math.pi, math.pi)
    assert dataclasses.replace(wide, tilt_min=paper.tilt_min, tilt_max=paper.tilt_max) == paper
    assert load_control_period(robot_file('robot_past_vertical')) == load_control_period()
    path = config_file('robot_past_vertical.yaml')
    assert robot_file(str(path)) == path and robot_file('robot') == config_file('robot.yaml')
    with pytest.raises(ParameterError, match="'nonesuch'; allowed: a robot parameter file"):
        robot_file('nonesuch')
