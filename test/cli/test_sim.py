"""``tiltrov sim``: outputs, the CSV, metrics.json, --compare, and one-line input errors."""

from __future__ import annotations

import json
import math
from pathlib import Path
import sys

from harness import run_while_progressing
import numpy as np
import pytest

from tiltrov_ros.cli import main
from tiltrov_ros.core import jit
from tiltrov_ros.core.metrics import compute_metrics
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.paths import config_file

INTERFACE_KEYS = {'rms_error', 'final_error', 'max_tilt_rate', 'thrust_saturation_fraction',
                  'wrench_error_rms'}


def test_one_run_writes_data_metrics_and_figures(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / 'out'
    code = main(['sim', '--scenario', 'pitch_hold', '--controller', 'pid', '--duration', '2',
                 '--out', str(out), '--dpi', '30'])
    assert code == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ['control.csv', 'errors.png', 'metrics.json', 'overlay.png', 'run.npz',
                     'tilts.png', 'tracking.png', 'wrench_pid.png']
    stdout = capsys.readouterr().out
    assert 'pitch_hold pid: final |e|' in stdout and str(out / 'metrics.json') in stdout
    metrics = json.loads((out / 'metrics.json').read_text())
    assert INTERFACE_KEYS <= set(metrics)
    assert metrics['run'] == {'scenario': 'pitch_hold', 'controller': 'pid',
                              'allocator_mode': 'robust', 'backend': jit.backend()}
    # The saved RunLog gives the same metrics (what tiltrov analyze will recompute).
    log = RunLog.load_npz(out / 'run.npz')
    assert log.t[-1] == 2.0 and len(log.tc) == 40
    assert json.loads(json.dumps(compute_metrics(log))) == metrics
    # The CSV: a header with units, one row per tick, the same errors.
    header = (out / 'control.csv').read_text().splitlines()[0].split(',')
    assert header[:2] == ['t [s]', 'x_d [m]'] and 'e_pitch [rad]' in header
    assert 'M_cmd [N m]' in header and header[-1] == 'tilt_rear [rad]'
    table = np.loadtxt(out / 'control.csv', delimiter=',', skiprows=1)
    assert table.shape == (40, len(header))
    np.testing.assert_allclose(table[:, 0], log.tc)
    e_x = table[:, header.index('e_x [m]')]
    assert np.sqrt(np.mean(e_x**2)) == pytest.approx(metrics['rms_error']['x'], rel=1e-8)
    np.testing.assert_allclose(table[:, header.index('thrust_3_cmd [N]')], log.thrust_cmd[:, 2],
                               rtol=1e-9, atol=1e-12)


def test_compare_overlays_several_controllers(tmp_path: Path) -> None:
    out = tmp_path / 'cmp'
    code = main(['sim', '--scenario', 'trajectory', '--compare', 'pd,switching',
                 '--allocator', 'paper', '--duration', '1', '--out', str(out), '--no-figures'])
    assert code == 0
    for kind in ('pd', 'switching'):
        metrics = json.loads((out / kind / 'metrics.json').read_text())
        assert metrics['run'] == {'scenario': 'trajectory', 'controller': kind,
                                  'allocator_mode': 'paper', 'backend': jit.backend()}
        assert (out / kind / 'run.npz').is_file() and (out / kind / 'control.csv').is_file()
    assert not list(out.glob('*.png'))


def test_a_robot_file_by_name_or_path(tmp_path: Path) -> None:
    """--robot robot_past_vertical: the servos' range reaches the run and the steady
    wrench's verdict; a path works as well."""
    for robot in ('robot_past_vertical', str(config_file('robot_past_vertical.yaml'))):
        out = tmp_path / Path(robot).stem
        code = main(['sim', '--scenario', 'current_hold', '--controller', 'pid', '--duration',
                     '1', '--robot', robot, '--out', str(out), '--no-figures'])
        assert code == 0
        meta = RunLog.load_npz(out / 'run.npz').meta
        assert (meta['tilt_min'], meta['tilt_max']) == pytest.approx((-math.pi, math.pi))
        metrics = json.loads((out / 'metrics.json').read_text())
        assert metrics['steady_shortfall_ratio'] < 1.0


@pytest.mark.parametrize(('args', 'message'), [
    (['--robot', 'no_such_robot'], "'no_such_robot'; allowed: a robot parameter file"),
    (['--scenario', 'nonesuch'], "no scenario named 'nonesuch'"),
    (['--scenario', '{bad}'], 'bad.yaml: not valid YAML'),
    (['--scenario', '{wrong}'], "wrong.yaml: reference.x[0]: unknown term type 'parabola'"),
    (['--duration', '-1'], '--duration must be > 0 s'),
    (['--duration', '0.005'], "parameter 'duration'"),
    (['--compare', 'pd,lqr'], "--compare: unknown controller 'lqr'"),
])
def test_bad_input_is_one_line_and_exit_code_2(tmp_path: Path, capsys, args: list[str],
                                               message: str) -> None:
    (tmp_path / 'bad.yaml').write_text('duration: [1, 2\n  reference: {\n')
    (tmp_path / 'wrong.yaml').write_text('duration: 5\nreference:\n  x:\n'
                                         '    - {type: parabola}\n')
    args = [a.format(bad=tmp_path / 'bad.yaml', wrong=tmp_path / 'wrong.yaml') for a in args]
    code = main(['sim', *args, '--out', str(tmp_path / 'out'), '--no-figures'])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith('tiltrov sim: error: ') and err.count('\n') == 1, err
    assert message in err
    assert not (tmp_path / 'out').exists()


def test_the_command_line_exit_code_and_no_traceback(tmp_path: Path) -> None:
    result = run_while_progressing([sys.executable, '-m', 'tiltrov_ros.cli', 'sim', '--scenario',
                             'nonesuch', '--out', str(tmp_path)])
    assert result.returncode == 2
    assert 'Traceback' not in result.stderr
    assert result.stderr.strip().startswith('tiltrov sim: error: no scenario named')
