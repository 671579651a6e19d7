"""``tiltrov campaign`` input errors: one line, exit code 2, nothing run or written."""

from __future__ import annotations

from pathlib import Path
import sys
from typing import Any

from campaign_run import TINY
import pytest
import yaml

from tiltrov_ros.cli import main


def _file(tmp_path: Path, **changes: Any) -> Path:
    path = tmp_path / 'camp.yaml'
    path.write_text(yaml.safe_dump({**TINY, **changes}))
    return path


@pytest.mark.parametrize(('changes', 'extra', 'message'), [
    ({'compare': {'controllers': ['pdd']}}, [],
     '{file}: compare.controllers[0]: got \'pdd\'; allowed: pd, switching, pid'),
    ({'compare': {'allocators': ['fast']}}, [],
     "{file}: compare.allocators: parameter 'mode' (in {file}): got 'fast'; allowed: "
     "robust or paper"),
    ({'robot': {'tilt_rate_limit': {'uniform': [-10, 100]}}}, ['--samples', '40'],
     "parameter 'robot.tilt_rate_limit' (in {file} (sample "),
    ({}, ['--samples', '0'], '--samples must be >= 1, got 0'),
    ({}, ['--worst', '-1'], '--worst must be >= 0, got -1'),
    ({}, ['--export', 's0001-pd'], "--export: 's0001-pd' is not a run of this campaign"),
    ({}, ['--export', 's00001-pd'], "--export: 's00001-pd' is not a run of this campaign"),
])
def test_bad_input_is_one_line_and_exit_code_2(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str],
                                              changes: dict[str, Any], extra: list[str],
                                              message: str) -> None:
    file = _file(tmp_path, **changes)
    out = tmp_path / 'out'
    code = main(['campaign', str(file), '--out', str(out), *extra])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith('tiltrov campaign: error: ' + message.format(file=file)), err
    assert err.count('\n') == 1
    assert not (out / 'runs.csv').exists()


def test_a_missing_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(['campaign', str(tmp_path / 'nope.yaml'), '--out', str(tmp_path / 'out')])
    assert code == 2
    assert capsys.readouterr().err == (f'tiltrov campaign: error: campaign file not found: '
                                       f'{tmp_path / "nope.yaml"}\n')


def test_without_dask_the_command_says_what_to_install(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, 'distributed', None)      # import distributed fails
    monkeypatch.delitem(sys.modules, 'tiltrov_ros.campaign.execute', raising=False)
    out = tmp_path / 'out'
    code = main(['campaign', str(_file(tmp_path)), '--out', str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1
    assert err.startswith('tiltrov campaign: error: Dask is missing') and 'pip install' in err
    assert not out.exists()
