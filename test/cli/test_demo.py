"""``tiltrov demo``: the README's first command, shortened (2 s of sim time)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader

from tiltrov_ros import cli
from tiltrov_ros.bag.losses import final_diagnostics, message_counts
from tiltrov_ros.cli.demo import summary_table


@pytest.mark.slow
def test_demo_records_analyzes_and_checks_against_the_headless_runner(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'demo'
    code = cli.main(['demo', '--out', str(out), '--controllers', 'pd,switching',
                     '--duration', '2'])
    stdout = capsys.readouterr().out
    assert code == 0, stdout
    assert 'every bag gives the metrics of the headless runner' in stdout
    for controller in ('pd', 'switching'):
        bag = out / 'bags' / controller
        with Reader(bag) as reader:
            counts = {c.topic: c.msgcount for c in reader.connections}
        # One per step and tick, plus the state a stall published again (a loaded
        # machine) and the answers to it: the bag has what the nodes published.
        again = int(final_diagnostics(bag)[0]['/plant_simulator']['republished_states'])
        assert 201 <= counts['/odom'] <= 201 + again, (counts, again)
        assert 40 <= counts['/wrench_cmd'] <= 40 + again, (counts, again)
        assert all(c['recorded'] == c['published']
                   for c in message_counts(bag, final_diagnostics(bag)[0]).values())
        run_metrics = json.loads((out / 'analysis' / controller / 'metrics.json').read_text())
        assert run_metrics['run']['controller'] == controller
        assert run_metrics['ticks'] == 40
        assert (out / 'logs' / f'{controller}.log').stat().st_size > 0
    index = json.loads((out / 'analysis' / 'metrics.json').read_text())
    assert list(index) == ['pd', 'switching']
    for figure in ('errors', 'tilts', 'tracking', 'overlay', 'wrench_pd', 'wrench_switching'):
        assert (out / 'analysis' / f'{figure}.png').stat().st_size > 10_000, figure
    summary = (out / 'summary.md').read_text()
    assert '| pd |' in summary and '| switching |' in summary


def test_demo_rejects_an_unknown_controller(tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(['demo', '--out', str(tmp_path), '--controllers', 'pd,lqr']) == 2
    assert "unknown controller 'lqr'" in capsys.readouterr().err
    assert not (tmp_path / 'bags').exists()


def test_summary_table_rows_in_mm_and_deg() -> None:
    dofs = ('x', 'y', 'z', 'roll', 'pitch', 'yaw')
    metrics = {'run_a': {'final_error': dict.fromkeys(dofs, 0.0) | {'z': 0.0297},
                         'rms_error': dict.fromkeys(dofs, 0.0) | {'pitch': 0.0349},
                         'servo_travel': {'front': 3.14159, 'rear': None},
                         'thrust_saturation_fraction': 0.125}}
    table = summary_table(metrics).splitlines()
    assert len(table) == 3
    assert table[2] == ('| run_a | 0.0 / 0.0 / 29.7 | 0.00 / 0.00 / 0.00 | 0.0 / 0.0 | 2.00 | '
                        '180.00 / - | 12.5 % |')
