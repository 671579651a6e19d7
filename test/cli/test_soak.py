"""``tiltrov soak`` on a few seconds of sim time: the code path of ``make soak``."""

from __future__ import annotations

import json
from pathlib import Path
import sys

from harness import run_while_progressing
import pytest

from tiltrov_ros.cli import soak


@pytest.mark.slow
def test_short_soak_reports_memory_counts_and_stalls(tmp_path: Path) -> None:
    out = tmp_path / 'soak'
    result = run_while_progressing(
        [sys.executable, '-m', 'tiltrov_ros.cli', 'soak', '--duration', '2', '--out', str(out),
         '--warmup', '0', '--sample-period', '0.2'], cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads((out / 'soak.json').read_text())
    assert report['launch_exit_code'] == 0 and report['missing_stamps'] == {}
    assert report['sim_time_reached'] == 2.0
    # Stalls are reported (a loaded machine may make a tick wait that long), not a failure.
    assert report['stalls'] >= 0 and report['longest_stall_s'] >= 0.0
    assert set(report['rss']) == {'bag_recorder', 'plant_simulator', 'wrench_controller',
                                  'thrust_allocator', 'reference_publisher'}
    assert all(row['start_kib'] > 0 and row['end_kib'] > 0 for row in report['rss'].values())
    counts = report['messages']
    # One state per step, one answer per tick: the run started on the handshake.
    assert counts['/odom']['published'] == 201, counts['/odom']
    assert counts['/thrust_cmd']['published'] == 40, counts['/thrust_cmd']
    assert all(c['published'] == c['recorded'] for c in counts.values())
    assert report['lost'] == {}
    assert 'published' in result.stdout and 'RSS' in result.stdout


def test_rss_of_this_process_and_of_a_gone_one() -> None:
    import os
    assert soak.rss_kib(os.getpid()) > 0
    assert soak.rss_kib(2**22 + 12345) is None
