"""bench/bench_plant.py keeps working (its numbers are reported, never asserted)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
import sys

import pytest

BENCH = Path(__file__).resolve().parents[2] / 'bench' / 'bench_plant.py'


def test_bench_plant_main_returns_its_numbers(capsys: pytest.CaptureFixture[str],
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    spec = importlib.util.spec_from_file_location('bench_plant', BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, 'bench_plant', module)   # dataclasses look it up
    spec.loader.exec_module(module)
    results = module.main(['--steps', '200', '--repeats', '1', '--duration', '1.0'])
    # The headless run it times is the one asked for: 1 s, 10 ms steps, 50 ms ticks.
    assert results['run_plant_steps'] == 100.0
    assert results['run_control_ticks'] == 20.0
    assert all(math.isfinite(value) and value > 0.0 for value in results.values())
    out = capsys.readouterr().out
    for key, value in results.items():      # every number is in the printed table
        assert key in out and f'{value:12.3f}' in out, key
