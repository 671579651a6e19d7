"""Running a campaign's tasks on Dask (``dask.distributed``).

* By default a :class:`~distributed.LocalCluster`: worker processes, one per
  core (``--workers``), one thread each, BLAS libraries pinned to one thread
  (``OMP_NUM_THREADS``, ``OPENBLAS_NUM_THREADS``, ``MKL_NUM_THREADS`` set
  before the workers start), listening on 127.0.0.1 only, no dashboard.
* With ``scheduler='tcp://HOST:8786'``, the Dask cluster running there
  (``dask scheduler`` and ``dask worker`` processes, or dask-jobqueue); its
  workers need this package installed (checked before anything is sent).

Tasks are batches of runs (:func:`tiltrov_ros.campaign.worker.run_batch`), so
the scheduler's cost per task is shared by several runs; each batch returns
its runs' metrics, not their RunLogs. Results are handed to ``on_results`` as
batches finish, in whatever order they finish; a batch lost with its worker
(Dask retries it first, then gives up) comes back as failed runs with the
reason.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
import logging
import math
import os
import signal
import threading
from typing import Any

import dask
from distributed import Client, LocalCluster, as_completed

from tiltrov_ros.campaign.plan import RunTask
from tiltrov_ros.campaign.worker import RunResult, run_batch, worker_environment
from tiltrov_ros.core.campaign import verdict
from tiltrov_ros.core.errors import CampaignError

#: Environment of local worker processes: numpy's BLAS single-threaded, so one
#: process per core does not oversubscribe the cores.
PINNED_THREADS = {'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1', 'MKL_NUM_THREADS': '1'}
#: At most this many runs per task (a 60 s run takes one to a few seconds).
MAX_BATCH = 8
#: Seconds to wait for an external scheduler and for its first worker.
CONNECT_TIMEOUT = 30.0


def batch_size(runs: int, workers: int) -> int:
    """Runs per task: about four tasks per worker, so the last ones finish together,
    and at most :data:`MAX_BATCH`, so results stream in."""
    return max(1, min(MAX_BATCH, math.ceil(runs / (4 * max(1, workers)))))


def batches(tasks: Sequence[RunTask], size: int) -> list[list[RunTask]]:
    return [list(tasks[i:i + size]) for i in range(0, len(tasks), size)]


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A connected ``distributed.Client``: to ``scheduler``, or to a LocalCluster of
    ``workers`` processes (default: one per core). Closed on exit."""

    cluster = None
    if scheduler:
        try:
            client = Client(scheduler, timeout=f'{CONNECT_TIMEOUT}s')
        except (OSError, TimeoutError) as exc:
            raise CampaignError(f'cannot reach the Dask scheduler at {scheduler}: '
                                f'{" ".join(str(exc).split())}') from exc
    else:
        count = workers or os.cpu_count() or 1
        environ = {**dask.config.get('distributed.nanny.pre-spawn-environ', {}),
                   **PINNED_THREADS}
        with dask.config.set({'distributed.nanny.pre-spawn-environ': environ}), \
                _workers_ignore_ctrl_c():
            # On this machine only; no dashboard, its HTTP routes on a free port. The
            # workers and the scheduler log only what is critical: after Ctrl-C a worker's
            # heartbeat can meet the scheduler already closed and log that as an error
            # with its traceback (seen in a loaded full test run), and a run that fails
            # comes back as a result anyway (the table's status and error columns).
            cluster = LocalCluster(n_workers=count, threads_per_worker=1, processes=True,
                                   host='127.0.0.1', dashboard_address=None,
                                   scheduler_kwargs={'dashboard_address': '127.0.0.1:0'},
                                   silence_logs=logging.CRITICAL)
        client = Client(cluster)
    # After Ctrl-C, distributed's own callbacks on the client's event loop can fail
    # (a NameError inside distributed.utils.cancel, seen once in about twenty
    # interrupted campaigns), and tornado logs each with its traceback: nothing a user
    # can act on, so tornado's callback log is quiet while the client runs. Runs that
    # fail come back as results (the table's status and error columns).
    tornado_log = logging.getLogger('tornado.application')
    level = tornado_log.level
    tornado_log.setLevel(logging.CRITICAL)
    try:
        if scheduler:
            _check_workers(client, scheduler)
        yield client
    finally:
        try:
            client.close()
            if cluster is not None:
                cluster.close()
        finally:
            tornado_log.setLevel(level)


@contextmanager
def _workers_ignore_ctrl_c() -> Iterator[None]:
    """Worker processes started inside ignore SIGINT (an ignored signal stays ignored in
    a child): Ctrl-C reaches the whole process group, and the client alone stops the
    campaign and then the cluster, without a traceback from every worker."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _check_workers(client: Any, scheduler: str) -> None:
    from tiltrov_ros import __version__
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT)
    except TimeoutError as exc:
        raise CampaignError(f'the Dask scheduler at {scheduler} has no worker after '
                            f'{CONNECT_TIMEOUT:g} s (start some with: dask worker '
                            f'{scheduler} --nthreads 1)') from exc
    try:
        found = client.run(worker_environment)
    except Exception as exc:
        raise CampaignError(f'the workers of {scheduler} cannot run tiltrov_ros (install '
                            f'the package on each): {type(exc).__name__}: '
                            f'{" ".join(str(exc).split())}') from exc
    other = sorted({env['tiltrov_ros'] for env in found.values()} - {__version__})
    if other:
        raise CampaignError(f'the workers of {scheduler} have tiltrov_ros {other[0]}, this '
                            f'machine {__version__}: install the same version on both')


def worker_count(client: Any) -> int:
    """Threads the cluster has now (one per run in parallel)."""
    return max(1, sum(client.nthreads().values()))


def execute(client: Any, tasks: Sequence[RunTask],
            on_results: Callable[[list[RunResult]], None], *,
            size: int | None = None) -> None:
    """Run ``tasks`` on ``client``'s cluster in batches, calling ``on_results`` with each
    batch's results as it finishes. On an exception (Ctrl-C) the pending batches are
    cancelled and the exception goes on."""
    size = size or batch_size(len(tasks), worker_count(client))
    pending = {}
    for batch in batches(tasks, size):
        future = client.submit(run_batch, batch, pure=False)
        pending[future] = batch
    try:
        for future in as_completed(list(pending)):
            batch = pending.pop(future)
            try:
                results = future.result()
            except Exception as exc:    # the batch was lost (its worker died, ...)
                reason = f'batch lost: {type(exc).__name__}: {" ".join(str(exc).split())}'
                results = [RunResult(t.run_id, None, reason[:500], 0.0, '',
                                     verdict=verdict(False, None, None)) for t in batch]
            future.release()
            on_results(results)
    finally:
        if pending:
            client.cancel(list(pending))
