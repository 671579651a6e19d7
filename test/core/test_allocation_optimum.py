"""The per-tick optimum against the project's own global reference.

Robust mode without the planner answers each call with the least weighted
wrench error within reach: exact whenever an exact solution lies within the
reachable tilts, otherwise the global optimum of the error over them (within
1 %), over the whole range (wrapping through +-90 deg) without ``previous``.
``global_reference.GlobalReference`` computes that optimum with none of the
allocator's machinery (grid, Nelder-Mead, branch and bound over eq. (5)).
"""

from __future__ import annotations

import math

from global_reference import GlobalReference
import numpy as np
import pytest

from tiltrov_ros.core.allocation import DEFAULT_WEIGHTS, ThrustAllocator
from tiltrov_ros.core.thrust_map import thrust_wrench

L, D, FMAX = 0.6, 0.4, 40.0
HALF_PI = 0.5 * math.pi
STEP = math.radians(7.5)
FULL = np.array([[-HALF_PI, HALF_PI]] * 2)
W = np.array(DEFAULT_WEIGHTS)


def _unattainable(seed: int, n: int) -> list[np.ndarray]:
    """Wrenches no configuration in range produces exactly (the paper mode's verdict):
    random six-DOF demands, sway + heave (a cone no tilt reaches), small ones."""
    rng = np.random.default_rng(seed)
    paper = ThrustAllocator(L, D, FMAX, mode='paper')
    out: list[np.ndarray] = []
    while len(out) < n:
        kind = rng.integers(3)
        if kind == 0:
            tau = rng.normal(size=6) * np.array([80, 80, 120, 25, 40, 30])
        elif kind == 1:
            tau = np.array([0.0, rng.uniform(-20, 20), rng.uniform(-60, 60), 0, 0, 0])
        else:
            tau = rng.normal(size=6) * np.array([10, 10, 20, 2, 3, 2])
        if not paper.allocate(tau).feasible:
            out.append(tau)
    return out


def _reachable(prev: np.ndarray, step: float) -> np.ndarray:
    return np.column_stack([np.maximum(-HALF_PI, prev - step), np.minimum(HALF_PI, prev + step)])


@pytest.mark.parametrize('with_previous', [False, True])
def test_exact_wherever_an_exact_solution_is_within_reach(with_previous: bool) -> None:
    rng = np.random.default_rng(21)
    alloc = ThrustAllocator(L, D, FMAX, max_tilt_step=STEP, planning=False)
    for _ in range(300):
        f = rng.uniform(-FMAX, FMAX, 4)
        tilts = rng.uniform(-HALF_PI, HALF_PI, 2)
        tau = thrust_wrench(f[None], tilts[:1], tilts[1:], L, D)[0]
        previous = None
        if with_previous:
            near = np.clip(tilts + rng.uniform(-STEP, STEP, 2), -HALF_PI, HALF_PI)
            previous = alloc.allocate_fixed(np.zeros(6), near[0], near[1])
        result = alloc.allocate(tau, previous)
        assert result.feasible, (tau, tilts)
        assert result.error <= 1e-6 * max(np.abs(tau).max(), FMAX)


@pytest.mark.slow
@pytest.mark.parametrize('case', ['no previous', 'previous, rate limit', 'previous, no limit'])
def test_within_one_percent_of_the_global_reference(case: str) -> None:
    """A few seeded wrenches per case (the reference takes seconds each); the same
    comparison on 30 wrenches without previous and 30 with previous and the rate
    limit (seed 3, a finer reference: rtol 0.5 %) had every one within 1 %."""
    seed, count = {'no previous': (1, 8), 'previous, rate limit': (2, 16),
                   'previous, no limit': (3, 8)}[case]
    step = STEP if case == 'previous, rate limit' else math.inf
    alloc = ThrustAllocator(L, D, FMAX, max_tilt_step=step, planning=False)
    reference = GlobalReference(L, D, FMAX, W)
    rng = np.random.default_rng(seed + 100)
    ratios = []
    for tau in _unattainable(seed, count):
        previous, box = None, FULL
        if case != 'no previous':
            prev = rng.uniform(-HALF_PI, HALF_PI, 2)
            previous = alloc.allocate_fixed(np.zeros(6), prev[0], prev[1])
            box = _reachable(prev, step) if math.isfinite(step) else FULL
        best = reference.optimum(tau, box, rtol=0.01, radius=math.radians(1.0), budget=20_000)
        result = alloc.allocate(tau, previous)
        assert np.all(result.tilts >= box[:, 0] - 1e-12)
        assert np.all(result.tilts <= box[:, 1] + 1e-12)
        ratios.append(result.error / max(best.error, 1e-12))
    ratios_arr = np.array(ratios)
    assert np.mean(ratios_arr <= 1.01) >= 0.99, ratios_arr
    assert ratios_arr.min() > 1 - 1e-6          # the reference is the optimum: never beaten
