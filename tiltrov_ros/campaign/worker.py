"""What a worker does with a batch of runs: run each headless, return its metrics.

A run that raises is a result too (its ``error``), never a lost batch; the
RunLog stays on the worker, only ``metrics.json`` comes back. No Dask here:
the serial baseline of the benchmark calls the same :func:`run_batch`.
"""

from __future__ import annotations

from collections.abc import Sequence
import os
import socket
import time
from typing import Any, NamedTuple

from tiltrov_ros.campaign.plan import RunTask
from tiltrov_ros.core.metrics import compute_metrics
from tiltrov_ros.core.runner import run_scenario


class RunResult(NamedTuple):
    """One run's outcome: metrics (None if it raised), the error's one line, the wall
    time it took on its worker (s) and the worker (host:pid)."""

    run_id: str
    metrics: dict[str, Any] | None
    error: str
    seconds: float
    worker: str


def run_one(task: RunTask) -> RunResult:
    """Run one task; any exception becomes the result's ``error``."""
    start = time.perf_counter()
    metrics: dict[str, Any] | None = None
    error = ''
    try:
        metrics = compute_metrics(run_scenario(task.config))
    except Exception as exc:    # a run that fails is recorded, the campaign goes on
        error = f'{type(exc).__name__}: {" ".join(str(exc).split())}'[:500]
    return RunResult(task.run_id, metrics, error, time.perf_counter() - start, worker_name())


def run_batch(tasks: Sequence[RunTask]) -> list[RunResult]:
    """The task of a Dask worker: each run of the batch in turn."""
    return [run_one(task) for task in tasks]


def worker_name() -> str:
    return f'{socket.gethostname()}:{os.getpid()}'


def worker_environment() -> dict[str, str]:
    """What a worker runs with: the package version and the BLAS thread settings."""
    from tiltrov_ros import __version__
    keys = ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')
    return {'tiltrov_ros': __version__, **{k: os.environ.get(k, '') for k in keys}}
