"""Benchmark: thrust allocation speed, against a generic solver measured in the same run.

Robust mode as the ``thrust_allocator`` node runs it (tilt step 7.5 deg per
call, ``previous`` given, the planner on):

* attainable: ``allocate`` on wrenches made from random thrusts and tilts in
  range, ``previous`` within one step of tilts that produce them (the closed
  form answers); p50 and p99 per call;
* unattainable: ``allocate`` on wrenches no configuration produces (random
  six-DOF demands beyond the limits, sway + heave, small random ones), from
  random ``previous`` tilts: the per-tick optimum and the planner; p50, p99;
* batch: ``allocate_batch`` throughput on 100 000 attainable wrenches with
  ``previous`` tilts (the mix of the attainable set above);
* baseline: ``scipy.optimize.least_squares`` over (f1..f4, alpha, beta) with
  the thrust bounds and the reachable tilt box, on the same problems (a local
  solver: on unattainable wrenches it stops in the nearest minimum).

Run: ``python bench/bench_allocation.py`` (or ``tiltrov bench``); ``main()``
returns the numbers as a dict.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
import math
import time
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from tiltrov_ros.core.allocation import AllocationResult, ThrustAllocator
from tiltrov_ros.core.thrust_map import thrust_wrench

L, D, FMAX = 0.6, 0.4, 40.0
STEP = math.radians(7.5)
HALF_PI = 0.5 * math.pi


def _timed(fn: Callable[[Any], object], items: Sequence[Any]) -> np.ndarray:
    """Seconds per call, one entry per item (one warm-up call first)."""
    fn(items[0])
    out = np.empty(len(items))
    for i, item in enumerate(items):
        start = time.perf_counter()
        fn(item)
        out[i] = time.perf_counter() - start
    return out


def _unattainable(rng: np.random.Generator, paper: ThrustAllocator, n: int) -> list[np.ndarray]:
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


def _generic(tau: np.ndarray, prev: np.ndarray) -> None:
    lo = np.maximum(-HALF_PI, prev - STEP)
    hi = np.minimum(HALF_PI, prev + STEP)
    least_squares(lambda x: thrust_wrench(x[:4], x[4], x[5], L, D) - tau,
                  np.concatenate([np.zeros(4), (lo + hi) / 2]),
                  bounds=(np.r_[[-FMAX] * 4, lo], np.r_[[FMAX] * 4, hi]))


def main() -> dict[str, float]:
    rng = np.random.default_rng(0)
    alloc = ThrustAllocator(L, D, FMAX, max_tilt_step=STEP)
    paper = ThrustAllocator(L, D, FMAX, mode='paper')
    n = 400
    f = rng.uniform(-FMAX, FMAX, size=(n, 4))
    tilts = rng.uniform(-HALF_PI, HALF_PI, size=(n, 2))
    attainable = thrust_wrench(f, tilts[:, 0], tilts[:, 1], L, D)
    near = np.clip(tilts + rng.uniform(-STEP, STEP, size=(n, 2)), -HALF_PI, HALF_PI)
    unattainable = _unattainable(rng, paper, 200)
    far = rng.uniform(-HALF_PI, HALF_PI, size=(len(unattainable), 2))

    def previous(t: np.ndarray) -> AllocationResult:
        return alloc.allocate_fixed(np.zeros(6), float(t[0]), float(t[1]))

    att_items = [(tau, previous(p)) for tau, p in zip(attainable, near)]
    un_items = [(tau, previous(p)) for tau, p in zip(unattainable, far)]
    att = _timed(lambda item: alloc.allocate(item[0], item[1]), att_items)
    un = _timed(lambda item: alloc.allocate(item[0], item[1]), un_items)
    exact = np.mean([alloc.allocate(t, p).feasible for t, p in att_items[:100]])

    m = 100_000
    big_tilts = rng.uniform(-HALF_PI, HALF_PI, size=(m, 2))
    big = thrust_wrench(rng.uniform(-FMAX, FMAX, size=(m, 4)), big_tilts[:, 0], big_tilts[:, 1],
                        L, D)
    big_prev = np.clip(big_tilts + rng.uniform(-STEP, STEP, size=(m, 2)), -HALF_PI, HALF_PI)
    start = time.perf_counter()
    alloc.allocate_batch(big, big_prev)
    batch_rate = m / (time.perf_counter() - start)

    ls_att = _timed(lambda item: _generic(item[0], item[1]), list(zip(attainable, near))[:100])
    ls_un = _timed(lambda item: _generic(item[0], item[1]), list(zip(unattainable, far))[:50])

    us = 1e6
    results = {
        'attainable_p50_us': float(np.percentile(att, 50) * us),
        'attainable_p99_us': float(np.percentile(att, 99) * us),
        'attainable_exact_share': float(exact),
        'unattainable_p50_us': float(np.percentile(un, 50) * us),
        'unattainable_p99_us': float(np.percentile(un, 99) * us),
        'batch_per_s': batch_rate,
        'least_squares_attainable_p50_us': float(np.percentile(ls_att, 50) * us),
        'least_squares_unattainable_p50_us': float(np.percentile(ls_un, 50) * us),
    }
    results['attainable_speedup'] = (results['least_squares_attainable_p50_us']
                                     / results['attainable_p50_us'])
    results['unattainable_speedup'] = (results['least_squares_unattainable_p50_us']
                                       / results['unattainable_p50_us'])
    print('thrust allocation, robust mode, 7.5 deg per call (this machine, this run)')
    print('                                 p50 [us]    p99 [us]')
    print(f"  attainable (closed form) {results['attainable_p50_us']:11.1f} "
          f"{results['attainable_p99_us']:11.1f}   ({len(att)} calls)")
    print(f"  unattainable (+ planner) {results['unattainable_p50_us']:11.1f} "
          f"{results['unattainable_p99_us']:11.1f}   ({len(un)} calls)")
    print(f"  scipy least_squares, attainable   {results['least_squares_attainable_p50_us']:9.1f}"
          f"   ({results['attainable_speedup']:.1f} x the allocator's p50)")
    print(f"  scipy least_squares, unattainable {results['least_squares_unattainable_p50_us']:9.1f}"
          f"   ({results['unattainable_speedup']:.1f} x)")
    print(f"  batch, attainable with previous   {results['batch_per_s']:9.0f} allocations/s")
    return results


if __name__ == '__main__':
    main()
