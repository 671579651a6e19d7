"""bench/bench_transforms.py keeps working (its numbers are reported, never asserted)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
import sys

import pytest
from ros_stack import require_tf2_msgs

BENCH = Path(__file__).resolve().parents[2] / 'bench' / 'bench_transforms.py'


def test_bench_transforms_main_returns_its_numbers(capsys: pytest.CaptureFixture[str],
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    require_tf2_msgs()
    spec = importlib.util.spec_from_file_location('bench_transforms', BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, 'bench_transforms', module)
    spec.loader.exec_module(module)
    results = module.main(['--steps', '50', '--repeats', '1'])
    assert set(results) == {'state_us_without_tf', 'state_us_with_tf', 'tf_us_template',
                            'tf_us_objects', 'state_with_tf_over_without',
                            'tf_objects_over_template'}
    assert all(math.isfinite(value) and value > 0.0 for value in results.values())
    out = capsys.readouterr().out
    for key, value in results.items():      # every number is in the printed table
        assert key in out and f'{value:12.3f}' in out, key
