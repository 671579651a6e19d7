"""Benchmark: the allocator's compiled kernels against its numpy reference, in the same run.

Both backends of ``ThrustAllocator`` (``backend='numba'`` and ``'numpy'``) on
the same calls, robust mode, 7.5 deg per call:

* attainable, closed form: random thrusts and tilts in range, ``previous``
  within one step of the tilts (as ``bench_allocation.py``); p50, p99;
* attainable, family path: the calls of a headless ``pitch_hold`` run (pid)
  that the reference answers from a one-parameter family (hovering and the
  wrenches near it); p50, p99;
* unattainable: wrenches no configuration produces (``bench_allocation.py``'s
  set), from random ``previous`` tilts (the per-tick optimum within reach and
  the planner) and without ``previous`` (the whole range); p50, p99;
* ``allocate_batch``: 100 000 attainable wrenches with ``previous`` tilts;
* the headless ``current_hold`` run (pid), loop only, in a fresh process per
  backend (``TILTROV_BACKEND``), and ``jit.warmup(['allocation'])`` there;
  ``--cold`` adds a start on an empty kernel cache (``NUMBA_CACHE_DIR``).

Run: ``python bench/bench_allocation_kernels.py [--cold]``; ``main()`` returns
the numbers as a dict. Times on a loaded machine are only good as ratios.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation import AllocationResult, ThrustAllocator
from tiltrov_ros.core.runner import run, stack_config
from tiltrov_ros.core.thrust_map import thrust_wrench

L, D, FMAX = 0.6, 0.4, 40.0
STEP = math.radians(7.5)
HALF_PI = 0.5 * math.pi
Call = tuple[np.ndarray, AllocationResult | None]

# A fresh process: warm-up time, then the headless current_hold loop (pid).
_RUN = """
import json, sys, time
t0 = time.perf_counter()
from tiltrov_ros.core import jit
from tiltrov_ros.core.runner import run_scenario, stack_config
imported = time.perf_counter() - t0
warm = jit.warmup(['allocation'])
config = stack_config('current_hold', 'pid')
config.build_allocator()
t0 = time.perf_counter()
log = run_scenario(config, duration=float(sys.argv[1]))
loop = time.perf_counter() - t0
print(json.dumps({'backend': jit.backend(), 'import_s': imported, 'warmup_s': warm,
                  'loop_s': loop}))
"""


def _timed(fn: Callable[[Call], object], items: Sequence[Call]) -> np.ndarray:
    """Seconds per call (one warm-up call first)."""
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


class _Recorder:
    """The allocator of a headless run, keeping every ``allocate`` call."""

    def __init__(self, inner: ThrustAllocator) -> None:
        self.inner = inner
        self.calls: list[tuple[Call, str]] = []

    def allocate(self, wrench: Any, previous: AllocationResult | None = None
                 ) -> AllocationResult:
        tau = np.array(wrench, dtype=float)
        result = self.inner.allocate(tau, previous)
        self.calls.append(((tau, previous), result.method))
        return result

    def allocate_fixed(self, wrench: Any, tilt_front: float, tilt_rear: float,
                       previous: AllocationResult | None = None) -> AllocationResult:
        return self.inner.allocate_fixed(wrench, tilt_front, tilt_rear, previous)


def _family_calls(duration: float) -> list[Call]:
    """The calls of a headless pitch_hold run (pid) answered on a family."""
    config = stack_config('pitch_hold', 'pid')
    recorder = _Recorder(config.build_allocator())
    profile = config.scenario.reference
    run(config.build_plant(), config.build_controller(), recorder, profile.at, duration,
        control_period_ns=config.control_period_ns)
    return [call for call, method in recorder.calls if method in ('family', 'zero')]


def _headless(backend: str, duration: float, cache: str | None = None) -> dict[str, Any]:
    env = dict(os.environ, TILTROV_BACKEND=backend)
    if cache is not None:
        env['NUMBA_CACHE_DIR'] = cache
    out = subprocess.run([sys.executable, '-c', _RUN, str(duration)], env=env, check=True,
                         capture_output=True, text=True).stdout
    result: dict[str, Any] = json.loads(out.strip().splitlines()[-1])
    return result


def _pair(name: str, times: dict[str, np.ndarray], results: dict[str, float]) -> None:
    ref, ker = times['numpy'], times['numba']
    for q in (50, 99):
        r, k = np.percentile(ref, q) * 1e6, np.percentile(ker, q) * 1e6
        results[f'{name}_p{q}_us'] = float(k)
        results[f'{name}_reference_p{q}_us'] = float(r)
    print(f'  {name:28s} {results[f"{name}_p50_us"]:9.1f} {results[f"{name}_p99_us"]:9.1f}'
          f'   reference {results[f"{name}_reference_p50_us"]:9.1f} '
          f'{results[f"{name}_reference_p99_us"]:9.1f}'
          f'   ({results[f"{name}_reference_p50_us"] / results[f"{name}_p50_us"]:.0f}x p50, '
          f'{results[f"{name}_reference_p99_us"] / results[f"{name}_p99_us"]:.0f}x p99; '
          f'{len(ker)} calls)')


def main(argv: Sequence[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--cold', action='store_true',
                        help='also start on an empty kernel cache (a minute or more)')
    parser.add_argument('--duration', type=float, default=20.0,
                        help='simulated seconds of the headless runs (default 20)')
    args = parser.parse_args([] if argv is None else argv)
    if not jit.compiled():
        print('bench_allocation_kernels: the compiled kernels are not available in this '
              f'process ({jit.describe()["reason"]}); nothing to compare')
        return {}
    rng = np.random.default_rng(0)
    backends = {name: ThrustAllocator(L, D, FMAX, max_tilt_step=STEP, backend=name)
                for name in ('numpy', 'numba')}
    paper = ThrustAllocator(L, D, FMAX, mode='paper', backend='numba')
    n = 2000
    f = rng.uniform(-FMAX, FMAX, size=(n, 4))
    tilts = rng.uniform(-HALF_PI, HALF_PI, size=(n, 2))
    attainable = thrust_wrench(f, tilts[:, 0], tilts[:, 1], L, D)
    near = np.clip(tilts + rng.uniform(-STEP, STEP, size=(n, 2)), -HALF_PI, HALF_PI)
    unattainable = _unattainable(rng, paper, 300)
    far = rng.uniform(-HALF_PI, HALF_PI, size=(len(unattainable), 2))

    def previous(t: np.ndarray) -> AllocationResult:
        return backends['numpy'].allocate_fixed(np.zeros(6), float(t[0]), float(t[1]))

    sets: dict[str, list[Call]] = {
        'attainable': [(tau, previous(p)) for tau, p in zip(attainable, near)],
        'family': _family_calls(args.duration),
        'unattainable_previous': [(tau, previous(p)) for tau, p in zip(unattainable, far)],
        'unattainable_none': [(tau, None) for tau in unattainable],
    }
    results: dict[str, float] = {}
    print('ThrustAllocator.allocate, robust mode, 7.5 deg per call: compiled kernels against '
          'the numpy reference (this machine, this run)')
    print('                                p50 [us]  p99 [us]')
    for name, items in sets.items():
        times = {b: _timed(lambda item, a=a: a.allocate(item[0], item[1]), items)
                 for b, a in backends.items()}
        _pair(name, times, results)

    m = 100_000
    big_tilts = rng.uniform(-HALF_PI, HALF_PI, size=(m, 2))
    big = thrust_wrench(rng.uniform(-FMAX, FMAX, size=(m, 4)), big_tilts[:, 0], big_tilts[:, 1],
                        L, D)
    big_prev = np.clip(big_tilts + rng.uniform(-STEP, STEP, size=(m, 2)), -HALF_PI, HALF_PI)
    for name, alloc in backends.items():
        alloc.allocate_batch(big[:10], big_prev[:10])
        start = time.perf_counter()
        alloc.allocate_batch(big, big_prev)
        key = 'batch_per_s' if name == 'numba' else 'batch_reference_per_s'
        results[key] = m / (time.perf_counter() - start)
    print(f"  allocate_batch, attainable with previous: {results['batch_per_s']:10.0f}/s   "
          f"reference {results['batch_reference_per_s']:10.0f}/s   "
          f"({results['batch_per_s'] / results['batch_reference_per_s']:.1f}x)")

    runs = {b: _headless(b, args.duration) for b in ('numpy', 'numba')}
    results['current_hold_loop_s'] = runs['numba']['loop_s']
    results['current_hold_reference_loop_s'] = runs['numpy']['loop_s']
    results['warmup_warm_s'] = runs['numba']['warmup_s']
    print(f"  headless current_hold (pid, {args.duration:g} s): loop "
          f"{runs['numba']['loop_s']:.2f} s (RTF {args.duration / runs['numba']['loop_s']:.0f})"
          f"   reference {runs['numpy']['loop_s']:.2f} s (RTF "
          f"{args.duration / runs['numpy']['loop_s']:.0f})   "
          f"({runs['numpy']['loop_s'] / runs['numba']['loop_s']:.1f}x)")
    print(f"  jit.warmup(['allocation']) in a fresh process, warm cache: "
          f"{runs['numba']['warmup_s']:.2f} s (import {runs['numba']['import_s']:.2f} s)")
    if args.cold:
        with tempfile.TemporaryDirectory() as cache:
            cold = _headless('numba', 1.0, cache)
            again = _headless('numba', 1.0, cache)
        results['warmup_cold_s'] = cold['warmup_s']
        results['warmup_filled_s'] = again['warmup_s']
        print(f"  jit.warmup(['allocation']), empty cache: {cold['warmup_s']:.1f} s; the same "
              f"cache filled: {again['warmup_s']:.2f} s")
    return results


if __name__ == '__main__':
    main(sys.argv[1:])
