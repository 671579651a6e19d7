"""Scenario files: term values and rates, units, disturbances, overrides, errors.

The shipped scenarios are checked against the paper's Section 4 text.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from tiltrov_ros.core.errors import ParameterError, ScenarioError
from tiltrov_ros.core.kinematics import euler_from_quat
from tiltrov_ros.core.params import load_robot_params
from tiltrov_ros.core.scenarios import (
    Scenario,
    WrenchPulses,
    load_scenario,
    scenario_names,
)

DEG = math.pi / 180.0


def _scenario(reference: dict, **extra) -> Scenario:
    return Scenario.from_mapping({'duration': 10.0, 'reference': reference, **extra},
                                 source='test.yaml')


def _dof(scn: Scenario, t: float, dof: int) -> tuple[float, float]:
    eta, rate = scn.reference.eta(t)
    return float(eta[dof]), float(rate[dof])


# --------------------------------------------------------------------------- terms


def test_constant_term() -> None:
    scn = _scenario({'y': [{'type': 'constant', 'value': 0.3}]})
    for t in (0.0, 5.0, 100.0):
        assert _dof(scn, t, 1) == (0.3, 0.0)


def test_ramp_term_value_and_rate() -> None:
    scn = _scenario({'x': [{'type': 'ramp', 'from': 1.0, 'to': 3.0, 'start': 2.0,
                            'duration': 4.0}]})
    assert _dof(scn, 0.0, 0) == (1.0, 0.0)              # held before
    assert _dof(scn, 2.0, 0) == (1.0, 0.0)              # at the kink: the held piece's rate
    assert _dof(scn, 2.5, 0) == (1.25, 0.5)
    assert _dof(scn, 3.0, 0) == (1.5, 0.5)
    assert _dof(scn, 6.0, 0) == (3.0, 0.0)              # held from the end on
    assert _dof(scn, 60.0, 0) == (3.0, 0.0)
    # start defaults to 0
    scn = _scenario({'x': [{'type': 'ramp', 'from': 0.0, 'to': -1.0, 'duration': 2.0}]})
    assert _dof(scn, 1.0, 0) == (-0.5, -0.5)


def test_sine_term_value_and_rate() -> None:
    term = {'type': 'sine', 'amplitude': 0.4, 'omega': 0.5, 'phase': 0.25, 'start': 1.0,
            'end': 5.0}
    scn = _scenario({'z': [term]})
    assert _dof(scn, 0.0, 2) == pytest.approx((0.4 * math.sin(0.25), 0.0))
    for t in (1.0, 2.5, 4.9):
        value, rate = _dof(scn, t, 2)
        assert value == pytest.approx(0.4 * math.sin(0.5 * (t - 1.0) + 0.25), abs=1e-15)
        assert rate == pytest.approx(0.2 * math.cos(0.5 * (t - 1.0) + 0.25), abs=1e-15)
    held = 0.4 * math.sin(0.5 * 4.0 + 0.25)
    assert _dof(scn, 5.0, 2) == pytest.approx((held, 0.2 * math.cos(0.5 * 4.0 + 0.25)))
    assert _dof(scn, 5.01, 2) == pytest.approx((held, 0.0))
    assert _dof(scn, 9.0, 2) == pytest.approx((held, 0.0))


def test_step_term() -> None:
    scn = _scenario({'roll': [{'type': 'step', 'value': 0.1, 'at': 3.0}]})
    assert _dof(scn, 2.99, 3) == (0.0, 0.0)
    assert _dof(scn, 3.0, 3) == (0.1, 0.0)


def test_terms_add_and_rates_are_derivatives() -> None:
    scn = _scenario({'z': [{'type': 'ramp', 'from': 0.0, 'to': -1.0, 'duration': 8.0},
                           {'type': 'sine', 'amplitude': 0.4, 'omega': 0.7},
                           {'type': 'constant', 'value': 0.05}]})
    value, _ = _dof(scn, 2.0, 2)
    assert value == pytest.approx(-0.25 + 0.4 * math.sin(1.4) + 0.05)
    # The rate is the derivative of the value (central differences, away from kinks).
    h = 1e-6
    for t in np.linspace(0.5, 9.5, 17):
        if abs(t - 8.0) < 1e-3:
            continue
        numeric = (_dof(scn, t + h, 2)[0] - _dof(scn, t - h, 2)[0]) / (2 * h)
        assert _dof(scn, t, 2)[1] == pytest.approx(numeric, abs=1e-7)


def test_unlisted_dofs_are_held_at_zero_and_a_single_term_may_be_a_mapping() -> None:
    scn = _scenario({'x': {'type': 'constant', 'value': 2.0}})
    eta, rate = scn.reference.eta(3.0)
    np.testing.assert_array_equal(eta, [2.0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(rate, np.zeros(6))


def test_angle_unit_deg_scales_angle_values_only() -> None:
    reference = {
        'pitch': [{'type': 'ramp', 'from': 0.0, 'to': -30.0, 'duration': 30.0}],
        'yaw': [{'type': 'sine', 'amplitude': 10.0, 'omega': 0.5, 'phase': 0.0}],
        'x': [{'type': 'constant', 'value': 2.0}],
    }
    deg = _scenario(reference, angle_unit='deg',
                    initial_state={'euler': [1.0, 2.0, 3.0], 'position': [1, 2, 3]})
    rad = _scenario(reference, initial_state={'euler': [1.0, 2.0, 3.0]})
    assert _dof(deg, 15.0, 4) == pytest.approx((-15.0 * DEG, -DEG))
    assert _dof(rad, 15.0, 4) == pytest.approx((-15.0, -1.0))
    # omega, phase, start and duration are not angles: the sine keeps its frequency.
    assert _dof(deg, 1.0, 5) == pytest.approx((10.0 * DEG * math.sin(0.5),
                                               5.0 * DEG * math.cos(0.5)))
    assert _dof(deg, 1.0, 0) == (2.0, 0.0)             # positions untouched
    assert deg.initial_state.euler == pytest.approx((DEG, 2 * DEG, 3 * DEG))
    assert deg.initial_state.position == (1.0, 2.0, 3.0)
    assert rad.initial_state.euler == (1.0, 2.0, 3.0)


def test_reference_at_carries_the_attitude_as_a_quaternion() -> None:
    scn = _scenario({'roll': [{'type': 'constant', 'value': 5.0}],
                     'pitch': [{'type': 'constant', 'value': -30.0}],
                     'yaw': [{'type': 'constant', 'value': 120.0}],
                     'x': [{'type': 'constant', 'value': 0.5}]}, angle_unit='deg')
    ref = scn.reference.at(1.0)
    assert ref.quaternion.shape == (4,)
    assert float(np.linalg.norm(ref.quaternion)) == pytest.approx(1.0)
    np.testing.assert_allclose(euler_from_quat(ref.quaternion),
                               [5 * DEG, -30 * DEG, 120 * DEG], atol=1e-12)
    np.testing.assert_array_equal(ref.position, [0.5, 0.0, 0.0])


# --------------------------------------------------------------------------- disturbances


def test_disturbances_constant_and_pulses() -> None:
    scn = _scenario({}, disturbances={
        'com_error': [0.01, 0.0, 0.005], 'current': [0.1, 0.0, 0.0],
        'current_std': [0.02, 0.0, 0.0], 'current_time_constant': [30, 60, 60], 'seed': 7,
        'external_wrench': [{'start': 1.0, 'end': 2.0, 'wrench': [10, 0, 0, 0, 0, 0]},
                            {'start': 1.5, 'wrench': [0, 0, 5, 0, 0, 1]}]})
    d = scn.disturbances
    assert d.com_error == (0.01, 0.0, 0.005) and d.current == (0.1, 0.0, 0.0)
    assert d.current_std == (0.02, 0.0, 0.0) and d.seed == 7
    assert d.current_time_constant == (30.0, 60.0, 60.0)
    pulses = d.external_wrench
    assert isinstance(pulses, WrenchPulses)
    np.testing.assert_array_equal(pulses(0.5), np.zeros(6))
    np.testing.assert_array_equal(pulses(1.0), [10, 0, 0, 0, 0, 0])     # [start, end)
    np.testing.assert_array_equal(pulses(1.7), [10, 0, 5, 0, 0, 1])     # overlap adds
    np.testing.assert_array_equal(pulses(2.0), [0, 0, 5, 0, 0, 1])
    np.testing.assert_array_equal(pulses(1e6), [0, 0, 5, 0, 0, 1])      # no end: forever
    const = _scenario({}, disturbances={'external_wrench': [1, 2, 3, 4, 5, 6]})
    assert const.disturbances.external_wrench == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)


def test_robot_overrides_are_applied_and_validated() -> None:
    base = load_robot_params()
    scn = _scenario({}, robot={'tilt_rate_limit': 1.0, 'max_thrust': 30})
    robot = scn.robot(base)
    assert robot.tilt_rate_limit == 1.0 and robot.max_thrust == 30.0
    assert robot.mass_matrix == base.mass_matrix
    assert _scenario({}).robot(base) is base
    bad = _scenario({}, robot={'tilt_rate_limit': -1.0})
    with pytest.raises(ParameterError, match='tilt_rate_limit') as info:
        bad.robot(base)
    assert 'test.yaml' in str(info.value)


# --------------------------------------------------------------------------- errors

GOOD = {'duration': 10.0, 'reference': {'pitch': [{'type': 'ramp', 'from': 0, 'to': -30,
                                                    'duration': 5}]}}


@pytest.mark.parametrize(('change', 'where'), [
    ({'duration': -1.0}, 'duration'),
    ({'duration': 'long'}, 'duration'),
    ({'duration': None}, 'duration'),
    ({'angle_unit': 'grad'}, 'angle_unit'),
    ({'speed': 1}, 'top level'),
    ({'reference': {'surge': []}}, 'reference'),
    ({'reference': {'x': 3.0}}, 'reference.x'),
    ({'reference': {'x': [{'type': 'parabola'}]}}, 'reference.x[0]'),
    ({'reference': {'x': [{'value': 1.0}]}}, 'reference.x[0]'),
    ({'reference': {'x': [{'type': 'ramp', 'from': 0, 'duration': 1}]}}, 'reference.x[0]'),
    ({'reference': {'x': [{'type': 'ramp', 'from': 0, 'to': 1, 'duration': 0}]}},
     'reference.x[0].duration'),
    ({'reference': {'x': [{'type': 'constant', 'value': 1, 'at': 2}]}}, 'reference.x[0]'),
    ({'reference': {'z': [{'type': 'constant', 'value': 0},
                          {'type': 'sine', 'amplitude': 'big', 'omega': 1}]}},
     'reference.z[1].amplitude'),
    ({'reference': {'z': [{'type': 'sine', 'amplitude': 1, 'omega': 1, 'start': 5,
                           'end': 4}]}}, 'reference.z[0].end'),
    ({'disturbances': {'com_error': [0.01, 0.0]}}, 'disturbances'),
    ({'disturbances': {'wind': 3}}, 'disturbances'),
    ({'disturbances': {'external_wrench': [{'start': 2, 'end': 1, 'wrench': [0] * 6}]}},
     'disturbances.external_wrench[0].end'),
    ({'disturbances': {'external_wrench': [{'start': 0, 'wrench': [0] * 5}]}},
     'disturbances.external_wrench[0].wrench'),
    ({'initial_state': {'euler': [0, 0]}}, 'initial_state.euler'),
    ({'initial_state': {'position': [0, 'a', 0]}}, 'initial_state.position[1]'),
    ({'initial_state': {'speed': 1}}, 'initial_state'),
    ({'robot': {'mass': 3}}, 'robot'),
])
def test_errors_name_the_file_and_the_key(tmp_path: Path, change: dict, where: str) -> None:
    doc = {**GOOD, **change}
    if doc.get('duration') is None:
        del doc['duration']
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert message.startswith(f'{path}: {where}'), message


def test_file_level_errors(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r'no scenario named .nonesuch.*pitch_hold'):
        load_scenario('nonesuch')
    with pytest.raises(ScenarioError, match='not found'):
        load_scenario(tmp_path / 'missing.yaml')
    broken = tmp_path / 'broken.yaml'
    broken.write_text('duration: [1, 2\nreference: {}\n')
    with pytest.raises(ScenarioError, match='not valid YAML'):
        load_scenario(broken)
    listing = tmp_path / 'list.yaml'
    listing.write_text('- 1\n- 2\n')
    with pytest.raises(ScenarioError, match='a scenario is a YAML mapping'):
        load_scenario(listing)


def test_a_file_anywhere_loads_and_its_name_defaults_to_the_stem(tmp_path: Path) -> None:
    path = tmp_path / 'my_dive.yaml'
    path.write_text(yaml.safe_dump(GOOD))
    scn = load_scenario(path)
    assert scn.name == 'my_dive' and scn.source == str(path) and scn.duration == 10.0
    assert _dof(scn, 5.0, 4)[0] == pytest.approx(-30.0)      # angle_unit defaults to rad


# --------------------------------------------------------------------------- shipped files


def test_shipped_scenarios() -> None:
    assert {'pitch_hold', 'pitch_hold_slow_servo', 'trajectory'} <= set(scenario_names())
    for name in scenario_names():
        assert load_scenario(name).name == name


@pytest.mark.parametrize('name', ['pitch_hold', 'pitch_hold_slow_servo'])
def test_pitch_hold_is_section_4_1(name: str) -> None:
    # Pitch 0 -> -30 deg within 30 s, then held; everything else 0; 60 s;
    # the center-of-mass modeling error as the disturbance.
    scn = load_scenario(name)
    assert scn.duration == 60.0
    for t, pitch in ((0.0, 0.0), (15.0, -15.0), (30.0, -30.0), (59.95, -30.0)):
        eta, _ = scn.reference.eta(t)
        np.testing.assert_allclose(eta, [0, 0, 0, 0, pitch * DEG, 0], atol=1e-12)
    assert scn.reference.eta(10.0)[1][4] == pytest.approx(-DEG)
    assert any(v != 0.0 for v in scn.disturbances.com_error)
    robot = scn.robot(load_robot_params())
    expected = 150.0 if name == 'pitch_hold' else 60.0
    assert math.degrees(robot.tilt_rate_limit) == pytest.approx(expected)


def test_trajectory_is_section_4_2_as_documented() -> None:
    scn = load_scenario('trajectory')
    assert scn.duration == 120.0
    omega = 0.025 * math.pi
    for t in (0.0, 20.0, 40.0, 77.7, 120.0):
        eta, rate = scn.reference.eta(t)
        np.testing.assert_allclose(eta, [t / 120.0, 0.0, -t / 120.0 + 0.4 * math.sin(omega * t),
                                         0, 0, 0], atol=1e-12)
        if 0.0 < t < 120.0:                             # away from the ramps' kinks
            np.testing.assert_allclose(rate[[0, 2]], [1 / 120.0, -1 / 120.0
                                                      + 0.4 * omega * math.cos(omega * t)],
                                       atol=1e-12)
    end, _ = scn.reference.eta(120.0)
    np.testing.assert_allclose(end[:3], [1.0, 0.0, -1.0], atol=1e-12)


def test_faults_are_parsed_and_checked(tmp_path) -> None:
    from tiltrov_ros.core.scenarios import ThrusterFault, failed_at

    scn = load_scenario('thruster_failure')
    assert scn.faults == (ThrusterFault(1, 40.0, 0.0),)
    faults = (ThrusterFault(1, 40.0, 0.5), ThrusterFault(3, 10.0))
    assert failed_at(faults, 9.99) == () and failed_at(faults, 40.0) == (1, 3)
    assert failed_at(faults, 40.0, detected=True) == (3,)
    assert failed_at(faults, 40.5, detected=True) == (1, 3)
    for fault, message in [('{thruster: 5, at: 1.0}', r'faults\[0\]\.thruster: got 5'),
                           ('{thruster: 2}', "needs 'at'"),
                           ('{thruster: 2, at: -1}', 'must be >= 0'),
                           ('{thruster: 2, at: 1, when: 3}', "unknown key 'when'")]:
        path = tmp_path / 'bad.yaml'
        path.write_text(f'duration: 1.0\nfaults:\n  - {fault}\n')
        with pytest.raises(ScenarioError, match=message):
            load_scenario(path)
