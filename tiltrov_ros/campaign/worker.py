"""What a worker does with a batch of runs: run each headless, return its metrics.

A run that raises is a result too (its ``error``), never a lost batch; the
RunLog stays on the worker, only ``metrics.json`` comes back (its ``hold``
judged by the campaign's criterion), with the hold bounds it misses and its
verdict (:func:`tiltrov_ros.core.hold.verdict`, the same as ``hold.verdict``
where the run has a ``hold``): a run that does not hold is also run again
with servos turning all the way round (the task's ``counterfactual``, nothing
else changed), and whether that one holds is part of the result, as evidence
beside the verdict. No Dask here: the serial baseline of the benchmark calls
the same :func:`run_batch`.
"""

from __future__ import annotations

from collections.abc import Sequence
import os
import socket
import time
from typing import Any, NamedTuple

from tiltrov_ros.campaign.plan import RunTask
from tiltrov_ros.core.bounds import Bound, violations
from tiltrov_ros.core.hold import HoldCriterion, Reach, needs_reach, reach, verdict
from tiltrov_ros.core.metrics import compute_metrics, final_setpoint
from tiltrov_ros.core.runner import StackConfig, run_scenario


class RunResult(NamedTuple):
    """One run's outcome: metrics (None if it raised), the error's one line, the wall
    time it took on its worker (s, its counterfactual included) and the worker
    (host:pid); the hold bounds it misses, its verdict, and whether its counterfactual
    (servos at +-180 deg) held (None: not run) with the bounds that one missed."""

    run_id: str
    metrics: dict[str, Any] | None
    error: str
    seconds: float
    worker: str
    violations: tuple[str, ...] = ()
    verdict: str = ''
    counterfactual_holds: bool | None = None
    counterfactual_violations: tuple[str, ...] = ()


#: What the counterfactual run's metrics are judged by: nothing (its bounds are checked
#: apart), so that its hold costs nothing.
UNJUDGED = HoldCriterion('', ())


def _metrics(config: StackConfig, criterion: HoldCriterion, bounds: tuple[Bound, ...]
             ) -> tuple[dict[str, Any] | None, str, str]:
    """A run's metrics and verdict, or None, the exception's one line and the verdict of
    a run that raised."""
    try:
        log = run_scenario(config)
        metrics = compute_metrics(log, criterion=criterion, bounds=bounds)
    except Exception as exc:    # a run that fails is recorded, the campaign goes on
        return None, f'{type(exc).__name__}: {" ".join(str(exc).split())}'[:500], \
            verdict(False, None, None)
    hold = metrics['hold']
    if hold is not None:
        return metrics, '', str(hold['verdict'])
    # No hold (switching, a failed thruster, a moving setpoint): the same judgement.
    holds = not violations(bounds, metrics)
    quaternion = final_setpoint(log)
    answer = reach(log.meta, quaternion) if quaternion is not None and needs_reach(
        holds, metrics) else Reach()
    return metrics, '', verdict(holds, metrics, answer)


def run_one(task: RunTask) -> RunResult:
    """Run one task (and its counterfactual when it does not hold); any exception
    becomes the result's ``error``."""
    start = time.perf_counter()
    criterion = HoldCriterion(task.criterion, task.bounds)
    metrics, error, why = _metrics(task.config, criterion, task.bounds)
    missed = tuple(violations(task.bounds, metrics)) if metrics is not None else ()
    holds = metrics is not None and not missed
    again: bool | None = None
    missed_again: tuple[str, ...] = ()
    if not holds and task.counterfactual is not None:
        # Only whether it holds counts: its hold (and the wander oracle) is not asked for.
        other, other_error, _ = _metrics(task.counterfactual, UNJUDGED, ())
        missed_again = (tuple(violations(task.bounds, other)) if other is not None
                        else (other_error,))
        again = other is not None and not missed_again
    return RunResult(task.run_id, metrics, error, time.perf_counter() - start, worker_name(),
                     missed, why, again, missed_again)


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
