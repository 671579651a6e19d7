"""Campaign files (pure part): parsing, one-line errors, samples, the hold criterion."""

from __future__ import annotations

import copy
import math
from pathlib import Path
import subprocess
import sys
from typing import Any

import numpy as np
import pytest
import yaml

from tiltrov_ros.core.campaign import (
    draw_sample,
    draw_samples,
    load_campaign,
    metrics_template,
    parse_campaign,
)
from tiltrov_ros.core.errors import CampaignError
from tiltrov_ros.core.scenarios import Scenario, load_scenario
from tiltrov_ros.paths import config_dir

DEG = math.pi / 180.0
STATION_KEEPING = config_dir() / 'campaigns' / 'station_keeping.yaml'

GOOD: dict[str, Any] = {
    'name': 'good', 'seed': 5, 'samples': 3, 'duration': 4.0, 'angle_unit': 'deg',
    'reference': {'x': [{'type': 'step', 'at': 0.0, 'value': {'uniform': [-0.5, 0.5]}}],
                  'yaw': {'type': 'ramp', 'from': 0, 'to': {'choice': [10, 20]},
                          'duration': 2.0}},
    'disturbances': {'current': {'speed': {'uniform': [0.0, 0.3]},
                                 'direction': {'uniform': [0, 360]}},
                     'current_std': [0.01, 0.01, {'normal': [0.0, 0.0]}],
                     'com_error': {'magnitude': 0.01},
                     'external_wrench': [{'probability': 0.5, 'start': {'uniform': [1, 2]},
                                          'duration': 0.5, 'wrench': [0, 5, 0, 0, 0, 1]}]},
    'robot': {'tilt_rate_limit': {'uniform': [60, 150]}, 'max_thrust': 35.0},
    'faults': {'probability': 0.5, 'thruster': {'choice': [2, 3]}, 'at': 1.0},
    'compare': {'controllers': ['pd', 'pid'], 'allocators': ['robust', 'paper'],
                'gains': {'shipped': {}, 'soft': {'kp': [50, 50, 50, 10, 10, 10]}}},
    'hold': [{'metric': 'oscillation_std', 'position': 0.005, 'angle': 0.5},
             {'metric': 'final_error', 'x': 0.1, 'controllers': ['pd']},
             {'metric': 'infeasible_fraction', 'max': 0.5, 'allocators': 'paper'}],
}


def _spec(change: dict[str, Any] | None = None, tmp_path: Path | None = None) -> Any:
    doc = copy.deepcopy(GOOD)
    doc.update(change or {})
    if tmp_path is None:
        return parse_campaign(doc, source='good.yaml')
    path = tmp_path / 'camp.yaml'
    path.write_text(yaml.safe_dump(doc))
    return load_campaign(path)


# --------------------------------------------------------------------------- the shipped file


def test_station_keeping_is_the_documented_campaign() -> None:
    spec = load_campaign(STATION_KEEPING)
    assert spec.samples >= 50 and spec.duration == 60.0
    assert [c.name for c in spec.configurations] == ['pd-robust', 'pid-robust']
    bounds = {(b.metric, b.controllers): dict(b.limits) for b in spec.hold}
    settle = bounds[('oscillation_std', ())]
    assert [settle[d] for d in ('x', 'y', 'z')] == [0.005] * 3
    assert [settle[d] for d in ('roll', 'pitch', 'yaw')] == pytest.approx([0.5 * DEG] * 3)
    assert bounds[('final_error', ('pid',))] == pytest.approx(
        {'x': 0.05, 'y': 0.05, 'z': 0.05, 'roll': 2 * DEG, 'pitch': 2 * DEG, 'yaw': 2 * DEG})
    assert bounds[('final_error', ('pd',))] == {'x': 0.1, 'y': 0.1, 'z': 0.1}
    for sample in draw_samples(spec, 100):
        p = sample.params
        assert 0.0 <= p['current_speed'] <= 0.3 and 0.0 <= p['current_direction'] < 360.0
        assert 0.0 <= p['disturbances.com_error.magnitude'] <= 0.01
        assert 60.0 <= p['robot.tilt_rate_limit'] <= 150.0
        limits = {'x': 1.0, 'y': 1.0, 'z': 0.5, 'pitch': 30.0, 'yaw': 90.0}
        for dof, limit in limits.items():
            assert abs(p[f'reference.{dof}[0].value']) <= limit
            present = len(sample.document['reference'][dof]) == 1
            assert present == (p[f'reference.{dof}[0].occurs'] == 1.0)
            if present:
                assert sample.document['reference'][dof][0]['at'] == 10.0
        scenario = sample.scenario()
        (key, rate), = scenario.robot_overrides
        assert key == 'tilt_rate_limit' and rate == pytest.approx(p[f'robot.{key}'] * DEG)
        assert np.linalg.norm(scenario.disturbances.com_error) == pytest.approx(
            p['disturbances.com_error.magnitude'], abs=1e-15)


# --------------------------------------------------------------------------- samples


def test_a_reference_term_with_a_probability_is_in_some_samples_only() -> None:
    doc = {**GOOD, 'reference': {'x': [{'type': 'step', 'probability': 0.25, 'at': 1.0,
                                        'value': {'uniform': [0.5, 1.0]}}]}}
    samples = draw_samples(parse_campaign(doc, source='good.yaml'), 400)
    present = [s for s in samples if s.document['reference']['x']]
    assert 0.18 < len(present) / len(samples) < 0.32          # seeded: the same every run
    for s in samples:           # drawn every time: the same columns, the value recorded
        assert 0.5 <= s.params['reference.x[0].value'] <= 1.0
        assert s.params['reference.x[0].occurs'] == (1.0 if s in present else 0.0)
        final = s.scenario().reference.at(2.0)[0][0]
        assert final == (s.params['reference.x[0].value'] if s in present else 0.0)
    with pytest.raises(CampaignError, match=r'reference.x\[0\].probability'):
        parse_campaign({**doc, 'reference': {'x': [{'type': 'step', 'probability': 2.0,
                                                     'value': 1.0}]}}, source='good.yaml')



def test_a_sample_depends_only_on_the_seed_and_its_index() -> None:
    spec = _spec()
    many = draw_samples(spec, 6)
    assert draw_sample(spec, 4) == many[4]
    assert draw_samples(spec, 2) == many[:2]
    assert len({yaml.safe_dump(s.document) for s in many}) == 6
    other = parse_campaign({**GOOD, 'seed': 6}, source='good.yaml')
    assert draw_sample(other, 4).params != many[4].params
    assert all(list(s.params) == list(many[0].params) for s in many)   # same columns


def test_a_sample_is_its_scenario_file() -> None:
    for sample in draw_samples(_spec(), 8):
        text = yaml.safe_dump(sample.document, sort_keys=False)
        again = Scenario.from_mapping(yaml.safe_load(text))
        assert again == sample.scenario()
        assert again.name == f'good-s{sample.index:05d}'


def test_drawn_values_reach_the_scenario() -> None:
    spec = _spec()
    pulses = faults = 0
    for sample in draw_samples(spec, 40):
        p, scenario = sample.params, sample.scenario()
        eta, _ = scenario.reference.eta(3.0)
        assert eta[0] == p['reference.x[0].value']
        assert eta[5] == pytest.approx(p['reference.yaw[0].to'] * DEG)
        assert p['reference.yaw[0].to'] in (10.0, 20.0)
        heading = p['disturbances.current.direction'] * DEG
        assert scenario.disturbances.current == pytest.approx(
            (p['current_speed'] * math.cos(heading), p['current_speed'] * math.sin(heading), 0.0))
        assert scenario.disturbances.current_std == (0.01, 0.01, 0.0)
        assert scenario.disturbances.seed == p['disturbances.seed']
        assert dict(scenario.robot_overrides) == {
            'max_thrust': 35.0, 'tilt_rate_limit': pytest.approx(
                p['robot.tilt_rate_limit'] * DEG)}
        wrench = scenario.disturbances.external_wrench
        start = p['disturbances.external_wrench[0].start']
        if p['disturbances.external_wrench[0].occurs']:
            pulses += 1
            assert list(wrench(start + 0.25)) == [0, 5, 0, 0, 0, 1]  # type: ignore[operator]
            assert list(wrench(start + 0.5)) == [0] * 6               # type: ignore[operator]
        else:
            assert not callable(wrench) and wrench == (0.0,) * 6
        if p['faults.occurs']:
            faults += 1
            (fault,) = scenario.faults
            assert fault.index + 1 == p['faults.thruster'] in (2.0, 3.0) and fault.at == 1.0
        else:
            assert scenario.faults == ()
    assert 5 < pulses < 35 and 5 < faults < 35         # probability 0.5 each, 40 draws


def test_base_scenarios_keep_their_parts_and_units(tmp_path: Path) -> None:
    base = tmp_path / 'base.yaml'
    base.write_text(yaml.safe_dump({
        'duration': 9.0, 'angle_unit': 'deg',
        'reference': {'pitch': [{'type': 'constant', 'value': -30}]},
        'disturbances': {'external_wrench': [0, 0, 1, 0, 0, 0]},
        'faults': [{'thruster': 1, 'at': 5.0}]}))
    doc = {'name': 'on_base', 'seed': 1, 'angle_unit': 'rad', 'base': ['base.yaml', 'pitch_hold'],
           'reference': {'pitch': [{'type': 'step', 'at': 1.0, 'value': 0.1}]},
           'disturbances': {'external_wrench': [{'start': 2, 'duration': 1,
                                                 'wrench': [3, 0, 0, 0, 0, 0]}]},
           'faults': {'probability': 1.0, 'thruster': 4, 'at': 3.0}}
    path = tmp_path / 'camp.yaml'
    path.write_text(yaml.safe_dump(doc))
    spec = load_campaign(path)
    first, second = draw_samples(spec, 2)
    assert (first.params['base'], second.params['base']) == ('base', 'pitch_hold')
    scenario = first.scenario()
    assert scenario.duration == 9.0                                  # the base's
    assert scenario.reference.eta(2.0)[0][4] == pytest.approx(-30 * DEG + 0.1)
    wrench = scenario.disturbances.external_wrench
    assert list(wrench(2.5)) == [3, 0, 1, 0, 0, 0]                   # type: ignore[operator]
    assert [(f.index, f.at) for f in scenario.faults] == [(0, 5.0), (3, 3.0)]
    shipped = load_scenario('pitch_hold')
    assert second.scenario().duration == shipped.duration
    assert second.scenario().reference.eta(40.0)[0][4] == pytest.approx(
        shipped.reference.eta(40.0)[0][4] + 0.1)


# --------------------------------------------------------------------------- configurations, hold


def test_configurations_cross_controllers_allocators_and_gain_sets() -> None:
    spec = _spec()
    names = [c.name for c in spec.configurations]
    assert names[:2] == ['pd-robust-shipped', 'pd-robust-soft'] and len(names) == 8
    assert spec.configuration('pid-paper-soft').controller == 'pid'
    # a bound may name a controller not compared; allocators and gain sets must be compared
    alone = _spec({'compare': {'controllers': ['pid']}, 'hold': GOOD['hold'][:2]})
    assert [c.name for c in alone.configurations] == ['pid-robust']
    with pytest.raises(CampaignError, match='no configuration'):
        spec.configuration('pd')


def test_robot_factors_are_configurations_whose_levels_set_the_robot() -> None:
    from tiltrov_ros.campaign.plan import Plan, counterfactual

    factors = {'servo_range': {'deg90': {'tilt_min': -90, 'tilt_max': 90},
                               'deg180': {'tilt_min': -180, 'tilt_max': 180}},
               'servo_rate': {'slow': {'tilt_rate_limit': 60}}}
    spec = _spec({'compare': {'controllers': ['pd', 'pid'], 'robot': factors},
                  'faults': None, 'hold': GOOD['hold'][:2]})
    assert [c.name for c in spec.configurations] == [
        'pd-robust-deg90-slow', 'pd-robust-deg180-slow', 'pid-robust-deg90-slow',
        'pid-robust-deg180-slow']
    assert spec.factors == (('servo_range', ('deg90', 'deg180')), ('servo_rate', ('slow',)))
    wide = spec.configuration('pid-robust-deg180-slow')
    assert wide.levels == ('deg180', 'slow')
    assert dict(wide.robot) == pytest.approx({'tilt_min': -math.pi, 'tilt_max': math.pi,
                                              'tilt_rate_limit': 60 * DEG})
    sample = draw_sample(spec, 0)
    plan = Plan(spec)
    narrow, full = (plan.stack(sample, spec.configuration(f'pd-robust-{r}-slow'))
                    for r in ('deg90', 'deg180'))
    # The levels go over the drawn servo rate and the robot file; the rest as drawn.
    assert narrow.robot.tilt_max == pytest.approx(math.pi / 2)
    assert narrow.robot.tilt_rate_limit == full.robot.tilt_rate_limit == pytest.approx(60 * DEG)
    assert narrow.robot.max_thrust == full.robot.max_thrust == 35.0
    assert narrow.scenario == full.scenario
    # The counterfactual of a run: the same with servos all the way round; none for those.
    again = counterfactual(narrow)
    assert again is not None and again.robot == full.robot and again.scenario == narrow.scenario
    assert counterfactual(full) is None
    tasks = plan.tasks([sample])
    assert [t.counterfactual is None for t in tasks] == [False, True, False, True]
    assert [len(t.bounds) for t in tasks] == [2, 2, 1, 1]      # the pd bound is pd's


def test_the_verdict_of_a_run() -> None:
    """physics first (not produced on the full circle, or its wander beyond the full
    circle's reach), then servo_range (not produced within the range, or its wander
    beyond the range's reach where the full circle follows it), else control; the
    counterfactual run is no part of it."""
    from tiltrov_ros.core.campaign import verdict
    from tiltrov_ros.core.hold import Reach

    reachable = _metrics(steady_shortfall_ratio=0.2, steady_shortfall_ratio_full_circle=0.2)
    narrow = _metrics(steady_shortfall_ratio=3.0, steady_shortfall_ratio_full_circle=0.2)
    hole = _metrics(steady_shortfall_ratio=3.0, steady_shortfall_ratio_full_circle=3.0)
    followed, lost, beyond = Reach(True), Reach(False, True), Reach(False, False)
    assert verdict(True, hole, beyond) == 'held'
    assert verdict(False, hole, None) == verdict(False, hole, followed) == 'physics'
    assert verdict(False, reachable, beyond) == 'physics'     # no servo follows it
    assert verdict(False, narrow, None) == verdict(False, narrow, followed) == 'servo_range'
    assert verdict(False, reachable, lost) == 'servo_range'   # the range's reach
    assert verdict(False, reachable, Reach(False)) == 'servo_range'
    assert verdict(False, reachable, followed) == 'control'
    assert verdict(False, reachable, None) == verdict(False, reachable, Reach()) == 'control'
    assert verdict(False, _metrics(), None) == 'control'      # no oracle: not physics
    assert verdict(False, None, None) == 'control'            # the run raised


def test_a_hold_file_and_a_campaign_file_give_a_hold_criterion(tmp_path: Path) -> None:
    from tiltrov_ros.core.campaign import load_hold

    shipped = load_hold(STATION_KEEPING)
    assert shipped.name == 'station_keeping' and len(shipped.bounds) == 3
    assert [len(shipped.applicable(c, 'robust')) for c in ('pd', 'pid', 'switching')] == [2, 2, 1]
    file = tmp_path / 'mine.yaml'
    file.write_text(yaml.safe_dump({'angle_unit': 'deg', 'hold': [
        {'metric': 'final_error', 'angle': 3.0, 'gains': ['soft'], 'allocators': ['paper']}]}))
    mine = load_hold(file)
    assert mine.name == 'mine' and dict(mine.bounds[0].limits)['yaw'] == pytest.approx(3 * DEG)
    assert mine.applicable('pd', 'paper', 'soft') == mine.bounds
    assert mine.applicable('pd', 'robust', 'soft') == () == mine.applicable('pd', 'paper')
    file.write_text(yaml.safe_dump({'hold': [{'metric': 'hold', 'max': 1}]}))
    with pytest.raises(CampaignError, match=r"mine.yaml: hold\[0\].metric: got 'hold'"):
        load_hold(file)
    file.write_text(yaml.safe_dump({'name': 'x'}))
    with pytest.raises(CampaignError, match=r'mine\.yaml: hold: missing'):
        load_hold(file)
    with pytest.raises(CampaignError, match='not found'):
        load_hold(tmp_path / 'none.yaml')


def _metrics(**changes: Any) -> dict[str, Any]:
    metrics = copy.deepcopy(dict(metrics_template()))
    for key in ('oscillation_std', 'final_error'):
        metrics[key] = dict.fromkeys(metrics[key], 0.0)
    metrics['infeasible_fraction'] = 0.0
    for key, value in changes.items():
        group, _, dof = key.partition('__')
        if dof:
            metrics[group][dof] = value
        else:
            metrics[group] = value
    return metrics


def test_hold_bounds_apply_to_their_configurations() -> None:
    spec = _spec()
    pd, pid_paper = spec.configuration('pd-robust-soft'), spec.configuration('pid-paper-soft')
    assert spec.violations(pd, _metrics()) == []
    assert spec.violations(pd, _metrics(oscillation_std__yaw=0.6 * DEG)) == [
        f'oscillation_std.yaw {0.6 * DEG:.4g} > {0.5 * DEG:.4g}']
    assert spec.violations(pd, _metrics(final_error__x=0.2)) == ['final_error.x 0.2 > 0.1']
    assert spec.violations(pid_paper, _metrics(final_error__x=0.2)) == []   # pd only
    assert spec.violations(pid_paper, _metrics(infeasible_fraction=0.7)) == [
        'infeasible_fraction 0.7 > 0.5']
    assert spec.violations(pd, _metrics(infeasible_fraction=0.7)) == []     # paper only
    assert spec.violations(pd, _metrics(oscillation_std__z=None)) == ['oscillation_std.z is null']
    assert spec.violations(pd, _metrics(final_error__x=math.nan)) == ['final_error.x nan > 0.1']


def test_settling_time_bounds_are_seconds_even_for_angles() -> None:
    spec = _spec({'hold': [{'metric': 'settling_time', 'angle': 5.0}]})
    assert dict(spec.hold[0].limits) == {'roll': 5.0, 'pitch': 5.0, 'yaw': 5.0}


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(('change', 'where'), [
    ({'sedd': 1}, 'top level'),
    ({'seed': -1}, 'seed'),
    ({'seed': None}, 'seed'),
    ({'samples': 0}, 'samples'),
    ({'duration': 0}, 'duration'),
    ({'duration': None}, 'duration'),
    ({'angle_unit': 'grad'}, 'angle_unit'),
    ({'name': 'has space'}, 'name'),
    ({'base': ['no_such_scenario']}, 'base[0]'),
    ({'reference': {'surge': []}}, 'reference'),
    ({'reference': {'x': [{'value': 1}]}}, 'reference.x[0]'),
    ({'reference': {'x': [{'type': 'step', 'at': 0, 'value': {'uniform': [1]}}]}},
     'reference.x[0].value.uniform'),
    ({'reference': {'x': [{'type': 'step', 'at': 0, 'value': {'uniform': [2, 1]}}]}},
     'reference.x[0].value.uniform'),
    ({'reference': {'x': [{'type': 'step', 'at': 0, 'value': {'gauss': [0, 1]}}]}},
     'reference.x[0].value'),
    ({'reference': {'x': [{'type': 'step', 'at': 0, 'value': {'normal': [0, -1]}}]}},
     'reference.x[0].value.normal'),
    ({'reference': {'x': [{'type': 'step', 'at': 0, 'value': {'choice': []}}]}},
     'reference.x[0].value.choice'),
    ({'reference': {'x': [{'type': 'step', 'at': 0, 'value': 'far'}]}}, 'reference.x[0].value'),
    ({'disturbances': {'wind': 1}}, 'disturbances'),
    ({'disturbances': {'current': {'speed': 0.1}}}, 'disturbances.current'),
    ({'disturbances': {'current': [0.1, 0.2]}}, 'disturbances.current'),
    ({'disturbances': {'com_error': {'size': 0.01}}}, 'disturbances.com_error'),
    ({'disturbances': {'external_wrench': [{'start': 1, 'duration': 1, 'wrench': [0] * 5}]}},
     'disturbances.external_wrench[0].wrench'),
    ({'disturbances': {'external_wrench': [{'probability': 2, 'start': 1, 'duration': 1,
                                            'wrench': [0] * 6}]}},
     'disturbances.external_wrench[0].probability'),
    ({'robot': {'mass': 3}}, 'robot'),
    ({'faults': {'at': 1, 'thruster': 5}}, 'faults.thruster'),
    ({'faults': {'thruster': 1}}, 'faults'),
    ({'compare': {'controllers': ['pdd']}}, 'compare.controllers[0]'),
    ({'compare': {'controllers': ['pd', 'pd']}}, 'compare.controllers'),
    ({'compare': {'gains': {'soft': {'kp': [1, 2]}}}}, 'compare.gains.soft.kp'),
    ({'compare': {'gains': {'soft': {'kq': [1] * 6}}}}, 'compare.gains.soft'),
    ({'compare': {'gains': []}}, 'compare.gains'),
    ({'compare': {'robot': []}}, 'compare.robot'),
    ({'compare': {'robot': {'range': {}}}}, 'compare.robot.range'),
    ({'compare': {'robot': {'range': {'r90': {}}}}}, 'compare.robot.range.r90'),
    ({'compare': {'robot': {'range': {'r90': {'tilt_mx': 90}}}}}, 'compare.robot.range.r90'),
    ({'compare': {'robot': {'range': {'r90': {'tilt_max': {'uniform': [80, 90]}}}}}},
     'compare.robot.range.r90.tilt_max'),
    ({'compare': {'robot': {'range': {'r 90': {'tilt_max': 90}}}}}, 'compare.robot.range[0]'),

    ({'hold': [{'metric': 'final_eror', 'x': 1}]}, 'hold[0].metric'),
    ({'hold': [{'metric': 'final_error'}]}, 'hold[0]'),
    ({'hold': [{'metric': 'final_error', 'front': 1}]}, 'hold[0]'),
    ({'hold': [{'metric': 'wrench_error_rms', 'x': 1}]}, 'hold[0]'),
    ({'hold': [{'metric': 'wrench_error_rms'}]}, 'hold[0]'),
    ({'hold': [{'metric': 'final_error', 'x': 1, 'controllers': ['pdi']}]},
     'hold[0].controllers[0]'),
    ({'hold': [{'metric': 'final_error', 'x': 1, 'allocators': ['robst']}]},
     'hold[0].allocators[0]'),
])
def test_errors_name_the_file_and_the_key(tmp_path: Path, change: dict[str, Any],
                                          where: str) -> None:
    doc = {**copy.deepcopy(GOOD), **change}
    for key in [k for k, v in doc.items() if v is None]:
        del doc[key]
    path = tmp_path / 'bad.yaml'
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(CampaignError) as info:
        load_campaign(path)
    message = str(info.value)
    assert message.startswith(f'{path}: {where}: '), message
    assert '\n' not in message


def test_file_level_errors(tmp_path: Path) -> None:
    with pytest.raises(CampaignError, match='campaign file not found'):
        load_campaign(tmp_path / 'missing.yaml')
    broken = tmp_path / 'broken.yaml'
    broken.write_text('seed: [1, 2\n')
    with pytest.raises(CampaignError, match='not valid YAML'):
        load_campaign(broken)
    listing = tmp_path / 'list.yaml'
    listing.write_text('- 1\n')
    with pytest.raises(CampaignError, match='a campaign is a YAML mapping'):
        load_campaign(listing)


def test_what_the_scenario_parser_checks_is_checked_on_sample_0(tmp_path: Path) -> None:
    with pytest.raises(CampaignError,
                       match=r'camp.yaml \(sample 0\): reference.x\[0\]: unknown key .vale.'):
        _spec({'reference': {'x': [{'type': 'step', 'at': 0, 'value': 1, 'vale': 2}]}},
              tmp_path)


def test_a_draw_the_scenario_rejects_names_the_sample() -> None:
    spec = _spec({'seed': 1, 'reference': {'x': [{'type': 'ramp', 'from': 0, 'to': 1,
                                                  'duration': {'choice': [1.0, -1.0]}}]}})
    assert draw_sample(spec, 0).params['reference.x[0].duration'] == 1.0
    assert draw_sample(spec, 2).params['reference.x[0].duration'] == -1.0
    with pytest.raises(CampaignError, match=r'^good.yaml \(sample 2\): reference.x\[0\].duration'):
        draw_sample(spec, 2).scenario('good.yaml (sample 2)')


def test_the_pure_part_imports_neither_dask_nor_matplotlib_nor_ros() -> None:
    code = ('import sys, tiltrov_ros.core.campaign as c\n'
            "c.draw_samples(c.load_campaign(sys.argv[1]), 3)\n"
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
            "{'dask', 'distributed', 'matplotlib', 'rclpy'})\n"
            'print(bad)\n'
            'sys.exit(1 if bad else 0)\n')
    result = subprocess.run([sys.executable, '-c', code, str(STATION_KEEPING)],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
