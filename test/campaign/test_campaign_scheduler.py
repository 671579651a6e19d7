"""The same campaign on an external Dask cluster (``dask scheduler`` and two ``dask worker``
processes on this machine, random ports) gives the same table as on the local cluster."""

from __future__ import annotations

from collections.abc import Callable, Iterator
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
from typing import NamedTuple

from campaign_run import CampaignRun, comparable, read_rows, tiltrov_campaign
from distributed import Client
from harness import HANG_BOUND, TreeProgress, progressing_until
import pytest

from tiltrov_ros.campaign import execute
from tiltrov_ros.cli import main

#: A cluster and campaigns in processes: waits that give up on a hang, not on a slow machine.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(HANG_BOUND)]
DASK = str(Path(sys.executable).parent / 'dask')


def _stop(processes: list[subprocess.Popen[bytes]]) -> None:
    for proc in reversed(processes):
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
    for proc in processes:
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)


def _wait(done: Callable[[], bool], processes: list[subprocess.Popen[bytes]],
          log: Path, idle: float = 120.0) -> None:
    """Until ``done()``, however slowly a loaded machine starts ``processes``: failing
    when one of them has ended, or none has used CPU for ``idle`` s (a hang)."""
    progressing_until(lambda: done() or any(p.poll() is not None for p in processes),
                      TreeProgress(*(p.pid for p in processes)), idle)
    assert done(), log.read_text()       # none ended, not hung


class Cluster(NamedTuple):
    address: str
    worker_pids: set[int]


@pytest.fixture
def scheduler(tmp_path: Path) -> Iterator[Cluster]:
    """A scheduler and two single-threaded workers on 127.0.0.1, both connected."""
    info = tmp_path / 'scheduler.json'
    env = {**os.environ, 'OMP_NUM_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1'}
    logs = tmp_path / 'logs'
    logs.mkdir()
    processes: list[subprocess.Popen[bytes]] = []

    def start(name: str, *args: str) -> None:
        with (logs / f'{name}.log').open('wb') as log:
            processes.append(subprocess.Popen([DASK, *args], stdout=log, stderr=log, env=env))

    try:
        start('scheduler', 'scheduler', '--host', '127.0.0.1', '--port', '0',
              '--no-dashboard', '--dashboard-address', '127.0.0.1:0',
              '--scheduler-file', str(info))
        _wait(lambda: info.is_file() and bool(info.read_text().strip()), processes,
              logs / 'scheduler.log')
        address = json.loads(info.read_text())['address']
        for k in (1, 2):
            start(f'worker{k}', 'worker', address, '--nthreads', '1', '--host', '127.0.0.1',
                  '--no-dashboard', '--dashboard-address', '127.0.0.1:0')
        with Client(address, timeout='60s') as client:
            _wait(lambda: len(client.scheduler_info()['workers']) >= 2, processes,
                  logs / 'worker1.log')
            pids = set(client.run(os.getpid).values())
        yield Cluster(address, pids)
    finally:
        _stop(processes)


def test_an_external_scheduler_gives_the_same_table(local_run: CampaignRun, tiny_file: Path,
                                                    scheduler: Cluster, tmp_path: Path) -> None:
    external = tiltrov_campaign(tiny_file, '--out', tmp_path / 'out', '--scheduler',
                                scheduler.address)
    assert external.returncode == 0, external.stdout + external.stderr
    assert f'on {scheduler.address} (2 workers)' in external.stdout
    rows = read_rows(external.out / 'runs.csv')
    assert comparable(rows) == comparable(read_rows(local_run.out / 'runs.csv'))
    # every run ran in a process of the external cluster
    assert {int(r['worker'].rpartition(':')[2]) for r in rows} <= scheduler.worker_pids
    assert (external.out / 'summary.json').read_text() == \
        (local_run.out / 'summary.json').read_text()


def test_an_unreachable_scheduler_is_one_line(tiny_file: Path, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(execute, 'CONNECT_TIMEOUT', 1.0)
    code = main(['campaign', str(tiny_file), '--out', str(tmp_path / 'out'),
                 '--scheduler', 'tcp://127.0.0.1:9'])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith('tiltrov campaign: error: cannot reach the Dask scheduler at '
                          'tcp://127.0.0.1:9') and err.count('\n') == 1, err
