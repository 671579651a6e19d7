"""Benchmark: the random station-keeping campaign, hold rate and worst runs.

Runs :func:`tiltrov_ros.core.station_keeping.sample_cases` ``(n, seed)`` with
pd and pid headless (the shipped robot, controller and allocator files, each
case's current, center-of-mass error and servo rate), judges every run with
:func:`~tiltrov_ros.core.station_keeping.hold_verdict` and prints the hold rate
per controller, the runs that did not hold with their reasons, and the worst
final errors. Baseline in the same run: the paper-mode allocator on the same
cases (``--no-paper`` skips it).

Run: ``python bench/bench_station_keeping.py [--cases 50] [--seed 1] [--jobs 2]``
(about a second per run and core); ``main()`` returns the numbers as a dict.
"""

from __future__ import annotations

import argparse
from concurrent.futures import ProcessPoolExecutor
import json
import math
from pathlib import Path
import time
from typing import Any

from tiltrov_ros.core.allocation import AllocatorConfig
from tiltrov_ros.core.station_keeping import (
    CONTROLLERS,
    CaseResult,
    run_case,
    sample_case,
)

DEFAULT_CASES = 50
DEFAULT_SEED = 1


def _paper(config: Any) -> Any:
    mapping = {'mode': 'paper', 'max_tilt_step': config.allocator.max_tilt_step,
               'weights': list(config.allocator.weights)}
    return AllocatorConfig.from_mapping(mapping).build(config.robot, config.control_period)


def _job(args: tuple[int, int, str, str]) -> tuple[CaseResult, float]:
    seed, index, controller, mode = args
    start = time.perf_counter()
    result = run_case(sample_case(seed, index), controller,
                      allocator=_paper if mode == 'paper' else None)
    return result, time.perf_counter() - start


def _position_error(result: CaseResult) -> float:
    final = result.metrics['final_error']
    return math.sqrt(sum(final[d] ** 2 for d in ('x', 'y', 'z')))


def campaign(cases: int, seed: int, mode: str, jobs: int) -> list[tuple[CaseResult, float]]:
    work = [(seed, i, c, mode) for i in range(cases) for c in CONTROLLERS]
    if jobs <= 1:
        return [_job(w) for w in work]
    with ProcessPoolExecutor(jobs) as pool:
        return list(pool.map(_job, work, chunksize=2))


def report(mode: str, runs: list[tuple[CaseResult, float]], worst: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    print(f'\nallocator {mode}:')
    for controller in CONTROLLERS:
        mine = [r for r, _ in runs if r.controller == controller]
        held = sum(r.verdict.held for r in mine)
        out[f'{mode}_{controller}_held'] = held
        out[f'{mode}_{controller}_runs'] = len(mine)
        print(f'  {controller:4s} held {held} of {len(mine)}')
    failed = [r for r, _ in runs if not r.verdict.held]
    for r in failed:
        print(f'  FAILED case {r.case.index} {r.controller}: {r.case.describe()}')
        print(f'         infeasible {100 * (r.metrics["infeasible_fraction"] or 0):.0f} % of '
              f'ticks; ' + '; '.join(r.verdict.reasons[:4]))
    ranked = sorted((r for r, _ in runs), key=_position_error, reverse=True)[:worst]
    print('  worst final position errors:')
    for r in ranked:
        yaw = math.degrees(r.metrics['oscillation_std']['yaw'])
        print(f'    case {r.case.index:3d} {r.controller:4s} {1000 * _position_error(r):8.1f} mm'
              f'   yaw std {yaw:6.2f} deg   {"held" if r.verdict.held else "NOT HELD"}')
    seconds = [s for _, s in runs]
    out[f'{mode}_seconds_per_run'] = sum(seconds) / max(len(seconds), 1)
    out[f'{mode}_failed'] = [(r.case.index, r.controller) for r in failed]
    return out


def main(cases: int = DEFAULT_CASES, seed: int = DEFAULT_SEED, jobs: int = 2,
         paper: bool = True, worst: int = 5, json_out: Path | None = None) -> dict[str, Any]:
    print(f'random station keeping: {cases} cases x {CONTROLLERS}, seed {seed}, '
          f'{jobs} process(es)')
    results: dict[str, Any] = {'cases': cases, 'seed': seed}
    for mode in ('robust', 'paper') if paper else ('robust',):
        start = time.perf_counter()
        runs = campaign(cases, seed, mode, jobs)
        results.update(report(mode, runs, worst))
        results[f'{mode}_wall_s'] = time.perf_counter() - start
        print(f'  {len(runs)} runs in {results[f"{mode}_wall_s"]:.1f} s wall, '
              f'{results[f"{mode}_seconds_per_run"]:.2f} s per run')
    if json_out is not None:
        json_out.write_text(json.dumps(results, indent=2) + '\n', encoding='utf-8')
    return results


if __name__ == '__main__':
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--cases', type=int, default=DEFAULT_CASES)
    parser.add_argument('--seed', type=int, default=DEFAULT_SEED)
    parser.add_argument('--jobs', type=int, default=2)
    parser.add_argument('--no-paper', action='store_true')
    parser.add_argument('--worst', type=int, default=5)
    parser.add_argument('--json', type=Path)
    a = parser.parse_args()
    main(a.cases, a.seed, a.jobs, not a.no_paper, a.worst, a.json)
