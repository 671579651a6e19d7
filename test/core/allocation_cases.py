"""Seeded allocation problems for the tests that pin the kernels to the numpy reference.

The wrenches come from the allocation tests' own generators (attainable ones
made from random thrusts and tilts, unattainable ones by the paper mode's
verdict), plus the same scaled far beyond the thrust limit; each problem comes
with a weighting (the defaults, the failed-thruster defaults or random ones)
and the thrusters available (all, or one failed). Every problem is given both
as the reference's :class:`TiltProblem` and as the kernels' flat ``prob``.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np
from test_allocation import FMAX, D, L, _attainable
from test_allocation_optimum import _unattainable

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation import DEFAULT_WEIGHTS, FAILED_WEIGHTS
from tiltrov_ros.core.allocation.decomposition import Geometry
from tiltrov_ros.core.allocation.kernels import layout as lay
from tiltrov_ros.core.allocation.kernels.tiltcost import problem as kernel_problem
from tiltrov_ros.core.allocation.thrusts import TiltProblem

HALF_PI = 0.5 * math.pi
STEP = math.radians(7.5)
#: Tilts where the thrust map is singular or the range ends, met exactly.
SPECIAL_TILTS = (0.0, HALF_PI, -HALF_PI, math.pi, -math.pi, 2 * math.pi / 3,
                 -2 * math.pi / 3)
#: Tilt ranges: the shipped +-90 deg and wider than pi (+-120 deg, +-180 deg).
RANGES = ((-HALF_PI, HALF_PI), (-2 * math.pi / 3, 2 * math.pi / 3), (-math.pi, math.pi))


def count(numba_count: int, numpy_count: int) -> int:
    """How many seeded cases a test runs: the kernels run as plain Python under
    ``TILTROV_BACKEND=numpy``, a few hundred times slower, so fewer there."""
    return numba_count if jit.compiled() else numpy_count


def config(weights: np.ndarray, available: np.ndarray) -> np.ndarray:
    """The allocator config fields the tilt problem reads (layout ``CFG_*``)."""
    cfg = np.zeros(lay.CFG_SIZE)
    cfg[lay.CFG_L], cfg[lay.CFG_W], cfg[lay.CFG_K] = L, D, Geometry(L, D).k
    cfg[lay.CFG_FMAX] = FMAX
    cfg[lay.CFG_WEIGHTS:lay.CFG_WEIGHTS + 6] = weights
    cfg[lay.CFG_AVAILABLE:lay.CFG_AVAILABLE + 4] = available
    return cfg


@dataclass(frozen=True)
class Case:
    """One wrench with its weights and working thrusters, for both implementations."""

    tau: np.ndarray
    weights: np.ndarray
    available: np.ndarray          # bool (4,)
    reference: TiltProblem
    prob: np.ndarray               # float64[PROB_SIZE]


def make_case(tau: np.ndarray, weights: np.ndarray, available: np.ndarray) -> Case:
    reference = TiltProblem(Geometry(L, D), tau, FMAX, weights, available)
    prob = np.empty(lay.PROB_SIZE)
    kernel_problem(config(weights, available.astype(float)),
                   np.ascontiguousarray(tau, dtype=float), prob)
    return Case(np.asarray(tau, dtype=float), weights, available, reference, prob)


def cases(seed: int, n: int) -> list[Case]:
    """``n`` seeded cases cycling through the kinds of wrench, weights and failures."""
    rng = np.random.default_rng(seed)
    unattainable = _unattainable(seed, n)
    attainable = _attainable(rng, n)
    out = []
    for i in range(n):
        kind = i % 3
        if kind == 0:
            tau = unattainable[i]
        elif kind == 1:
            tau = attainable[i]
        else:                                   # far beyond the thrust limit
            tau = attainable[i] * rng.uniform(3.0, 30.0)
        weights = (np.array(DEFAULT_WEIGHTS) if i % 4 == 0 else
                   np.array(FAILED_WEIGHTS) if i % 4 == 1 else rng.uniform(0.2, 5.0, 6))
        available = np.ones(4, dtype=bool)
        if i % 5 == 4:
            available[rng.integers(4)] = False
        out.append(make_case(tau, weights, available))
    return out


def tilts(rng: np.random.Generator, n: int, wide: bool = True) -> np.ndarray:
    """(n, 2) tilts: random over +-180 deg (+-90 deg unless ``wide``), a third of them
    with one or both at a special tilt."""
    span = math.pi if wide else HALF_PI
    out = rng.uniform(-span, span, (n, 2))
    special = np.array([t for t in SPECIAL_TILTS if abs(t) <= span])
    for i in range(0, n, 3):
        which = rng.integers(3)
        pick = rng.choice(special, 2)
        if which == 2:
            out[i] = pick
        else:
            out[i, which] = pick[0]
    return out


def atol(case: Case) -> float:
    """The absolute floor of the comparisons: 1e-12 sum(w^2) (scaled units).

    Every cost, gradient and Hessian entry is a sum of terms of at most about
    sum(w^2) in size (the scaled wrench and thrusts are at most 1), so that is
    where rounding lives when the sum cancels (the gradient at a minimum, the
    cost of an attainable wrench); measured, the two implementations differ by
    at most 6e-17 of it.
    """
    return 1e-12 * float(np.sum(case.weights ** 2))


def assert_close(kernel: np.ndarray, reference: np.ndarray, absolute: float,
                 what: str) -> None:
    """Relative 1e-9 with the absolute floor ``absolute`` (see :func:`atol`)."""
    np.testing.assert_allclose(kernel, reference, rtol=1e-9, atol=absolute, err_msg=what)
