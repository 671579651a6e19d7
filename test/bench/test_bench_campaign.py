"""bench/bench_campaign.py keeps working (its numbers are reported, never asserted)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
import sys

import pytest

BENCH = Path(__file__).resolve().parents[2] / 'bench' / 'bench_campaign.py'


@pytest.mark.slow
def test_bench_campaign_main_returns_its_numbers(capsys: pytest.CaptureFixture[str],
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    spec = importlib.util.spec_from_file_location('bench_campaign', BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, 'bench_campaign', module)
    spec.loader.exec_module(module)
    # It raises if the three ways of running give different metrics.
    results = module.main(['--samples', '2', '--duration', '0.5', '--workers', '2',
                           '--tiny-runs', '4', '--repeat', '1'])
    assert results['runs'] == 4 and results['tiny_runs'] == 4 and results['workers'] == 2
    for key in ('serial_runs_per_s', 'dask_1_runs_per_s', 'dask_n_runs_per_s',
                'dask_1_startup_s', 'dask_n_startup_s'):
        assert results[key] > 0.0, key
    assert len(results['load_before']) == 3 and len(results['dask_n_all_runs_per_s']) == 1
    assert 'dask, 2 workers' in capsys.readouterr().out
