"""``tiltrov campaign`` on the default local Dask cluster: the table, failures, the hold
column, the summary, and runs reproduced by ``tiltrov sim`` from their files."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
import sys

from campaign_run import IDS, TINY, CampaignRun, read_rows, tiltrov_campaign
from harness import HANG_BOUND, run_while_progressing
import pytest
import yaml

from tiltrov_ros.campaign.execute import PINNED_THREADS, dask_client
from tiltrov_ros.campaign.plan import Plan
from tiltrov_ros.campaign.table import metric_columns, row_metrics
from tiltrov_ros.campaign.worker import run_one, worker_environment
from tiltrov_ros.core.campaign import draw_sample, draw_samples, load_campaign
from tiltrov_ros.core.metrics import metric_differences
from tiltrov_ros.core.names import DOF_NAMES
from tiltrov_ros.core.yamlfile import flatten

#: Whole campaigns in processes: waits that give up on a hang, not on a slow machine.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(HANG_BOUND)]


def test_every_run_is_one_row_with_its_parameters_and_metrics(local_run: CampaignRun,
                                                             tiny_file: Path) -> None:
    rows = read_rows(local_run.out / 'runs.csv')
    assert sorted(r['run_id'] for r in rows) == sorted(IDS)
    spec = load_campaign(tiny_file)
    header = list(rows[0])
    assert header[-len(metric_columns()):] == metric_columns()
    for row in rows:
        sample = draw_sample(spec, int(row['sample']))
        for key, value in sample.params.items():
            assert row[f'param.{key}'] == (value if isinstance(value, str) else repr(value))
        assert row['controller'] + '-robust' == row['configuration'] == row['run_id'][7:]
        if row['status'] == 'ok':
            assert row['run.scenario'] == sample.name
            assert row['run.controller'] == row['controller']
            assert int(row['ticks']) == 40 and float(row['duration']) == 2.0
        assert row['worker'] and float(row['seconds']) > 0


def test_a_run_that_raises_is_a_recorded_failure(local_run: CampaignRun) -> None:
    rows = read_rows(local_run.out / 'runs.csv')
    pulsed = {r['run_id'] for r in rows
              if r['param.disturbances.external_wrench[0].occurs'] == '1.0'}
    assert 0 < len(pulsed) < len(rows)          # the seed gives both kinds
    for row in rows:
        if row['run_id'] in pulsed:             # 1e200 N: the simulation diverges
            assert row['status'] == 'failed' and row['holds'] == '0'
            assert row['error'].startswith('ValueError: ') and row['final_error.x'] == ''
        else:
            assert row['status'] == 'ok' and row['error'] == ''
            assert row['final_error.x'] != ''


def test_the_hold_column_follows_the_bounds_of_the_file(local_run: CampaignRun) -> None:
    seen = set()
    for row in read_rows(local_run.out / 'runs.csv'):
        if row['status'] != 'ok':
            continue
        final = [float(row[f'final_error.{d}']) for d in DOF_NAMES[:3]]
        peak = [float(row[f'max_error.{d}']) for d in DOF_NAMES[3:]]
        holds = max(final) <= 0.1 and max(peak) <= math.radians(30.0)
        assert row['holds'] == str(int(holds)), row['violations']
        assert (row['violations'] == '') == holds
        seen.add(holds)
    assert seen == {True, False}                 # the tiny campaign has both


def test_the_summary_counts_the_table(local_run: CampaignRun) -> None:
    rows = read_rows(local_run.out / 'runs.csv')
    summary = json.loads((local_run.out / 'summary.json').read_text())
    assert summary['runs'] == 8 and summary['samples'] == 4 and summary['seed'] == TINY['seed']
    for config in summary['configurations']:
        mine = [r for r in rows if r['configuration'] == config['configuration']]
        holds = sum(r['holds'] == '1' for r in mine)
        assert (config['runs'], config['holds']) == (4, holds)
        assert config['failed'] == sum(r['status'] == 'failed' for r in mine)
        errors = [math.hypot(*(float(r[f'final_error.{d}']) for d in 'xyz'))
                  for r in mine if r['status'] == 'ok']
        assert config['position_mm']['max'] == pytest.approx(1e3 * max(errors))
        assert config['worst'][0] in {r['run_id'] for r in mine if r['status'] == 'failed'}
        verdicts = {v: sum(r['verdict'] == v for r in mine)
                    for v in ('servo_range', 'physics', 'control')}
        assert config['verdicts'] == verdicts and sum(verdicts.values()) == 4 - holds
        why = ', '.join(f'{n} {v.replace("_", " ")}' for v, n in verdicts.items())
        assert (f"hold rate {config['configuration']}: {100 * holds / 4:.0f} % ({holds} of 4 "
                f"runs, {config['failed']} failed; not held: {why})") in local_run.stdout
    markdown = (local_run.out / 'summary.md').read_text()
    assert '| pd-robust | 4 |' in markdown and 'final_error: x, y, z <= 100 mm' in markdown
    for name in ('cdf_final_position.png', 'error_vs_current.png'):
        assert (local_run.out / name).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
        assert f'({name})' in markdown
    assert (local_run.out / 'campaign.yaml').read_text().startswith('name: tiny')


def test_an_exported_run_gives_the_same_metrics_with_tiltrov_sim(
        local_run: CampaignRun, tiny_file: Path, tmp_path: Path) -> None:
    rows = {r['run_id']: r for r in read_rows(local_run.out / 'runs.csv')}
    run_id = next(i for i in sorted(rows) if rows[i]['status'] == 'ok'
                  and rows[i]['controller'] == 'pid')
    exported = tiltrov_campaign(tiny_file, '--out', tmp_path, '--export', run_id)
    assert exported.returncode == 0, exported.stderr
    folder = tmp_path / 'runs' / run_id
    for name in ('scenario.yaml', 'wrench_controller.yaml', 'thrust_allocator.yaml',
                 'reproduce.sh'):      # the same files as the summary's worst runs
        assert (folder / name).read_text() == (local_run.out / 'worst' / run_id / name).read_text()
    env = {**os.environ, 'PATH': f'{Path(sys.executable).parent}{os.pathsep}{os.environ["PATH"]}'}
    result = run_while_progressing([str(folder / 'reproduce.sh'), '--no-figures'],
                                   env=env)
    assert result.returncode == 0, result.stdout + result.stderr
    metrics = json.loads((folder / 'sim' / 'metrics.json').read_text())
    assert metric_differences(metrics, row_metrics(rows[run_id]), rtol=0.0, atol=0.0) == []
    assert flatten(metrics)['run.scenario'] == f'tiny-s{int(rows[run_id]["sample"]):05d}'


def test_local_workers_are_processes_with_one_thread_and_blas_pinned() -> None:
    with dask_client(workers=2) as client:
        assert sorted(client.nthreads().values()) == [1, 1]
        environments = client.run(worker_environment)
        pids = client.run(os.getpid)
    assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()
    for env in environments.values():
        assert {k: env[k] for k in PINNED_THREADS} == PINNED_THREADS


def test_a_gain_set_reaches_tiltrov_sim_through_the_exported_files(tmp_path: Path) -> None:
    file = tmp_path / 'gains.yaml'
    soft = {'kp': [30.0, 40.0, 50.0, 10.0, 20.0, 20.0], 'kd': [60.0, 80.0, 100.0, 8.0, 16.0, 16.0]}
    file.write_text(yaml.safe_dump({**TINY, 'disturbances': {}, 'compare': {
        'controllers': ['pd'], 'allocators': ['paper'], 'gains': {'shipped': {}, 'soft': soft}}}))
    spec = load_campaign(file)
    task = next(t for t in Plan(spec).tasks(draw_samples(spec, 1))
                if t.configuration == 'pd-paper-soft')
    assert task.config.controller.gains.kp == tuple(soft['kp'])
    assert task.config.allocator.mode == 'paper'
    expected = run_one(task).metrics
    exported = tiltrov_campaign(file, '--out', tmp_path / 'out', '--export', task.run_id)
    assert exported.returncode == 0, exported.stderr
    folder = tmp_path / 'out' / 'runs' / task.run_id
    env = {**os.environ, 'PATH': f'{Path(sys.executable).parent}{os.pathsep}{os.environ["PATH"]}'}
    result = run_while_progressing([str(folder / 'reproduce.sh'), '--no-figures'],
                                   env=env)
    assert result.returncode == 0, result.stderr
    metrics = json.loads((folder / 'sim' / 'metrics.json').read_text())
    assert metric_differences(metrics, expected, rtol=0.0, atol=0.0) == []
    shipped = next(t for t in Plan(spec).tasks(draw_samples(spec, 1))
                   if t.configuration == 'pd-paper-shipped')
    assert run_one(shipped).metrics != expected          # the gains make a difference
