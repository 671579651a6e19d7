"""Benchmark (not a test): campaign runs per second on Dask against a plain serial loop.

The same runs (the first ``--samples`` samples of
``config/campaigns/station_keeping.yaml``, pd and pid, shortened to
``--duration`` s) are done, in this order, in one process:

* ``serial``: a plain loop calling the workers' function
  (:func:`tiltrov_ros.campaign.worker.run_one`) in this process;
* ``dask-1``: a LocalCluster of one worker process (one thread, BLAS pinned);
* ``dask-N``: a LocalCluster of one worker per core (``--workers``);

each through :func:`tiltrov_ros.campaign.execute.execute` with the default
batch size, timed from the first submission to the last result (the
cluster's start-up, with the workers' imports, is reported apart). The
metrics of every run must be the same in the three, or the benchmark fails.

Scheduling overhead per run, two ways:

* ``overhead_per_run_ms``: (wall time x workers - the runs' own time on the
  workers) / runs, in the dask-N campaign: what the cluster costs beyond the
  runs (scheduling, transfers, idle workers at the end);
* ``task_overhead_ms``: with runs of one control tick (about a millisecond),
  one run per task on one worker, (wall time - serial time) / runs: the cost
  of one task through the scheduler.

The three are measured in ``--repeat`` interleaved rounds and the best round
of each is reported (the one least disturbed by other work on the machine),
with every round's rate and the load average.

::

    .venv/bin/python bench/bench_campaign.py      # 12 samples x pd, pid, 20 s runs, 2 rounds
    .venv/bin/python bench/bench_campaign.py --samples 40 --duration 60

``main()`` returns the numbers as a dict.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import yaml

from tiltrov_ros.campaign.execute import batch_size, dask_client, execute
from tiltrov_ros.campaign.plan import Plan, RunTask
from tiltrov_ros.campaign.worker import RunResult, run_one
from tiltrov_ros.core.campaign import draw_samples, parse_campaign
from tiltrov_ros.paths import config_dir


def tasks(samples: int, duration: float) -> list[RunTask]:
    """The runs of the shipped station-keeping campaign, shortened."""
    path = config_dir() / 'campaigns' / 'station_keeping.yaml'
    doc = yaml.safe_load(path.read_text(encoding='utf-8'))
    doc['duration'] = duration
    spec = parse_campaign(doc, source=str(path))
    return Plan(spec).tasks(draw_samples(spec, samples))


def serial(runs: list[RunTask]) -> tuple[float, list[RunResult]]:
    start = time.perf_counter()
    results = [run_one(t) for t in runs]
    return time.perf_counter() - start, results


def on_dask(runs: list[RunTask], workers: int, size: int | None = None
            ) -> tuple[float, float, list[RunResult]]:
    """(cluster start-up s, campaign wall s, results)."""
    results: list[RunResult] = []
    start = time.perf_counter()
    with dask_client(workers=workers) as client:
        client.wait_for_workers(workers)
        client.run(exec, 'import tiltrov_ros.campaign.worker')    # imports are start-up
        started = time.perf_counter()
        execute(client, runs, results.extend, size=size)
        wall = time.perf_counter() - started
    return started - start, wall, results


def _check_same(name: str, got: list[RunResult], expected: list[RunResult]) -> None:
    mine = {r.run_id: (r.metrics, r.error) for r in got}
    if mine != {r.run_id: (r.metrics, r.error) for r in expected}:
        raise AssertionError(f'{name}: the runs gave other metrics than the serial loop')


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--samples', type=int, default=12)
    parser.add_argument('--duration', type=float, default=20.0, help='s of each run')
    parser.add_argument('--workers', type=int, default=os.cpu_count() or 1,
                        help='workers of the dask-N cluster (default: one per core)')
    parser.add_argument('--tiny-runs', type=int, default=100,
                        help='one-tick runs for the per-task overhead')
    parser.add_argument('--repeat', type=int, default=2,
                        help='rounds of the three (best of them reported)')
    args = parser.parse_args(argv)
    load_before = os.getloadavg()
    runs = tasks(args.samples, args.duration)
    out: dict[str, Any] = {'runs': len(runs), 'duration_s': args.duration,
                           'workers': args.workers,
                           'batch_size': batch_size(len(runs), args.workers)}

    rates: dict[str, list[float]] = {'serial': [], 'dask_1': [], 'dask_n': []}
    expected: list[RunResult] = []
    for _ in range(args.repeat):      # interleaved, so a change of load hits all three
        serial_s, expected = serial(runs)
        rates['serial'].append(len(runs) / serial_s)
        for name, workers in (('dask_1', 1), ('dask_n', args.workers)):
            startup, wall, results = on_dask(runs, workers)
            _check_same(name, results, expected)
            out[f'{name}_startup_s'] = startup
            rates[name].append(len(runs) / wall)
            if name == 'dask_n':
                busy = sum(r.seconds for r in results)
                overhead = 1e3 * (wall * workers - busy) / len(runs)
                out['overhead_per_run_ms'] = min(out.get('overhead_per_run_ms', overhead),
                                                 overhead)
    for name, values in rates.items():       # the best of the repeats: the least disturbed
        out[f'{name}_runs_per_s'] = max(values)
        out[f'{name}_all_runs_per_s'] = values
    for name in ('dask_1', 'dask_n'):
        out[f'{name}_vs_serial'] = out[f'{name}_runs_per_s'] / out['serial_runs_per_s']

    tiny = tasks(max(1, args.tiny_runs // 2), 0.05)[:args.tiny_runs]
    tiny_serial, tiny_expected = serial(tiny)
    _, tiny_wall, tiny_results = on_dask(tiny, 1, size=1)
    _check_same('tiny runs', tiny_results, tiny_expected)
    out['tiny_runs'] = len(tiny)
    out['task_overhead_ms'] = 1e3 * (tiny_wall - tiny_serial) / len(tiny)
    out['load_before'] = list(load_before)
    out['load_after'] = list(os.getloadavg())

    print(f'{len(runs)} runs of {args.duration:g} s (station_keeping, pd and pid), '
          f'batches of {out["batch_size"]}; load average {load_before[0]:.2f} before, '
          f'{out["load_after"][0]:.2f} after ({os.cpu_count()} cores)')
    every = ' '.join(f'{v:.2f}' for v in rates['serial'])
    print(f'  serial loop      {out["serial_runs_per_s"]:7.2f} runs/s  (rounds: {every})')
    for name, label in (('dask_1', 'dask, 1 worker'), ('dask_n', f'dask, {args.workers} workers')):
        every = ' '.join(f'{v:.2f}' for v in rates[name])
        print(f'  {label:16s} {out[f"{name}_runs_per_s"]:7.2f} runs/s  '
              f'{out[f"{name}_vs_serial"]:5.2f}x serial  '
              f'(cluster start {out[f"{name}_startup_s"]:.1f} s; rounds: {every})')
    print(f'  overhead per run, {args.workers} workers: {out["overhead_per_run_ms"]:.1f} ms '
          '(wall x workers - run time, / runs)')
    print(f'  overhead per task ({len(tiny)} one-tick runs, one per task, 1 worker): '
          f'{out["task_overhead_ms"]:.2f} ms')
    return out


if __name__ == '__main__':
    main()
