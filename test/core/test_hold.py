"""metrics.json's ``hold`` (core/hold.py): which runs get one, by which criterion, and
its verdict (the same judgement a campaign's runs.csv makes)."""

from __future__ import annotations

from typing import Any

import pytest

from tiltrov_ros.core.bounds import Bound
from tiltrov_ros.core.hold import (
    HoldCriterion,
    Reach,
    judge,
    judged,
    needs_reach,
    shipped,
    verdict,
)
from tiltrov_ros.core.metrics import compute_metrics
from tiltrov_ros.core.runner import run_scenario, stack_config

TIGHT = HoldCriterion('tight', (Bound('final_error', (('x', 1e-9),)),))


def _run(scenario: str, controller: str, duration: float = 2.0) -> Any:
    return run_scenario(stack_config(scenario, controller), duration=duration)


def test_a_pd_or_pid_run_holding_a_still_setpoint_gets_a_hold() -> None:
    log = _run('current_hold', 'pid')
    metrics = compute_metrics(log)
    hold = metrics['hold']
    assert set(hold) == {'criterion', 'holds', 'verdict', 'reach', 'reach_full_circle'}
    assert hold['criterion'] == shipped().name == 'station_keeping'
    bounds = shipped().applicable('pid', 'robust')
    assert hold['holds'] == (not any(b.violations(metrics) for b in bounds))
    assert hold['verdict'] == verdict(hold['holds'], metrics,
                                      Reach(hold['reach'], hold['reach_full_circle']))
    assert log.meta['faults'] == []


def test_a_run_that_misses_gets_a_verdict_and_the_wander_oracle_only_when_needed() -> None:
    log = _run('current_hold', 'pd')
    metrics = compute_metrics(log, criterion=TIGHT)
    hold = metrics['hold']
    assert hold['criterion'] == 'tight' and hold['holds'] is False
    assert needs_reach(False, metrics) == (hold['reach'] is not None)
    assert (hold['reach_full_circle'] is None) == (hold['reach'] is not False)
    assert hold['verdict'] == verdict(False, metrics, Reach(hold['reach'],
                                                            hold['reach_full_circle']))
    assert hold['verdict'] in ('control', 'servo_range', 'physics')
    # Bounds given by the caller (a campaign's configuration) are used as they are.
    none = compute_metrics(log, criterion=TIGHT, bounds=())
    assert none['hold'] == {'criterion': 'tight', 'holds': True, 'verdict': 'held',
                            'reach': None, 'reach_full_circle': None}


@pytest.mark.parametrize(('scenario', 'controller'), [
    ('pitch_hold', 'switching'),          # the baseline fixes its tilts
    ('trajectory', 'pd'),                 # the setpoint moves at the end
    ('pitch_hold', 'pd'),                 # ... still ramping at 1 s
    ('thruster_failure', 'pid'),          # a thruster has failed
])
def test_other_runs_have_no_hold(scenario: str, controller: str) -> None:
    log = _run(scenario, controller, 1.0)
    assert compute_metrics(log)['hold'] is None


def test_a_run_without_a_known_fault_list_is_not_judged() -> None:
    """A recording made before the fault list was part of the run's description."""
    assert not judged({'controller': 'pd'}, True)
    assert judged({'controller': 'pd', 'faults': []}, True)
    assert not judged({'controller': 'pd', 'faults': []}, False)
    assert judge({}, {'controller': 'pd'}, (1.0, 0.0, 0.0, 0.0), TIGHT) is None
