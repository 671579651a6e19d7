"""Benchmark: the allocation kernels against their numpy reference, call by call.

The robust allocator is run (numpy reference) on the allocation benchmark's
unattainable wrenches: with ``previous`` and the 7.5 deg step (the common
case), without ``previous`` (the whole range, wrapped), with ``previous`` and
no step (the whole range), on a +-120 deg range; every call it makes to
``Search.run``, ``Search.minima`` and ``planner.plan`` is recorded. Each call
is then timed through the reference and through the kernel
(``kernels/search.run``, ``minima``, ``kernels/plan.plan``; both called from
Python, the kernel's inputs packed beforehand), and ``local.evaluate``
against ``kernels/tiltcost.evaluate`` at the answers (a bound active) and at
random tilts. Per call the least of three timings counts (a preempted call
says nothing about either); p50, p99 and their ratios, in the same run. The
kernels' answers are checked on the way (cost to 1e-9).

Run: ``python bench/bench_allocation_search.py [--wrenches N]`` (or
``tiltrov bench allocation_search``); ``main()`` returns the numbers as a dict.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator
from contextlib import contextmanager
import inspect
import math
from pathlib import Path
import sys
import time
from typing import Any

import numpy as np

from tiltrov_ros.core import jit
from tiltrov_ros.core.allocation import ThrustAllocator, planner, robust
from tiltrov_ros.core.allocation.kernels import layout as lay
from tiltrov_ros.core.allocation.kernels import plan as kplan
from tiltrov_ros.core.allocation.kernels import search as ksearch
from tiltrov_ros.core.allocation.kernels import tiltcost
from tiltrov_ros.core.allocation.local import evaluate
from tiltrov_ros.core.allocation.optimum import Search
from tiltrov_ros.core.allocation.thrusts import TiltProblem

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_allocation import FMAX, STEP, D, L, _unattainable

REPEATS = 3
NAN2 = np.array([math.nan, math.nan])


@contextmanager
def _recording(calls: dict[str, list[Any]]) -> Iterator[None]:
    """Record the robust fallback's searches and plans (with their kernel inputs)."""
    search_cls, plan_fn = robust.Search, robust.plan

    def packed(problem: TiltProblem) -> np.ndarray:
        return problem.prob  # type: ignore[attr-defined, no-any-return]

    class Recorder(Search):
        def run(self, starts: Any = (), seeds: int = 3) -> Any:
            rows = np.array([s for s in starts], dtype=float).reshape(-1, 2)
            anchor = self.anchor
            calls['run'].append((self.problem, packed(self.problem), (
                np.ascontiguousarray(self.box), list(starts), anchor, math.sqrt(self.mu2),
                self.periodic, rows if len(rows) else np.zeros((1, 2)), len(rows))))
            return super().run(starts, seeds)

        def minima(self, count: int, below: float) -> Any:
            calls['minima'].append((self.problem, packed(self.problem),
                                    (np.ascontiguousarray(self.box), self.periodic, count, below)))
            return super().minima(count, below)

    def plan(problem: TiltProblem, start: Any, step: float, local: float, targets: Any,
             horizon: int, kept: Any = None) -> Any:
        rows = np.array([(*t.tilts, t.cost) for t in targets], dtype=float).reshape(-1, 3)
        calls['plan'].append((problem, packed(problem), (
            np.array(start, dtype=float), step, local, targets, rows, horizon, kept)))
        return plan_fn(problem, start, step, local, targets, horizon, kept)

    original_problem = robust.TiltProblem

    class Packed(TiltProblem):
        def __init__(self, geometry: Any, tau: Any, max_thrust: float, weights: Any,
                     available: Any = None) -> None:
            super().__init__(geometry, tau, max_thrust, weights, available)
            cfg = np.zeros(lay.CFG_SIZE)
            cfg[[lay.CFG_L, lay.CFG_W, lay.CFG_K, lay.CFG_FMAX]] = (
                geometry.length, geometry.width, geometry.k, max_thrust)
            cfg[lay.CFG_WEIGHTS:lay.CFG_WEIGHTS + 6] = weights
            cfg[lay.CFG_AVAILABLE:lay.CFG_AVAILABLE + 4] = self.available
            self.prob = np.empty(lay.PROB_SIZE)
            tiltcost.problem(cfg, np.asarray(tau, dtype=float), self.prob)

    robust.Search, robust.plan, robust.TiltProblem = Recorder, plan, Packed  # type: ignore[misc]
    try:
        yield
    finally:
        robust.Search, robust.plan, robust.TiltProblem = search_cls, plan_fn, original_problem


def _capture(n: int) -> dict[str, list[Any]]:
    rng = np.random.default_rng(7)
    # The reference allocator (robust.fallback) makes the calls, whatever the backend.
    reference = ({'backend': 'numpy'}
                 if 'backend' in inspect.signature(ThrustAllocator).parameters else {})
    paper = ThrustAllocator(L, D, FMAX, mode='paper')
    reach = ThrustAllocator(L, D, FMAX, max_tilt_step=STEP, **reference)
    free = ThrustAllocator(L, D, FMAX, **reference)
    wide = ThrustAllocator(L, D, FMAX, tilt_limits=(-2 * math.pi / 3, 2 * math.pi / 3),
                           max_tilt_step=STEP, **reference)
    calls: dict[str, list[Any]] = {'run': [], 'minima': [], 'plan': []}
    with _recording(calls):
        for tau in _unattainable(rng, paper, n):
            prev = rng.uniform(-0.5 * math.pi, 0.5 * math.pi, 2)
            for alloc in (reach, free, wide):
                alloc.allocate(tau, alloc.allocate_fixed(np.zeros(6), prev[0], prev[1]))
            reach.allocate(tau)
    return calls


def _timed(fn: Callable[..., Any], *args: Any) -> tuple[float, Any]:
    """Seconds of fn(*args), the least of REPEATS calls, and its result."""
    best, out = math.inf, None
    for _ in range(REPEATS):
        start = time.perf_counter()
        out = fn(*args)
        best = min(best, time.perf_counter() - start)
    return best, out


def _kind(box: np.ndarray, periodic: tuple[bool, bool]) -> str:
    if periodic[0]:
        return 'run, whole range (wrapped)'
    return 'run, 7.5 deg reach' if box[0, 1] - box[0, 0] < 0.3 else 'run, whole range'


def main(wrenches: int = 150) -> dict[str, float]:
    start = time.perf_counter()
    jit.warmup(['allocation'])
    warm = time.perf_counter() - start
    calls = _capture(wrenches)
    times: dict[str, tuple[list[float], list[float]]] = {}
    rec = np.empty(lay.REC_SIZE)
    recs = np.empty((4, lay.REC_SIZE))
    out = np.empty(5)
    hint = np.zeros(4, dtype=np.int64)
    mismatches = 0
    rng = np.random.default_rng(8)
    for problem, prob, (box, starts, anchor, penalty, periodic, rows, n) in calls['run']:
        ref_t, e = _timed(Search(problem, box, anchor, penalty, periodic).run, starts)
        args = (prob, box, np.zeros(2) if anchor is None else np.asarray(anchor, dtype=float),
                anchor is not None, penalty, periodic[0], periodic[1], rows, n, rec)
        ker_t, _ = _timed(ksearch.run, *args)
        mismatches += abs(rec[lay.REC_COST] - e.cost) > 1e-9 * e.cost + 1e-15
        times.setdefault(_kind(box, periodic), ([], []))[0].append(ref_t)
        times[_kind(box, periodic)][1].append(ker_t)
        for a, b in ((e.a, e.b), tuple(rng.uniform(-1.5, 1.5, 2))):
            kind = ('evaluate, a bound active' if evaluate(problem, a, b).bounds != (0, 0, 0, 0)
                    else 'evaluate, no bound active')
            ref_t, _ = _timed(evaluate, problem, a, b)
            ker_t, _ = _timed(tiltcost.evaluate, prob, a, b, hint, False, rec)
            times.setdefault(kind, ([], []))[0].append(ref_t)
            times[kind][1].append(ker_t)
    for problem, prob, (box, periodic, count, below) in calls['minima']:
        ref_t, m = _timed(Search(problem, box, periodic=periodic).minima, count, below)
        ker_t, found = _timed(ksearch.minima, prob, box, periodic[0], periodic[1], count, below,
                              recs)
        mismatches += found != len(m)
        times.setdefault('minima, whole range', ([], []))[0].append(ref_t)
        times['minima, whole range'][1].append(ker_t)
    for problem, prob, (begin, step, local, targets, rows, horizon, kept) in calls['plan']:
        ref_t, p = _timed(planner.plan, problem, begin, step, local, targets, horizon, kept)
        keep = NAN2 if kept is None else np.asarray(kept, dtype=float)
        ker_t, chosen = _timed(kplan.plan, prob, begin, step, local, rows, len(rows), horizon,
                               keep, out)
        mismatches += chosen != (p is not None)
        times.setdefault('plan', ([], []))[0].append(ref_t)
        times['plan'][1].append(ker_t)
    print(f'allocation kernels against the numpy reference (this machine, this run; '
          f'warm-up {warm:.2f} s, {mismatches} answers differing)')
    print('                               calls   reference p50 / p99 [us]'
          '   kernel p50 / p99 [us]   ratio p50 / p99')
    results: dict[str, float] = {'warmup_s': warm, 'mismatches': float(mismatches)}
    for name, (ref, ker) in times.items():
        r50, r99 = np.percentile(ref, 50) * 1e6, np.percentile(ref, 99) * 1e6
        k50, k99 = np.percentile(ker, 50) * 1e6, np.percentile(ker, 99) * 1e6
        print(f'  {name:28s} {len(ref):5d}   {r50:9.1f} / {r99:8.1f}   '
              f'{k50:9.1f} / {k99:8.1f}   {r50 / k50:6.1f}x / {r99 / k99:5.1f}x')
        key = name.replace(', ', '_').replace(' ', '_').replace('.', '').replace('(', '') \
            .replace(')', '')
        results.update({f'{key}_ref_p50_us': r50, f'{key}_ref_p99_us': r99,
                        f'{key}_kernel_p50_us': k50, f'{key}_kernel_p99_us': k99})
    return results


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--wrenches', type=int, default=150)
    main(parser.parse_args().wrenches)
