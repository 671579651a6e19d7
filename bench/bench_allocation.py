"""Benchmark: thrust allocation speed, against a generic solver measured in the same run.

* closed form: ``ThrustAllocator.allocate`` on attainable wrenches (one call each);
* robust fallback: ``allocate`` on unattainable wrenches (the optimiser runs);
* batch: ``allocate_batch`` throughput on attainable wrenches;
* baseline: the same attainable problems solved by scipy.optimize.least_squares
  over (f1..f4, alpha, beta) with the thrust and tilt bounds.

Run: ``python bench/bench_allocation.py`` (or ``tiltrov bench``).
"""

from __future__ import annotations

import time

import numpy as np
from scipy.optimize import least_squares

from tiltrov_ros.core.allocation import ThrustAllocator
from tiltrov_ros.core.thrust_map import thrust_wrench

L, D, FMAX = 0.6, 0.4, 40.0


def _per_call(fn, items, repeat: int = 1) -> float:
    start = time.perf_counter()
    for _ in range(repeat):
        for item in items:
            fn(item)
    return (time.perf_counter() - start) / (repeat * len(items))


def main() -> dict[str, float]:
    rng = np.random.default_rng(0)
    n = 400
    f = rng.uniform(-FMAX, FMAX, size=(n, 4))
    a, b = rng.uniform(-np.pi / 2, np.pi / 2, size=(2, n))
    attainable = thrust_wrench(f, a, b, L, D)
    unattainable = [np.array([0.0, y, z, 0, 0, 0])
                    for y, z in rng.uniform([-20, -60], [20, 60], size=(40, 2))]
    alloc = ThrustAllocator(L, D, FMAX)

    closed = _per_call(alloc.allocate, attainable, repeat=3)
    fallback = _per_call(alloc.allocate, unattainable)
    big = thrust_wrench(rng.uniform(-FMAX, FMAX, size=(100_000, 4)),
                        *rng.uniform(-np.pi / 2, np.pi / 2, size=(2, 100_000)), L, D)
    start = time.perf_counter()
    alloc.allocate_batch(big)
    batch_rate = len(big) / (time.perf_counter() - start)

    lower = [-FMAX] * 4 + [-np.pi / 2] * 2
    upper = [FMAX] * 4 + [np.pi / 2] * 2

    def generic(tau: np.ndarray) -> None:
        least_squares(lambda x: thrust_wrench(x[:4], x[4], x[5], L, D) - tau,
                      np.full(6, 0.1), bounds=(lower, upper))

    baseline = _per_call(generic, attainable[:100])
    results = {
        'closed_form_us': closed * 1e6,
        'robust_fallback_us': fallback * 1e6,
        'batch_per_s': batch_rate,
        'least_squares_us': baseline * 1e6,
        'closed_form_speedup': baseline / closed,
        'fallback_speedup': baseline / fallback,
    }
    print('thrust allocation (per call, this machine, this run)')
    print(f"  closed form              {results['closed_form_us']:10.1f} us")
    print(f"  robust fallback          {results['robust_fallback_us']:10.1f} us")
    print(f"  scipy least_squares      {results['least_squares_us']:10.1f} us   (baseline)")
    print(f"  closed form speed-up     {results['closed_form_speedup']:10.1f} x")
    print(f"  fallback speed-up        {results['fallback_speedup']:10.1f} x")
    print(f"  batch                    {results['batch_per_s']:10.0f} allocations/s")
    return results


if __name__ == '__main__':
    main()
