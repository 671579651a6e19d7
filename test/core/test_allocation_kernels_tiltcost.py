"""The reduced-cost kernels (``kernels/tiltcost.py``) against the numpy reference.

``problem``, ``bounds`` and ``evaluate`` are pinned to ``TiltProblem`` and
``local.evaluate`` on seeded cases (``allocation_cases``): attainable
wrenches, unattainable ones, wrenches far beyond the thrust limit; default,
failed-thruster and random weights; one thruster failed in a fifth of them;
tilts over +-180 deg, a third of them at 0, +-90, +-120 or +-180 deg exactly;
with no hint, the all-free hint and random ones. Relative 1e-9 everywhere
with the absolute floor ``allocation_cases.atol`` (1e-12 sum(w^2), scaled
units) where a result cancels. Bounds states equal exactly.
"""

from __future__ import annotations

import itertools
import math

from allocation_cases import assert_close, atol, cases, count, tilts
import numpy as np
import pytest

from tiltrov_ros.core.allocation.kernels import activeset, tiltcost
from tiltrov_ros.core.allocation.kernels import layout as lay
from tiltrov_ros.core.allocation.local import evaluate
from tiltrov_ros.core.allocation.thrusts import _enumerate

CASES = cases(seed=31, n=count(240, 60))


def _record(e: object) -> np.ndarray:
    """A reference Evaluation as the kernels' flat record."""
    a, b, cost, grad, hess, thrusts, bounds = e  # type: ignore[misc]
    return np.array([a, b, cost, *grad, *hess, *thrusts, *bounds], dtype=float)


def test_problem_fills_the_reference_problems_fields() -> None:
    for case in CASES:
        ref, prob = case.reference, case.prob
        fields = {lay.PROB_SCALE: [ref.scale], lay.PROB_FMAX: [ref.fmax],
                  lay.PROB_UPPER: ref.upper, lay.PROB_S_COEF: ref.s_coef,
                  lay.PROB_D_COEF: ref.d_coef, lay.PROB_S_TARGET: ref.s_target,
                  lay.PROB_D_TARGET: ref.d_target, lay.PROB_TARGET_NORM2: [ref.target_norm2],
                  lay.PROB_ALL_AVAILABLE: [float(ref.all_available)],
                  lay.PROB_AVAILABLE: ref.available.astype(float), lay.PROB_TAU: ref.tau}
        for start, values in fields.items():
            values = np.asarray(values, dtype=float)
            assert_close(prob[start:start + len(values)], values, 0.0, f'prob[{start}]')


def test_bounds_equal_the_reference_on_grids_and_points() -> None:
    rng = np.random.default_rng(32)
    for case in CASES:
        t = tilts(rng, 12)
        lower, upper = case.reference.bounds(t[:, 0], t[:, 1])
        klo, kup = np.empty(len(t)), np.empty(len(t))
        tiltcost.bounds_grid(case.prob, np.ascontiguousarray(t[:, 0]),
                             np.ascontiguousarray(t[:, 1]), klo, kup)
        floor = atol(case)
        assert_close(klo, lower, floor, 'lower')
        assert_close(kup, upper, floor, 'upper')
        for i in range(3):
            lo, up = tiltcost.bounds(case.prob, float(t[i, 0]), float(t[i, 1]))
            assert_close(np.array([lo, up]), np.array([lower[i], upper[i]]), floor, 'point')


@pytest.mark.parametrize('hints', ['none', 'all free', 'random'])
def test_evaluate_equals_the_reference(hints: str) -> None:
    """Cost, gradient, Hessian, thrusts to 1e-9; bounds states exactly; every path
    (no bound active, the active set, failed thrusters) is met."""
    rng = np.random.default_rng(33)
    rec = np.empty(lay.REC_SIZE)
    met = {'free': 0, 'bound': 0, 'failed': 0}
    for case in CASES:
        for a, b in tilts(rng, 4):
            hint = (None if hints == 'none' else (0, 0, 0, 0) if hints == 'all free'
                    else tuple(int(v) for v in rng.integers(-1, 3, 4)))
            ref = _record(evaluate(case.reference, float(a), float(b), hint))
            tiltcost.evaluate(case.prob, float(a), float(b),
                              np.array(hint or (0, 0, 0, 0), dtype=np.int64), hint is not None,
                              rec)
            what = f'tau={case.tau.tolist()} w={case.weights.tolist()} a={a} b={b} hint={hint}'
            bounds = slice(lay.REC_BOUNDS, lay.REC_BOUNDS + 4)
            assert rec[bounds].tolist() == ref[bounds].tolist(), what
            assert_close(rec[:lay.REC_BOUNDS], ref[:lay.REC_BOUNDS], atol(case), what)
            states = set(ref[bounds].tolist())
            met['failed' if 2.0 in states else 'bound' if states - {0.0} else 'free'] += 1
    assert all(met.values()), met


def test_the_enumeration_fallback_equals_the_reference() -> None:
    """The 3^4 active sets (reached when the active-set method does not settle,
    which no seeded evaluation does): random positive definite normal equations,
    with and without a failed thruster."""
    rng = np.random.default_rng(34)
    prob = np.zeros(lay.PROB_SIZE)
    work = np.zeros(activeset.WORK_SIZE)
    iwork = np.zeros(activeset.IWORK_SIZE, dtype=np.int64)
    for i in range(count(400, 40)):
        m = rng.normal(size=(4, 4)) * rng.uniform(0.1, 10.0, 4)
        G = m @ m.T + 1e-9 * np.eye(4)
        g = rng.normal(size=4) * rng.uniform(0.1, 20.0)
        up = np.full(4, rng.uniform(0.05, 1.0))
        if i % 3 == 0:
            up[rng.integers(4)] = 0.0
        prob[lay.PROB_UPPER:lay.PROB_UPPER + 4] = up
        work[activeset._MATS:activeset._MATS + 16] = G.ravel()
        work[activeset._VECS:activeset._VECS + 4] = g
        activeset._enumerate(prob, work, iwork)
        ref = _enumerate(G[None], g[None], -up, up)[0]
        assert_close(work[activeset._X:activeset._X + 4], ref, 1e-12, f'G={G} g={g} up={up}')


def test_evaluate_on_a_grid_of_special_tilts_with_every_hint() -> None:
    """Both tilts at every special angle, every hint pattern of -1/0/+1, one case of
    each kind: the edges of the thrust map with the active set started anywhere."""
    rec = np.empty(lay.REC_SIZE)
    special = (0.0, 0.5 * math.pi, -0.5 * math.pi, math.pi)
    patterns = list(itertools.product((-1, 0, 1), repeat=4))
    for case in CASES[:count(6, 3)]:
        for a, b in itertools.product(special, repeat=2):
            for hint in patterns[::count(1, 9)]:
                ref = _record(evaluate(case.reference, a, b, hint))
                tiltcost.evaluate(case.prob, a, b, np.array(hint, dtype=np.int64), True, rec)
                assert rec[lay.REC_BOUNDS:].tolist() == ref[lay.REC_BOUNDS:].tolist()
                assert_close(rec[:lay.REC_BOUNDS], ref[:lay.REC_BOUNDS], atol(case),
                             f'{case.tau.tolist()} {a} {b} {hint}')
