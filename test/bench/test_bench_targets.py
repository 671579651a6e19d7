"""bench/bench_targets.py keeps working: its table and its fresh-process measures (the
numbers are reported, never asserted)."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
import sys
from typing import Any

import pytest

BENCH = Path(__file__).resolve().parents[2] / 'bench' / 'bench_targets.py'


@pytest.fixture(scope='module')
def targets() -> Any:
    spec = importlib.util.spec_from_file_location('bench_targets', BENCH)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules['bench_targets'] = module          # NamedTuple looks its module up
    spec.loader.exec_module(module)
    return module


def test_the_table_has_a_line_per_measured_row_with_speed_up_and_verdict(targets: Any) -> None:
    results = {'plant:default': {'step_us': 1.5}, 'plant:numpy': {'step_us': 15.0},
               'headless:default': {'current_hold_rtf': 100.0, 'pitch_hold_rtf': 400.0},
               'headless:numpy': {'current_hold_rtf': 10.0},
               'campaign:default': {'error': 'RuntimeError: no cluster'}}
    lines = targets.table(results)
    assert lines[0].startswith('| measure | target | compiled | numpy reference |')
    rows = {line.split(' | ')[0].lstrip('| '): line for line in lines[2:]}
    assert rows['plant step'] == '| plant step | <= 3 us | 1.5 us | 15 us | 10.0x | yes |'
    assert rows['headless loop RTF, current_hold (pid)'].endswith('| 100.0 | 10.0 | 10.0x | no |')
    assert rows['headless loop RTF, pitch_hold (pid)'].endswith('| 400.0 | - | - | yes |')
    assert 'failed: RuntimeError: no cluster' in rows['station-keeping campaign, 2 workers '
                                                     '(wall)']
    assert len(rows) == 4            # rows of measures not run are left out


@pytest.mark.slow
def test_main_measures_in_fresh_processes_with_both_backends(
        targets: Any, capsys: pytest.CaptureFixture[str]) -> None:
    results = targets.main(['--only', 'plant', 'pid', '--repeat', '1'])
    for measure, key in (('plant', 'step_us'), ('pid', 'update_us')):
        for backend in ('default', 'numpy'):
            value = results[f'{measure}:{backend}.{key}']
            assert math.isfinite(value) and value > 0.0
    assert results['describe']['backend'] in ('numba', 'numpy')
    out = capsys.readouterr().out
    assert '| plant step | <= 3 us |' in out and '| pid law | <= 20 us |' in out
