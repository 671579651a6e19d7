"""The compiled allocation answers as the numpy reference on calls captured from runs.

A headless run (:func:`tiltrov_ros.core.runner.run`) with the reference
allocator behind a recording wrapper gives the calls a robot really makes
(``allocate`` and ``allocate_fixed`` with the ``previous`` it chained); each
is then answered by the kernels and compared with :class:`kernel_equality.Tally`.
Runs: ``current_hold`` (pid: the current keeps the wrench unattainable) and
samples of ``config/campaigns/station_keeping.yaml`` (pd and pid), shortened.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from kernel_equality import Tally, needs_kernels
import numpy as np
import pytest

from tiltrov_ros.campaign.plan import Plan
from tiltrov_ros.core.allocation import AllocationResult, ThrustAllocator
from tiltrov_ros.core.campaign import draw_sample, load_campaign
from tiltrov_ros.core.runner import StackConfig, run, stack_config
from tiltrov_ros.paths import config_file

pytestmark = needs_kernels


@dataclass
class Recording:
    """The reference allocator of a run, keeping every call and its answer."""

    inner: ThrustAllocator
    calls: list[tuple[np.ndarray, tuple[float, float] | None, AllocationResult | None,
                      AllocationResult]] = field(default_factory=list)

    def allocate(self, wrench: Any, previous: AllocationResult | None = None
                 ) -> AllocationResult:
        tau = np.array(wrench, dtype=float)
        result = self.inner.allocate(tau, previous)
        self.calls.append((tau, None, previous, result))
        return result

    def allocate_fixed(self, wrench: Any, tilt_front: float, tilt_rear: float,
                       previous: AllocationResult | None = None) -> AllocationResult:
        tau = np.array(wrench, dtype=float)
        result = self.inner.allocate_fixed(tau, tilt_front, tilt_rear, previous)
        self.calls.append((tau, (tilt_front, tilt_rear), previous, result))
        return result


def _replay(config: StackConfig, duration: float, tally: Tally, where: str) -> dict[str, int]:
    """Run ``config`` headless on the reference, answer every call with the kernels."""
    recordings: list[Recording] = []

    def allocator(failed: tuple[int, ...] = ()) -> Recording:
        alloc = config.build_allocator(failed)
        recordings.append(Recording(ThrustAllocator(
            alloc.length, alloc.width, alloc.max_thrust, alloc.tilt_limits,
            alloc.max_tilt_step, alloc.mode, tuple(alloc.weights), alloc.failed_thrusters,
            alloc.motion_penalty, alloc.planning, alloc.horizon, backend='numpy')))
        return recordings[-1]

    run(config.build_plant(), config.build_controller(), allocator(),
        config.scenario.reference.at, duration, control_period_ns=config.control_period_ns,
        faults=config.scenario.faults, rebuild_allocator=allocator)
    methods: dict[str, int] = {}
    for recording in recordings:
        ref = recording.inner
        ker = ThrustAllocator(ref.length, ref.width, ref.max_thrust, ref.tilt_limits,
                              ref.max_tilt_step, ref.mode, tuple(ref.weights),
                              ref.failed_thrusters, ref.motion_penalty, ref.planning,
                              ref.horizon, backend='numba')
        for i, (tau, fixed, previous, result) in enumerate(recording.calls):
            answer = (ker.allocate(tau, previous) if fixed is None
                      else ker.allocate_fixed(tau, *fixed, previous=previous))
            tally.same(ref, result, answer, f'{where} call {i}', previous)
            methods[result.method] = methods.get(result.method, 0) + 1
    return methods


def test_current_hold_pid() -> None:
    tally = Tally()
    methods = _replay(stack_config('current_hold', 'pid'), 25.0, tally, 'current_hold pid')
    assert tally.calls == 500
    assert methods.get('optimized', 0) + methods.get('transit', 0) >= 100, methods
    tally.check_ties()


@pytest.mark.parametrize('sample', [0, 3, 7])
def test_station_keeping_campaign_samples(sample: int) -> None:
    spec = load_campaign(config_file('campaigns/station_keeping.yaml'))
    plan = Plan(spec)
    drawn = draw_sample(spec, sample)
    tally = Tally()
    for configuration in spec.configurations:
        _replay(plan.stack(drawn, configuration), 15.0, tally,
                f'station_keeping sample {sample} {configuration.name}')
    assert tally.calls == 300 * len(spec.configurations)
    tally.check_ties()
