"""Thrust allocation: exactness, limits, robustness, continuity, and the paper's errors."""

from __future__ import annotations

from dataclasses import replace
import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from tiltrov_ros.core.allocation import (
    DEFAULT_WEIGHTS,
    AllocationResult,
    ThrustAllocator,
)
from tiltrov_ros.core.allocation.closed_form import candidates
from tiltrov_ros.core.errors import AllocationError
from tiltrov_ros.core.thrust_map import allocation_matrix, q_vector, thrust_wrench

L, D, FMAX = 0.6, 0.4, 40.0
HALF_PI = math.pi / 2
MODES = ('paper', 'robust')

# Hovering and other symmetric wrenches where the printed closed form divides by 0.
HOVERING = {
    'heave up': [0, 0, -20, 0, 0, 0],
    'heave down': [0, 0, 20, 0, 0, 0],
    'surge': [30, 0, 0, 0, 0, 0],
    'pitch moment': [0, 0, 0, 0, 5, 0],
    'heave + pitch': [0, 0, -20, 0, 3, 0],
    'zero': [0, 0, 0, 0, 0, 0],
    'surge + heave + pitch': [10, 0, -20, 0, 3, 0],
    'roll moment': [0, 0, 0, 2, 0, 0],
    'yaw moment': [0, 0, 0, 0, 0, 3],
    'sway': [0, 10, 0, 0, 0, 0],
    'heave + roll': [0, 0, -20, 2, 0, 0],
}


def _rel_error(result: AllocationResult, tau: np.ndarray) -> float:
    return float(np.linalg.norm(result.achieved - tau) / max(np.linalg.norm(tau), 1e-300))


def _attainable(rng: np.random.Generator, n: int, fmax: float = FMAX,
                tilt: float = HALF_PI) -> np.ndarray:
    """Wrenches made from random thrusts within the limit and tilts within range."""
    f = rng.uniform(-fmax, fmax, size=(n, 4))
    a, b = rng.uniform(-tilt, tilt, size=(2, n))
    return thrust_wrench(f, a, b, L, D)


def _assert_within_limits(result: AllocationResult, alloc: ThrustAllocator,
                          previous: AllocationResult | None = None) -> None:
    assert np.all(np.isfinite(result.thrusts))
    assert np.all(np.isfinite(result.achieved))
    assert math.isfinite(result.tilt_front) and math.isfinite(result.tilt_rear)
    assert np.all(np.abs(result.thrusts) <= alloc.max_thrust)
    lo, hi = alloc.tilt_limits
    assert lo <= result.tilt_front <= hi and lo <= result.tilt_rear <= hi
    if previous is not None and math.isfinite(alloc.max_tilt_step):
        step = alloc.max_tilt_step * (1 + 1e-12)
        assert abs(result.tilt_front - previous.tilt_front) <= step
        assert abs(result.tilt_rear - previous.tilt_rear) <= step
    np.testing.assert_allclose(
        result.achieved,
        thrust_wrench(result.thrusts, result.tilt_front, result.tilt_rear, alloc.length,
                      alloc.width), rtol=0, atol=1e-12 * (1 + np.abs(result.achieved).max()))


# ------------------------------------------------------------------------ exactness


@pytest.mark.parametrize('mode', MODES)
def test_random_attainable_wrenches_are_reproduced(mode: str) -> None:
    alloc = ThrustAllocator(L, D, FMAX, mode=mode)
    rng = np.random.default_rng(20261124)
    taus = _attainable(rng, 3000)
    worst = 0.0
    for tau in taus:
        result = alloc.allocate(tau)
        assert result.feasible, (tau, result)
        _assert_within_limits(result, alloc)
        worst = max(worst, _rel_error(result, tau))
    assert worst <= 1e-9


@pytest.mark.parametrize('mode', MODES)
@pytest.mark.parametrize('name', sorted(HOVERING))
def test_hovering_wrenches_are_reproduced(mode: str, name: str) -> None:
    tau = np.array(HOVERING[name], dtype=float)
    alloc = ThrustAllocator(L, D, FMAX, mode=mode)
    for previous in (None, alloc.allocate(np.array([5.0, 1.0, -10.0, 0.3, 0.5, 0.2]))):
        result = alloc.allocate(tau, previous)
        assert result.feasible, (name, result)
        assert np.linalg.norm(result.achieved - tau) <= 1e-9 * max(np.linalg.norm(tau), FMAX)
        _assert_within_limits(result, alloc)


def test_hovering_solutions_are_the_least_thrust_ones() -> None:
    """On a family of exact solutions the least-thrust member is chosen (xi = 0)."""
    alloc = ThrustAllocator(L, D, FMAX)
    heave = alloc.allocate(np.array([0, 0, -20.0, 0, 0, 0]))
    np.testing.assert_allclose(heave.thrusts, [5, 5, 5, 5], atol=1e-12)
    assert heave.tilt_front == pytest.approx(HALF_PI) and heave.tilt_rear == pytest.approx(
        HALF_PI)
    surge = alloc.allocate(np.array([30.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(surge.thrusts, np.full(4, 30 / (4 / math.sqrt(2))), rtol=1e-12)
    assert (surge.tilt_front, surge.tilt_rear) == (0.0, 0.0)
    # Pseudo-inverse (xi = 0) solution when it satisfies (9): least sum of f_i^2.
    tau = np.array([10.0, 0, -20, 0, 3, 0])
    mixed = alloc.allocate(tau)
    c = np.linalg.pinv(allocation_matrix(L, D)) @ tau
    np.testing.assert_allclose(np.sum(mixed.thrusts ** 2), np.sum(c ** 2), rtol=1e-9)


def test_zero_wrench_keeps_the_previous_tilts() -> None:
    alloc = ThrustAllocator(L, D, FMAX, max_tilt_step=0.1)
    previous = alloc.allocate_fixed(np.zeros(6), 0.05, -0.07)
    result = alloc.allocate(np.zeros(6), previous)
    assert result.feasible and result.method == 'zero'
    assert (result.tilt_front, result.tilt_rear) == (0.05, -0.07)
    np.testing.assert_array_equal(result.thrusts, np.zeros(4))


# ------------------------------------------------------------------------ limits


@pytest.mark.parametrize('mode', MODES)
def test_any_finite_input_gives_finite_output_within_limits(mode: str) -> None:
    rng = np.random.default_rng(5)
    alloc = ThrustAllocator(L, D, FMAX, mode=mode, max_tilt_step=0.2,
                            tilt_limits=(-1.2, 1.4))
    previous = None
    for _ in range(300):
        scale = 10.0 ** rng.uniform(-6, 6)
        tau = rng.normal(size=6) * scale * (rng.uniform(size=6) < 0.7)
        result = alloc.allocate(tau, previous)
        _assert_within_limits(result, alloc, previous)
        previous = result


@pytest.mark.parametrize('mode', MODES)
@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_non_finite_wrench_is_safe_and_reported(mode: str, bad: float) -> None:
    alloc = ThrustAllocator(L, D, FMAX, mode=mode)
    tau = np.array([1.0, bad, -20.0, 0, 0, 0])
    result = alloc.allocate(tau)
    _assert_within_limits(result, alloc)
    assert not result.feasible
    fixed = alloc.allocate_fixed(tau, bad, 0.0)
    _assert_within_limits(fixed, alloc)
    assert not fixed.feasible


def test_extreme_magnitudes_do_not_overflow() -> None:
    alloc = ThrustAllocator(L, D, FMAX)
    for tau in (np.full(6, 1e300), np.array([1e-300, 0, -1e-300, 0, 1e-300, 0]),
                np.array([-1e308, 1e308, 1e308, -1e308, 1e308, 1e308])):
        result = alloc.allocate(tau)
        _assert_within_limits(result, alloc)


def test_malformed_requests_raise_allocation_error() -> None:
    alloc = ThrustAllocator(L, D)
    with pytest.raises(AllocationError, match='shape'):
        alloc.allocate(np.zeros(5))
    with pytest.raises(AllocationError, match='6 numbers'):
        alloc.allocate(['a'] * 6)
    with pytest.raises(AllocationError, match='shape'):
        alloc.allocate_batch(np.zeros((3, 5)))


@pytest.mark.parametrize(('kwargs', 'name'), [
    ({'length': 0.0, 'width': D}, 'length'),
    ({'length': L, 'width': -1.0}, 'width'),
    ({'length': L, 'width': D, 'max_thrust': math.nan}, 'max_thrust'),
    ({'length': L, 'width': D, 'tilt_limits': (1.0, -1.0)}, 'tilt_limits'),
    ({'length': L, 'width': D, 'max_tilt_step': 0.0}, 'max_tilt_step'),
    ({'length': L, 'width': D, 'mode': 'fast'}, 'mode'),
    ({'length': L, 'width': D, 'weights': (1, 1, 1)}, 'weights'),
    ({'length': L, 'width': D, 'failed_thrusters': (4,)}, 'failed_thrusters'),
])
def test_invalid_configuration_names_the_parameter(kwargs: dict, name: str) -> None:
    with pytest.raises(AllocationError, match=name):
        ThrustAllocator(**kwargs)


# ------------------------------------------------------------------------ robust mode


def _unattainable(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Wrenches with no exact solution within the limits (checked, not assumed)."""
    paper = ThrustAllocator(L, D, FMAX, mode='paper')
    found: list[np.ndarray] = []
    while len(found) < n:
        kind = rng.integers(3)
        if kind == 0:      # beyond the thrust capacity
            tau = rng.normal(size=6) * np.array([80, 80, 120, 25, 40, 30])
        elif kind == 1:    # sway with heave and no roll: (*) has no real solution
            tau = np.array([0.0, rng.uniform(-20, 20), rng.uniform(-60, 60), 0, 0, 0])
        else:              # random mixes, many with a negative discriminant
            tau = rng.normal(size=6) * np.array([10, 10, 20, 2, 3, 2])
        if not paper.allocate(tau).feasible:
            found.append(tau)
    return found


def test_robust_is_never_worse_than_paper_on_unattainable_wrenches() -> None:
    rng = np.random.default_rng(11)
    paper = ThrustAllocator(L, D, FMAX, mode='paper')
    robust = ThrustAllocator(L, D, FMAX, mode='robust')
    improved = 0
    for tau in _unattainable(rng, 120):
        p, r = paper.allocate(tau), robust.allocate(tau)
        assert r.error <= p.error * (1 + 1e-12) + 1e-12, (tau, p, r)
        improved += r.error < 0.9 * p.error
        _assert_within_limits(r, robust)
    # Not just "no worse": on most of them the robust mode is much better.
    assert improved >= 60


def test_negative_discriminant_uses_the_papers_fallback_and_robust_improves() -> None:
    rng = np.random.default_rng(3)
    paper = ThrustAllocator(L, D, FMAX, mode='paper')
    robust = ThrustAllocator(L, D, FMAX)
    cases = 0
    for _ in range(2000):
        tau = rng.normal(size=6) * np.array([10, 10, 20, 2, 3, 2])
        p = paper.allocate(tau)
        if p.discriminant < 0:
            assert p.method == 'pseudo' and not p.feasible
            r = robust.allocate(tau)
            assert r.error <= p.error
            cases += 1
    assert cases >= 20


def test_robust_respects_the_tilt_step_and_feeds_back_the_delivered_wrench() -> None:
    step = math.radians(7.5)
    alloc = ThrustAllocator(L, D, FMAX, max_tilt_step=step)
    start = alloc.allocate(np.array([20.0, 0, 0, 0, 0, 0]))        # tilts at 0
    assert (start.tilt_front, start.tilt_rear) == (0.0, 0.0)
    # 20 N of heave from tilts within 7.5 deg of 0: exact, with the pairs
    # opposing each other horizontally (a member of family F1 within reach).
    reachable = alloc.allocate(np.array([0, 0, -20.0, 0, 0, 0]), start)
    assert reachable.feasible
    assert max(abs(reachable.tilt_front), abs(reachable.tilt_rear)) <= step * (1 + 1e-12)
    # 60 N of heave is out of reach within 7.5 deg: the best attainable wrench,
    # heave first, and the delivered wrench reported as it is.
    result = alloc.allocate(np.array([0, 0, -60.0, 0, 0, 0]), start)
    assert max(abs(result.tilt_front), abs(result.tilt_rear)) <= step * (1 + 1e-12)
    # Best within reach, or already heading for the exact solution (25 deg away).
    assert not result.feasible and result.method in ('optimized', 'transit')
    np.testing.assert_allclose(result.achieved,
                               alloc.wrench(result.thrusts, result.tilt_front,
                                            result.tilt_rear))
    best_heave = 4 * FMAX * math.sin(step)                  # all four pushing down, tilted
    assert -result.achieved[2] == pytest.approx(best_heave, rel=0.05)
    assert result.error < ThrustAllocator(L, D, FMAX, max_tilt_step=step, mode='paper'
                                          ).allocate(np.array([0, 0, -60.0, 0, 0, 0]),
                                                     start).error


def test_failed_thruster_is_never_used_and_hover_still_holds() -> None:
    alloc = ThrustAllocator(L, D, FMAX, failed_thrusters=(2,))
    result = alloc.allocate(np.array([0, 0, -20.0, 0, 0, 0]))
    assert result.thrusts[2] == 0.0
    assert result.feasible, result                # three thrusters can hover
    rng = np.random.default_rng(2)
    for tau in _attainable(rng, 20):
        r = alloc.allocate(tau)
        assert r.thrusts[2] == 0.0
        _assert_within_limits(r, alloc)


# ------------------------------------------------------------------------ fixed tilts


def test_fixed_tilts_horizontal_and_vertical_modes() -> None:
    alloc = ThrustAllocator(L, D, FMAX)
    horizontal = np.array([10.0, -5.0, 0, 0, 0, 2.0])
    r = alloc.allocate_fixed(horizontal, 0.0, 0.0)
    assert r.feasible and r.method == 'fixed_tilt'
    vertical = np.array([0, 0, -20.0, 1.0, -2.0, 0])
    r = alloc.allocate_fixed(vertical, HALF_PI, HALF_PI)
    assert r.feasible
    # At 0 deg nothing acts on heave: the error is reported, the rest delivered.
    r = alloc.allocate_fixed(np.array([10.0, 0, -20.0, 0, 0, 0]), 0.0, 0.0)
    assert not r.feasible
    assert r.achieved[0] == pytest.approx(10.0) and r.achieved[2] == 0.0


def test_fixed_tilts_saturate_and_obey_the_step() -> None:
    alloc = ThrustAllocator(L, D, FMAX, max_tilt_step=0.1)
    prev = alloc.allocate_fixed(np.zeros(6), 0.0, 0.0)
    r = alloc.allocate_fixed(np.array([0, 0, -500.0, 0, 0, 0]), HALF_PI, HALF_PI, prev)
    assert (r.tilt_front, r.tilt_rear) == (0.1, 0.1)
    np.testing.assert_allclose(np.abs(r.thrusts), FMAX)


# ------------------------------------------------------------------------ continuity


def _smooth_actuator_wrenches(t: np.ndarray) -> np.ndarray:
    f = np.column_stack([20 + 8 * np.sin(0.7 * t), 18 + 6 * np.cos(0.5 * t + 1),
                         15 + 5 * np.sin(0.3 * t + 2), 22 + 7 * np.cos(0.9 * t)])
    alpha = 0.9 * np.sin(0.2 * t)
    beta = 0.3 + 0.8 * np.cos(0.15 * t)
    return thrust_wrench(f, alpha, beta, L, D)


@pytest.mark.parametrize('mode', MODES)
def test_tilts_move_continuously_along_a_smooth_wrench_trajectory(mode: str) -> None:
    """20 Hz along 60 s: no jumps between roots, no flips across +-90 deg."""
    t = np.arange(0.0, 60.0, 0.05)
    taus = _smooth_actuator_wrenches(t)
    alloc = ThrustAllocator(L, D, FMAX, mode=mode)
    previous = None
    tilts = []
    for tau in taus:
        previous = alloc.allocate(tau, previous)
        assert previous.feasible
        tilts.append(previous.tilts)
    steps = np.abs(np.diff(np.array(tilts), axis=0)).max(axis=1)
    # The generating tilts move at most 0.9*0.2*0.05 = 0.009 rad per step. Where
    # the two roots of (**) meet (Delta = 0) they do so with unbounded slope, so
    # a few steps are faster there; a jump to the other root would be >> 0.1.
    assert steps.max() < 0.1, steps.max()
    assert np.mean(steps < 0.02) > 0.99


def _sweep_surge(alloc: ThrustAllocator, xs: np.ndarray) -> tuple[np.ndarray, list]:
    previous = alloc.allocate(np.array([xs[0], 0, -20.0, 0, 0, 0]))
    tilts, results = [previous.tilts], [previous]
    for x in xs[1:]:
        previous = alloc.allocate(np.array([x, 0, -20.0, 0, 0, 0]), previous)
        tilts.append(previous.tilts)
        results.append(previous)
    return np.array(tilts), results


def test_tilt_through_vertical_and_back_is_not_flipped() -> None:
    """Surge 5 -> 0 -> 5 N while lifting: the tilts reach exactly 90 deg and return
    on the same side; +90 is never swapped for the equivalent -90."""
    xs = np.concatenate([np.linspace(5, 0, 21), np.linspace(0, 5, 21)])
    tilts, results = _sweep_surge(ThrustAllocator(L, D, FMAX), xs)
    assert all(r.feasible for r in results)
    assert np.abs(np.diff(tilts, axis=0)).max() < 0.2
    assert tilts.min() > 0.0
    assert tilts[20] == pytest.approx([HALF_PI, HALF_PI])


def test_crossing_vertical_is_continuous_when_the_range_allows_it() -> None:
    xs = np.linspace(5, -5, 41)
    wide = ThrustAllocator(L, D, FMAX, tilt_limits=(-HALF_PI, math.pi))
    tilts, results = _sweep_surge(wide, xs)
    assert all(r.feasible for r in results)
    assert np.abs(np.diff(tilts, axis=0)).max() < 0.2
    assert tilts[-1].min() > HALF_PI           # went on past 90 deg, no flip


def test_crossing_vertical_within_90_deg_needs_a_flip_robust_plans_it() -> None:
    """With tilts limited to +-90 deg a backward push while lifting needs a pair
    on the other side of vertical. The paper mode jumps there at once. With a
    tilt step limit the per-tick optimum alone holds at the edge for ever; the
    planner moves one pair through 0 deg at full step (method ``transit``, the
    other pair keeping the depth) and is exact again when it arrives."""
    xs = np.linspace(5, -20, 41)
    tilts, results = _sweep_surge(ThrustAllocator(L, D, FMAX, mode='paper'), xs)
    assert all(r.feasible for r in results)
    assert np.abs(np.diff(tilts, axis=0)).max() > 1.5          # the jump, exact
    step = math.radians(7.5)
    xs = np.concatenate([xs, np.full(60, -20.0)])
    stays = ThrustAllocator(L, D, FMAX, max_tilt_step=step, planning=False)
    tilts, results = _sweep_surge(stays, xs)
    # Greedy: held at the edge, depth kept, the backward push it cannot deliver
    # reported.
    assert np.abs(np.diff(tilts, axis=0)).max() <= step * (1 + 1e-12)
    assert tilts.min() > 0.0 and not results[-1].feasible
    assert results[-1].achieved[2] == pytest.approx(-20.0, abs=1e-6)
    assert results[-1].achieved[0] == pytest.approx(0.0, abs=1e-6)
    robust = ThrustAllocator(L, D, FMAX, max_tilt_step=step)
    tilts, results = _sweep_surge(robust, xs)
    assert np.abs(np.diff(tilts, axis=0)).max() <= step * (1 + 1e-12)
    methods = [r.method for r in results]
    first_transit = methods.index('transit')
    assert results[first_transit].target is not None
    assert results[-1].feasible and results[-1].method in ('exact', 'family')
    assert results[-1].achieved[0] == pytest.approx(-20.0) and results[-1].stuck == 0
    assert tilts[-1].min() < 0.0                 # one pair went past vertical
    arrived = next(i for i in range(first_transit, len(results)) if results[i].feasible)
    assert arrived - first_transit <= 180 / 7.5
    # On the way the depth is kept within a fifth of the demand.
    assert all(abs(r.achieved[2] + 20.0) < 4.0 for r in results[first_transit:arrived])


# ------------------------------------------------------------------------ batch form


@pytest.mark.parametrize('mode', MODES)
def test_batch_equals_single_calls(mode: str) -> None:
    rng = np.random.default_rng(9)
    taus = np.vstack([np.array(list(HOVERING.values()), dtype=float),
                      _attainable(rng, 400), np.array([[0, 10.0, -20, 0, 0, 0]])])
    prev = rng.uniform(-1.0, 1.0, size=(len(taus), 2))
    alloc = ThrustAllocator(L, D, FMAX, mode=mode, max_tilt_step=math.inf)
    batch = alloc.allocate_batch(taus, prev)
    for i, tau in enumerate(taus):
        stand_in = alloc.allocate_fixed(np.zeros(6), prev[i, 0], prev[i, 1])
        single = alloc.allocate(tau, stand_in)
        np.testing.assert_allclose(batch.thrusts[i], single.thrusts, atol=1e-9)
        np.testing.assert_allclose([batch.tilt_front[i], batch.tilt_rear[i]], single.tilts,
                                   atol=1e-12)
        assert batch.feasible[i] == single.feasible
        assert batch.error[i] == pytest.approx(single.error, abs=1e-9)


def test_batch_reproduces_thousands_of_attainable_wrenches() -> None:
    rng = np.random.default_rng(21)
    taus = _attainable(rng, 20000)
    for mode in MODES:
        batch = ThrustAllocator(L, D, FMAX, mode=mode).allocate_batch(taus)
        assert batch.feasible.all()
        rel = np.linalg.norm(batch.achieved - taus, axis=1) / np.linalg.norm(taus, axis=1)
        assert rel.max() <= 1e-9
        assert np.all(np.abs(batch.thrusts) <= FMAX)


# ------------------------------------------------------------------------ the paper's errors


def _paper_terms(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """c = A^+ tau and the q of a configuration producing tau."""
    return np.linalg.pinv(allocation_matrix(L, D)) @ tau, np.zeros(8)


def test_printed_eq7_pairs_the_wrong_components() -> None:
    rng = np.random.default_rng(4)
    f = rng.uniform(5, 40, size=4)
    q = q_vector(f, 0.4, -0.7)
    printed_f1 = np.sign(q[4]) * math.hypot(q[0], q[2])     # as printed: q1, q3
    corrected_f1 = np.sign(q[4]) * math.hypot(q[0], q[4])   # q1, q5
    assert corrected_f1 == pytest.approx(f[0], rel=1e-12)
    assert abs(printed_f1 - f[0]) > 1e-3


def test_printed_eq14_constant_term_is_wrong() -> None:
    rng = np.random.default_rng(8)
    f = rng.uniform(5, 40, size=4)
    q = q_vector(f, 0.4, -0.7)
    tau = allocation_matrix(L, D) @ q
    c, _ = _paper_terms(tau)
    c1, c2, c3, c4, c5, c6, c7, c8 = c
    xi2 = c1 - q[0]                                         # from (11)
    den = -c1 + c2 + c3 - c4
    b1 = (c5 + c6 + c7 + c8) / den
    b2 = (-c1 * c6 + c2 * c5 + c4 * c7 - c3 * c8) / den
    a_bar = 2 * b1
    b_bar = 2 * b2 + (-c1 + c2) * b1 + (-c5 - c6)
    printed = (-c1 + c2) * b2
    corrected = printed + (c1 * c6 - c2 * c5)
    scale = abs(a_bar * xi2 ** 2) + abs(b_bar * xi2) + abs(corrected)
    assert abs(a_bar * xi2 ** 2 + b_bar * xi2 + corrected) <= 1e-10 * scale
    assert abs(a_bar * xi2 ** 2 + b_bar * xi2 + printed) > 1e-3 * scale


def test_printed_closed_form_divides_by_zero_when_hovering() -> None:
    """(13) divides by -c1 + c2 + c3 - c4 = -2K/d: zero for any K = 0 wrench."""
    for name in ('heave up', 'heave + pitch', 'surge + heave + pitch'):
        tau = np.array(HOVERING[name], dtype=float)
        c, _ = _paper_terms(tau)
        assert abs(-c[0] + c[1] + c[2] - c[3]) < 1e-12
        assert ThrustAllocator(L, D, FMAX, mode='paper').allocate(tau).feasible
    tau = np.array([1.0, 2.0, -3.0, 0.7, 0.4, 0.1])
    c, _ = _paper_terms(tau)
    assert -c[0] + c[1] + c[2] - c[3] == pytest.approx(-2 * tau[3] / D, rel=1e-12)


# ------------------------------------------------------------------------ properties


finite = st.floats(min_value=-1e4, max_value=1e4, allow_nan=False, allow_infinity=False)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(f=st.lists(st.floats(-FMAX, FMAX), min_size=4, max_size=4),
       alpha=st.floats(-HALF_PI, HALF_PI), beta=st.floats(-HALF_PI, HALF_PI),
       mode=st.sampled_from(MODES))
def test_property_round_trip(f: list[float], alpha: float, beta: float, mode: str) -> None:
    tau = thrust_wrench(np.array(f), alpha, beta, L, D)
    result = ThrustAllocator(L, D, FMAX, mode=mode).allocate(tau)
    assert result.feasible
    assert np.linalg.norm(result.achieved - tau) <= 1e-9 * max(np.linalg.norm(tau), FMAX)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tau=st.lists(finite, min_size=6, max_size=6),
       prev=st.tuples(st.floats(-HALF_PI, HALF_PI), st.floats(-HALF_PI, HALF_PI)),
       step=st.floats(1e-3, 4.0), mode=st.sampled_from(MODES))
def test_property_limits_hold_for_any_input(tau: list[float], prev: tuple[float, float],
                                            step: float, mode: str) -> None:
    alloc = ThrustAllocator(L, D, FMAX, mode=mode, max_tilt_step=step)
    previous = alloc.allocate_fixed(np.zeros(6), *prev)
    result = alloc.allocate(np.array(tau), previous)
    _assert_within_limits(result, alloc, previous)
    assert result.error == pytest.approx(
        float(np.linalg.norm((result.achieved - np.array(tau)) * np.array(DEFAULT_WEIGHTS))))


# ------------------------------------------------------------------------ regressions


@pytest.mark.parametrize('mode', MODES)
@pytest.mark.parametrize(('f', 'alpha', 'beta'), [
    ([1e-3, 1e-3, 40.0, 40.0], 1e-3, HALF_PI),               # rear pair at the limit, F1
    ([40.0, 40.0, -25.01957995, -25.01957995], -HALF_PI, -0.03890611161857893),
    ([40.0, 40.0, -1e-3, 1e-3], HALF_PI, 1e-3),
])
def test_exact_solutions_at_the_thrust_limit_on_a_family(mode, f, alpha, beta) -> None:
    """The least-largest-thrust member of a family is a candidate: solutions whose
    thrusts sit exactly at the limit are found, not missed between samples."""
    tau = thrust_wrench(np.array(f), alpha, beta, L, D)
    result = ThrustAllocator(L, D, FMAX, mode=mode).allocate(tau)
    assert _rel_error(result, tau) <= 1e-9, result


@pytest.mark.parametrize('mode', MODES)
def test_double_root_with_a_rounding_negative_discriminant(mode: str) -> None:
    f = np.array([1e-3, 0.0, 0.0, -34.2376891])
    tau = thrust_wrench(f, 0.8537155260600597, 0.8537155260600597, L, D)
    result = ThrustAllocator(L, D, FMAX, mode=mode).allocate(tau)
    assert result.method == 'exact'
    assert _rel_error(result, tau) <= 1e-9


def test_near_degenerate_wrench_is_snapped_to_its_family_in_robust_mode() -> None:
    """An integrator leaves roll, sway and yaw at rounding level: the exact roots
    jump far away, the family of the clean wrench is next door."""
    step = math.radians(7.5)
    robust = ThrustAllocator(L, D, FMAX, max_tilt_step=step)
    clean = np.array([0.87, 0.0, 4.92, 0.0, 3.52, 0.0])
    start = robust.allocate_fixed(np.zeros(6), math.radians(56.3), math.radians(82.9))
    previous = robust.allocate(clean, start)          # a member of the clean family
    assert previous.method == 'family' and previous.feasible
    hairy = clean + np.array([0, 3e-8, 0, 2e-9, 0, -5e-8])
    exact_roots, _ = candidates(robust.geometry, hairy)
    assert exact_roots and all(np.max(np.abs(c.tilts - previous.tilts)) > step
                               for c in exact_roots)
    result = robust.allocate(hairy, previous)
    assert result.method == 'family' and result.feasible
    assert np.max(np.abs(result.tilts - previous.tilts)) <= step
    assert np.linalg.norm(result.achieved - hairy) < 1e-6 * np.linalg.norm(hairy)


# ------------------------------------------------------------------------ configuration


def test_shipped_allocator_config_builds_the_servo_reach() -> None:
    from tiltrov_ros.core.allocation import load_allocator_config
    from tiltrov_ros.core.params import load_control_period, load_robot_params

    config = load_allocator_config()
    robot = load_robot_params()
    period = load_control_period()
    assert period == 0.05
    alloc = config.build(robot, period)
    assert alloc.mode == 'robust'
    assert alloc.max_tilt_step == pytest.approx(robot.tilt_rate_limit * 0.05)
    assert alloc.max_tilt_step == pytest.approx(math.radians(7.5))
    assert (alloc.length, alloc.width, alloc.max_thrust) == (robot.length, robot.width,
                                                            robot.max_thrust)


@pytest.mark.parametrize(('values', 'name'), [
    ({'mode': 'fast'}, 'mode'),
    ({'max_tilt_step': 'big'}, 'max_tilt_step'),
    ({'weights': [1, 1, 1]}, 'weights'),
    ({'weights': [1, 1, 1, 1, 1, 0]}, 'weights'),
])
def test_invalid_allocator_config_names_the_parameter(values: dict, name: str) -> None:
    from tiltrov_ros.core.allocation import AllocatorConfig
    from tiltrov_ros.core.errors import ParameterError

    with pytest.raises(ParameterError, match=name):
        AllocatorConfig.from_mapping(values, source='thrust_allocator.yaml')


# --------------------------------------------------------------------------- sequences


@pytest.mark.parametrize('mode', MODES)
def test_allocate_sequence_chains_previous_like_the_node(mode: str) -> None:
    from tiltrov_ros.core.allocation import BatchResult, allocate_sequence

    rng = np.random.default_rng(7)
    taus = _attainable(rng, 12)
    alloc = ThrustAllocator(L, D, FMAX, max_tilt_step=math.radians(7.5), mode=mode)
    results = allocate_sequence(alloc, taus)
    previous = None
    for tau, result in zip(taus, results):
        expected = alloc.allocate(tau, previous=previous)
        np.testing.assert_array_equal(result.thrusts, expected.thrusts)
        assert (result.tilt_front, result.tilt_rear) == (expected.tilt_front,
                                                          expected.tilt_rear)
        previous = expected
    # Chaining matters here: each tilt moves at most one servo reach per row,
    # which independent allocations do not respect.
    steps = np.abs(np.diff(BatchResult.stack(results).tilts, axis=0))
    assert np.all(steps <= math.radians(7.5) + 1e-12)
    independent = alloc.allocate_batch(taus)
    assert np.max(np.abs(np.diff(independent.tilts, axis=0))) > math.radians(7.5)

    batch = BatchResult.stack(results)
    assert batch.thrusts.shape == (12, 4) and batch.achieved.shape == (12, 6)
    np.testing.assert_array_equal(batch.error, [r.error for r in results])
    np.testing.assert_array_equal(batch.feasible, [r.feasible for r in results])


def test_allocate_sequence_holds_requested_tilts() -> None:
    from tiltrov_ros.core.allocation import allocate_sequence

    taus = np.array([[10.0, 0, -20, 0, 1, 0]] * 3)
    requests = np.array([[0.0, 0.0], [math.nan, math.nan], [HALF_PI, HALF_PI]])
    alloc = ThrustAllocator(L, D, FMAX, mode='robust')
    first, free, fixed = allocate_sequence(alloc, taus, requests)
    assert first.method == 'fixed_tilt' and (first.tilt_front, first.tilt_rear) == (0.0, 0.0)
    assert free.method != 'fixed_tilt'
    expected = alloc.allocate_fixed(taus[2], HALF_PI, HALF_PI, previous=free)
    assert fixed.method == 'fixed_tilt'
    np.testing.assert_array_equal(fixed.thrusts, expected.thrusts)
    with pytest.raises(AllocationError, match='tilt_requests'):
        allocate_sequence(alloc, taus, requests[:2])
    with pytest.raises(AllocationError, match='wrenches'):
        allocate_sequence(alloc, taus[:, :5])


def test_infeasible_rows_is_the_allocators_own_test() -> None:
    from tiltrov_ros.core.allocation import FEASIBILITY_RTOL, infeasible_rows

    req = np.array([[0.0, 0, 0, 0, 0, 0], [100.0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0]])
    tol = FEASIBILITY_RTOL * np.array([FMAX, 100.0, FMAX])
    ach = req.copy()
    ach[:, 1] = 0.9 * tol
    assert not infeasible_rows(req, ach, FMAX).any()
    ach[:, 1] = 1.1 * tol
    assert infeasible_rows(req, ach, FMAX).all()
    ach[0, 2] = math.nan
    assert not infeasible_rows(req, ach, FMAX)[0]      # unknown: not counted


def test_a_late_start_at_the_edge_gets_out_when_the_error_is_worth_the_travel() -> None:
    """A late-started or restarted allocator: its first wrench, a pure heave with
    no ``previous``, parks both pairs at -90 deg, where a backward push is out of
    reach (its twin is 180 deg of servo travel away). A small push is left
    undelivered (the travel would cost more error than it saves); a growing one,
    as a controller's reaction to the drift makes it, sends one pair through
    0 deg, and the answer is exact again, every step within the servo's reach."""
    step = math.radians(7.5)
    alloc = ThrustAllocator(L, D, FMAX, (-HALF_PI, HALF_PI), step)
    first = alloc.allocate([0, 0, 5.0, 0, 0, 0])
    assert first.feasible and np.allclose(np.abs(first.tilts), HALF_PI)
    small = first
    for _ in range(60):
        small = alloc.allocate([-1.0, 0, 5.0, 0, 0, 0], small)
    assert not small.feasible and small.achieved[2] == pytest.approx(5.0)
    previous, results = first, []
    for x in np.concatenate([np.linspace(0.0, -10.0, 41), np.full(40, -10.0)]):
        previous = alloc.allocate([x, 0, 5.0, 0, 0, 0], previous)
        results.append(previous)
    tilts = np.array([first.tilts] + [r.tilts for r in results])
    assert np.abs(np.diff(tilts, axis=0)).max() <= step * (1 + 1e-12)
    assert 'transit' in [r.method for r in results]
    assert results[-1].feasible and results[-1].achieved[0] == pytest.approx(-10.0)
    assert all(r.feasible for r in results[-20:])


def test_from_tilts_moves_previous_to_the_measured_tilts_and_keeps_the_planner_state() -> None:
    from tiltrov_ros.core.allocation import from_tilts, shortfall_tolerances
    from tiltrov_ros.core.params import load_robot_params

    alloc = ThrustAllocator(L, D, FMAX, max_tilt_step=math.radians(7.5))
    start = from_tilts(None, [0.2, -0.1])
    assert start.tilts.tolist() == [0.2, -0.1]
    result = alloc.allocate([0, 0, 5.0, 0, 0, 0], start)
    assert np.all(np.abs(result.tilts - [0.2, -0.1]) <= math.radians(7.5) + 1e-12)
    moved = from_tilts(replace(result, target=(1.0, 1.0), stuck=3, method='transit'),
                       [0.3, 0.4])
    assert moved.tilts.tolist() == [0.3, 0.4]
    assert (moved.target, moved.stuck, moved.method) == ((1.0, 1.0), 3, 'transit')
    tolerances = shortfall_tolerances(load_robot_params())
    np.testing.assert_allclose(tolerances, [0.4, 0.4, 0.4, 0.08, 0.08, 0.08])
