"""bench/bench_analyze.py keeps working (its numbers are reported, never asserted)."""

from __future__ import annotations

import importlib.util
from pathlib import Path
import sys

import pytest

BENCH = Path(__file__).resolve().parents[2] / 'bench' / 'bench_analyze.py'


def test_bench_analyze_main_returns_its_numbers(capsys: pytest.CaptureFixture[str],
                                                monkeypatch: pytest.MonkeyPatch,
                                                tmp_path: Path) -> None:
    spec = importlib.util.spec_from_file_location('bench_analyze', BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, 'bench_analyze', module)
    spec.loader.exec_module(module)
    results = module.main(['--duration', '12', '--bag', str(tmp_path / 'bag'),
                           '--no-figures'])
    # 12 s: 1201 plant rows (odom, joint_states, /clock), 240 ticks (6 topics)
    assert results['messages'] == 3 * 1201 + 6 * 240
    assert results['read_messages'] == 2 * 1201 + 6 * 240
    for key in ('iterate_s', 'npz_s', 'deserialize_s', 'read_runlog_s', 'analyze_s'):
        assert results[key] > 0.0, key
    assert (tmp_path / 'bag' / 'metadata.yaml').is_file()      # kept for reuse
    assert 'tiltrov analyze --no-figures' in capsys.readouterr().out
    again = module.main(['--duration', '12', '--bag', str(tmp_path / 'bag'), '--no-figures',
                         '--no-deserialize'])
    assert 'write_bag_s' not in again and 'deserialize_s' not in again
