"""The compiled allocation answers as the numpy reference, on seeded sets.

Every call is made on an allocator of each backend with the same settings and
compared by :class:`kernel_equality.Tally` (the weighted error to 1e-9
relative always; the point to 1e-9 unless two optima tie, which is detected
and counted; method, feasibility, target and stuck count equal). Under
``TILTROV_BACKEND=numpy`` the compiled side does not exist and these tests
are skipped with that reason. Calls captured from headless runs:
``test_allocation_kernels_runs.py``.
"""

from __future__ import annotations

import math

from kernel_equality import Tally, needs_kernels, pair, same_batch, stand_in
import numpy as np
import pytest
from test_allocation import FMAX, HOVERING, D, L, _attainable, _smooth_actuator_wrenches
from test_allocation_optimum import _unattainable

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation import AllocationResult, ThrustAllocator, allocate_sequence
from tiltrov_ros.core.allocation.decomposition import Geometry
from tiltrov_ros.core.errors import AllocationError

pytestmark = needs_kernels

HALF_PI = 0.5 * math.pi
STEP = math.radians(7.5)
K = Geometry(L, D).k
RANGES = {'90': (-HALF_PI, HALF_PI), '120': (-2 * math.pi / 3, 2 * math.pi / 3),
          '180': (-math.pi, math.pi)}


def _families(rng: np.random.Generator, n: int) -> list[np.ndarray]:
    """Wrenches on each one-parameter family of :mod:`..closed_form` (F1 symmetric and
    not, F2, F3), at magnitudes from easy to beyond the limit."""
    out = []
    for i in range(n):
        X, Y, Z, Kr, M = rng.normal(size=5) * rng.choice([5.0, 20.0, 60.0])
        kind = i % 4
        if kind == 0:                               # F1, symmetric: Y = K = N = 0
            out.append(np.array([X, 0.0, Z, 0.0, M, 0.0]))
        elif kind == 1:                             # F1: Zf = 0, Dr = 0, kappa = 0
            out.append(np.array([X, Y, Z, 0.0, L * Z / 2, math.sqrt(2.0) * K * Y]))
        elif kind == 2:                             # F2: H = 0, Df = Dr = 0
            out.append(np.array([0.0, 0.0, Z, Kr, M, 0.0]))
        else:                                       # F3: kappa = H = 0, P = -Q
            Zf, Zr, Df = rng.normal(size=3) * 10
            Dr = -Zf * Df / Zr
            out.append(np.array([0.0, (Df + Dr) / math.sqrt(2.0), -(Zf + Zr), 0.0,
                                 (Zf - Zr) * L / 2, (Df - Dr) * K]))
    return out


def _previous(alloc: ThrustAllocator, rng: np.random.Generator,
              around: np.ndarray | None = None) -> AllocationResult:
    """A previous result at random tilts in range (near ``around`` when given)."""
    lo, hi = alloc.tilt_limits
    t = (rng.uniform(lo, hi, 2) if around is None
         else np.clip(around + rng.uniform(-STEP, STEP, 2), lo, hi))
    return alloc.allocate_fixed(np.zeros(6), float(t[0]), float(t[1]))


def _run(ref: ThrustAllocator, ker: ThrustAllocator, taus: list[np.ndarray],
         rng: np.random.Generator, tally: Tally, where: str) -> dict[str, int]:
    """Each wrench without ``previous`` and from a random one; the methods met."""
    methods: dict[str, int] = {}
    for i, tau in enumerate(taus):
        for previous in (None, _previous(ref, rng)):
            r, _ = tally.call(ref, ker, tau, previous, f'{where} #{i} prev={previous is not None}')
            methods[r.method] = methods.get(r.method, 0) + 1
    return methods


# --------------------------------------------------------------------------- attainable


@pytest.mark.parametrize('mode', ['robust', 'paper'])
@pytest.mark.parametrize('step', [math.inf, STEP])
def test_attainable_generic_wrenches(mode: str, step: float) -> None:
    rng = np.random.default_rng(101)
    ref, ker = pair(mode=mode, max_tilt_step=step)
    tally = Tally()
    f = rng.uniform(-FMAX, FMAX, size=(150, 4))
    tilts = rng.uniform(-HALF_PI, HALF_PI, size=(150, 2))
    taus = ref.wrench(f, tilts[:, 0], tilts[:, 1])
    for i, (tau, t) in enumerate(zip(taus, tilts)):
        for previous in (None, _previous(ref, rng, t), _previous(ref, rng)):
            tally.call(ref, ker, tau, previous, f'{mode} step={step} #{i}')
    tally.check_ties()


@pytest.mark.parametrize('mode', ['robust', 'paper'])
def test_families_symmetric_zero_and_near_degenerate_wrenches(mode: str) -> None:
    rng = np.random.default_rng(102)
    ref, ker = pair(mode=mode, max_tilt_step=STEP)
    tally = Tally()
    family = _families(rng, 160)
    hover = [np.array(v, dtype=float) for v in HOVERING.values()]
    # A hair (below the snap tolerance) on the components a family needs at zero.
    near = [tau + rng.normal(size=6) * 1e-7 * np.max(np.abs(tau)) * (tau == 0)
            for tau in family[:80] + hover]
    methods = _run(ref, ker, family + hover + near + [np.zeros(6)], rng, tally, mode)
    assert methods.get('family', 0) >= 40 and methods.get('zero', 0) >= 2, methods
    tally.check_ties()


# --------------------------------------------------------------------------- unattainable


@pytest.mark.parametrize('planning', [True, False])
def test_unattainable_wrenches_with_and_without_previous(planning: bool) -> None:
    rng = np.random.default_rng(103)
    ref, ker = pair(max_tilt_step=STEP, planning=planning)
    tally = Tally()
    methods = _run(ref, ker, _unattainable(104, 60), rng, tally, f'planning={planning}')
    assert methods.get('optimized', 0) >= 40, methods
    if planning:
        assert methods.get('transit', 0) >= 5, methods
    tally.check_ties(0.05)


@pytest.mark.parametrize('failed', [(1,), (0, 3)])
def test_failed_thrusters(failed: tuple[int, ...]) -> None:
    rng = np.random.default_rng(105)
    tally = Tally()
    for mode in ('robust', 'paper'):
        ref, ker = pair(max_tilt_step=STEP, failed_thrusters=failed, mode=mode)
        taus = list(_attainable(rng, 30)) + _families(rng, 8) + _unattainable(106, 20)
        _run(ref, ker, taus, rng, tally, f'{mode} failed={failed}')
    tally.check_ties(0.05)


@pytest.mark.parametrize('width', ['120', '180'])
def test_wide_tilt_ranges(width: str) -> None:
    rng = np.random.default_rng(107)
    lo, hi = RANGES[width]
    tally = Tally()
    for step in (math.inf, STEP):
        ref, ker = pair(tilt_limits=(lo, hi), max_tilt_step=step)
        taus = (list(_attainable(rng, 40, tilt=hi)) + _families(rng, 12)
                + _unattainable(108, 20))
        _run(ref, ker, taus, rng, tally, f'+-{width} step={step}')
    tally.check_ties(0.05)


# --------------------------------------------------------------------------- chains


@pytest.mark.parametrize('mode', ['robust', 'paper'])
def test_rate_limited_chains_compare_every_tick(mode: str) -> None:
    """allocate_sequence over 200 ticks, both backends on their own chains; and each
    tick of the reference's chain answered by the kernels from the same previous."""
    rng = np.random.default_rng(109)
    t = np.arange(200) * 0.05
    smooth = _smooth_actuator_wrenches(t)
    # A wandering demand, mostly beyond reach: the per-tick optimum and the planner.
    walk = np.cumsum(rng.normal(size=(200, 6)) * [4, 4, 6, 1, 1.5, 1], axis=0)
    requests = np.full((200, 2), math.nan)
    requests[50:60] = [0.0, 0.0]
    requests[120:125] = [HALF_PI, 0.2]
    tally = Tally()
    for name, taus, req in (('smooth', smooth, None), ('walk', walk, requests)):
        ref, ker = pair(mode=mode, max_tilt_step=STEP)
        chain_r = allocate_sequence(ref, taus, req)
        chain_k = allocate_sequence(ker, taus, req)
        previous = None
        diverged = False
        for i, (r, k) in enumerate(zip(chain_r, chain_k)):
            if not diverged:
                diverged = not tally.same(ref, r, k, f'{mode} {name} chain tick {i}',
                                          None if i == 0 else chain_r[i - 1])
            fixed = req is not None and bool(np.all(np.isfinite(req[i])))
            kk = (ker.allocate_fixed(taus[i], *req[i], previous=previous) if fixed
                  else ker.allocate(taus[i], previous))
            tally.same(ref, r, kk, f'{mode} {name} tick {i}', previous)
            previous = r
        assert not diverged or tally.ties, 'chains diverged without a tie'
    tally.check_ties()


# --------------------------------------------------------------------------- the rest of the API


def test_non_finite_inputs() -> None:
    rng = np.random.default_rng(110)
    tally = Tally()
    for mode in ('robust', 'paper'):
        ref, ker = pair(mode=mode, max_tilt_step=STEP)
        good = ref.allocate(np.array([5.0, 1, -20, 0.5, 1, 0.2]))
        previous_bad = [None, good, AllocationResult(
            good.thrusts, math.nan, 0.3, good.achieved, True, good.requested, 'transit',
            math.nan, 0.0, (0.1, 0.2), 4)]
        for bad in (math.nan, math.inf, -math.inf):
            for j in range(6):
                tau = rng.normal(size=6) * 20
                tau[j] = bad
                for previous in previous_bad:
                    tally.call(ref, ker, tau, previous, f'{mode} tau[{j}]={bad}')
                    tilts = (bad, 0.3) if j % 2 else (0.1, bad)
                    tally.same(ref, ref.allocate_fixed(tau, *tilts, previous=previous),
                               ker.allocate_fixed(tau, *tilts, previous=previous),
                               f'{mode} fixed tau[{j}]={bad}', previous)
    assert not tally.ties


def test_allocate_fixed_and_thrusts_at() -> None:
    rng = np.random.default_rng(111)
    tally = Tally()
    for failed in ((), (2,)):
        ref, ker = pair(max_tilt_step=STEP, failed_thrusters=failed)
        for i, tau in enumerate(list(_attainable(rng, 40)) + _unattainable(112, 20)):
            tilts = rng.uniform(-2.0, 2.0, 2)
            previous = _previous(ref, rng) if i % 2 else None
            tally.same(ref, ref.allocate_fixed(tau, *tilts, previous=previous),
                       ker.allocate_fixed(tau, *tilts, previous=previous), f'fixed #{i}')
            t = np.clip(tilts, -HALF_PI, HALF_PI)
            np.testing.assert_allclose(ker.thrusts_at(tau, t), ref.thrusts_at(tau, t),
                                       rtol=0, atol=1e-9 * max(np.abs(tau).max(), FMAX))
    assert not tally.ties


@pytest.mark.parametrize('kwargs', [{}, {'mode': 'paper'}, {'max_tilt_step': STEP},
                                    {'failed_thrusters': (1,)},
                                    {'tilt_limits': RANGES['180'], 'max_tilt_step': STEP}],
                         ids=['robust', 'paper', 'step', 'failed', 'wide'])
def test_batch_row_by_row_and_against_single_calls(kwargs: dict) -> None:
    rng = np.random.default_rng(113)
    ref, ker = pair(**kwargs)
    taus = np.vstack([_attainable(rng, 300), _families(rng, 40),
                      [v for v in HOVERING.values()], _unattainable(114, 25)])
    taus[[3, 40, 350]] = [[math.nan, 0, 1, 0, 0, 0], [0, math.inf, 0, 0, 0, 1],
                          [0, 0, -math.inf, 0, 0, 0]]
    prev = rng.uniform(-2.0, 2.0, size=(len(taus), 2))
    prev[[5, 6]] = [[math.nan, 0.1], [0.2, math.inf]]
    tally = Tally()
    for given in (None, prev):
        r, k = ref.allocate_batch(taus, given), ker.allocate_batch(taus, given)
        same_batch(ref, ker, r, k, taus, given, tally, f'batch prev={given is not None}')
        # The compiled batch answers as the compiled single calls do, wherever the
        # reference's batch answers as its single calls (rows on their own).
        agree = 0
        for i, tau in enumerate(taus):
            previous = None if given is None else stand_in(ref, given[i])
            single_r, single_k = ref.allocate(tau, previous), ker.allocate(tau, previous)
            if np.allclose(r.thrusts[i], single_r.thrusts, rtol=0, atol=1e-9) and np.allclose(
                    r.tilts[i], single_r.tilts, rtol=0, atol=1e-12):
                agree += 1
                np.testing.assert_allclose(k.thrusts[i], single_k.thrusts, rtol=0, atol=1e-9)
                np.testing.assert_allclose(k.tilts[i], single_k.tilts, rtol=0, atol=1e-9)
        assert agree >= 0.9 * len(taus)
    tally.check_ties(0.05)


def test_backend_is_chosen_per_allocator_and_checked() -> None:
    ref, ker = pair()
    assert (ref.backend, ker.backend) == ('numpy', 'numba')
    # Built, an allocator never compiles again: every allocation kernel is compiled for
    # its signatures and sealed (a call with other types would raise, not compile).
    kernels = jit.registered(['allocation'])
    assert {'allocate', 'allocate_fixed', 'thrusts_at', 'allocate_batch'} <= {
        k.name.rsplit('.', 1)[1] for k in kernels}
    assert all(k.sealed for k in kernels)
    assert ThrustAllocator(L, D).backend == jit.backend()
    with pytest.raises(AllocationError, match="backend must be None, 'numba' or 'numpy'"):
        ThrustAllocator(L, D, backend='fortran')
    with pytest.raises(AllocationError, match='wrench must have shape'):
        ker.allocate(np.zeros(5))
    with pytest.raises(AllocationError, match='previous_tilts must have shape'):
        ker.allocate_batch(np.zeros((3, 6)), np.zeros((2, 2)))
