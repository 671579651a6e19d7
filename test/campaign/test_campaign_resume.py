"""Interrupting a campaign and ``--resume``: nothing finished is lost, nothing is run twice;
a table torn by a kill mid-write, and a campaign file changed in between."""

from __future__ import annotations

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys

from campaign_run import IDS, TINY, CampaignRun, comparable, read_rows, tiltrov_campaign
from harness import HANG_BOUND, TreeProgress, progressing_until
import pytest
import yaml

#: Whole campaigns in processes: waits that give up on a hang, not on a slow machine.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(HANG_BOUND)]


def test_an_interrupted_campaign_resumes_without_losing_or_repeating_a_run(
        local_run: CampaignRun, tiny_file: Path, tmp_path: Path) -> None:
    out = tmp_path / 'out'
    table = out / 'runs.csv'
    args = [str(tiny_file), '--out', str(out), '--samples', '30', '--batch-size', '1',
            '--workers', '2']
    # Its own session: Ctrl-C reaches the command and its workers, nothing else.
    proc = subprocess.Popen([sys.executable, '-m', 'tiltrov_ros.cli', 'campaign', *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        def rows_written() -> bool:
            return table.is_file() and len(table.read_text().splitlines()) >= 4

        progressing_until(lambda: rows_written() or proc.poll() is not None,
                          TreeProgress(proc.pid))
        assert rows_written(), proc.communicate()       # not ended, not hung
        os.killpg(proc.pid, signal.SIGINT)
        stdout, stderr = proc.communicate()     # to its end; a hang is HANG_BOUND's
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, stdout + stderr
    before = table.read_text()
    done = read_rows(table)
    assert 3 <= len(done) < 60
    assert f'interrupted; {len(done)} of 60 runs are in {table}' in stderr
    assert 'Traceback' not in stderr

    resumed = tiltrov_campaign(*args, '--resume')
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert f'60 runs; {len(done)} already in {table}' in resumed.stdout
    text = table.read_text()
    assert text.startswith(before)                       # nothing recorded was touched
    rows = read_rows(table)
    ids = [r['run_id'] for r in rows]
    assert len(ids) == len(set(ids)) == 60              # none lost, none twice
    assert {f's{i:05d}-{c}-robust' for i in range(30) for c in ('pd', 'pid')} == set(ids)
    # the samples of the tiny campaign's own run give the same rows
    first = [r for r in rows if r['run_id'] in IDS]
    assert comparable(first) == comparable(read_rows(local_run.out / 'runs.csv'))


def _copy(run: CampaignRun, to: Path) -> Path:
    shutil.copytree(run.out, to)
    return to / 'runs.csv'


def test_a_row_torn_by_a_kill_is_cut_and_its_run_done_again(
        local_run: CampaignRun, tiny_file: Path, tmp_path: Path) -> None:
    table = _copy(local_run, tmp_path / 'out')
    text = table.read_text()
    lines = text.splitlines(keepends=True)
    torn = lines[-1].split(',')[0]
    table.write_text(''.join(lines[:-1]) + lines[-1][:len(lines[-1]) // 2])
    resumed = tiltrov_campaign(tiny_file, '--out', tmp_path / 'out', '--resume')
    assert resumed.returncode == 0, resumed.stderr
    assert '8 runs; 7 already in' in resumed.stdout
    rows = read_rows(table)
    assert [r['run_id'] for r in rows].count(torn) == 1
    assert comparable(rows) == comparable(read_rows(local_run.out / 'runs.csv'))


def test_resume_refuses_a_changed_campaign_and_a_plain_run_an_existing_table(
        local_run: CampaignRun, tiny_file: Path, tmp_path: Path) -> None:
    table = _copy(local_run, tmp_path / 'out')
    before = table.read_text()
    again = tiltrov_campaign(tiny_file, '--out', tmp_path / 'out')
    assert again.returncode == 2
    assert again.stderr == (f'tiltrov campaign: error: {table} already holds runs: --resume '
                            'to continue that campaign, or choose another --out\n')
    changed = tmp_path / 'changed.yaml'
    changed.write_text(yaml.safe_dump({**TINY, 'seed': 4}))
    other = tiltrov_campaign(changed, '--out', tmp_path / 'out', '--resume')
    assert other.returncode == 2 and 'made from another campaign file' in other.stderr
    assert other.stderr.count('\n') == 1
    more = tiltrov_campaign(tiny_file, '--out', tmp_path / 'out', '--resume', '--samples', '4')
    assert more.returncode == 0 and '8 runs; 8 already in' in more.stdout
    assert table.read_text() == before
