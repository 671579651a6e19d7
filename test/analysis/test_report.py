"""``tiltrov report``: the results section, its markers, and the committed results page."""

from __future__ import annotations

import json
from pathlib import Path
import re

import pytest

from tiltrov_ros.analysis.report import BEGIN, END, RUNS, caption, fmt, update_readme
from tiltrov_ros.analysis.runs import InputError
from tiltrov_ros.cli import main
from tiltrov_ros.core.controllers import load_controller_config

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(('value', 'text'), [
    (None, 'n/a'), (float('nan'), 'n/a'), (0.0, '0'), (4.9e-4, '0'), (-0.0123, '-0.012'),
    (0.5, '0.500'), (29.661, '29.66'), (143.2, '143'), (1350.4, '1350')])
def test_fmt(value: float | None, text: str) -> None:
    assert fmt(value) == text


def test_update_readme_replaces_between_the_markers_or_appends() -> None:
    section = f'{BEGIN}\nnew table\n{END}'
    text = f'# Title\n\nintro\n\n{BEGIN}\nold table\n{END}\n\n## After\n'
    updated = update_readme(text, section)
    assert updated == f'# Title\n\nintro\n\n{section}\n\n## After\n'
    assert update_readme(updated, section) == updated
    appended = update_readme('# Title\n', section)
    assert appended == f'# Title\n\n## Results\n\n{section}\n'
    with pytest.raises(InputError, match='only one of the markers'):
        update_readme(f'# Title\n{BEGIN}\n', section)


def test_captions_name_the_papers_figures() -> None:
    assert caption('pitch_hold_errors').startswith('pitch_hold: errors')
    assert "Fig. 5" in caption('pitch_hold_errors')
    assert caption('pitch_hold_slow_servo_tilts').startswith('pitch_hold_slow_servo: tilt')
    assert "Fig. 7" in caption('trajectory_tracking')


def test_report_command_writes_figures_results_and_the_section(tmp_path: Path) -> None:
    readme = tmp_path / 'README.md'
    readme.write_text(f'# Robot\n\n## Results\n\n{BEGIN}\n{END}\n\n## Licence\n')
    code = main(['report', '--readme', str(readme), '--duration', '0.5', '--dpi', '20'])
    assert code == 0
    text = readme.read_text()
    assert text.startswith('# Robot\n') and text.endswith('\n## Licence\n')
    assert 'Shortened to 0.5 s per run' in text
    assert str(tmp_path) not in text                       # relative paths only
    images = re.findall(r'!\[[^\]]*\]\(([^)]+)\)', text)
    assert images and all(path.startswith('docs/figures/') for path in images)
    assert all((tmp_path / path).is_file() for path in images)
    results = json.loads((tmp_path / 'docs' / 'figures' / 'results.json').read_text())
    assert sorted(results) == sorted(f'{s}/{k}' for s, kinds in RUNS for k in kinds)
    assert all(m['duration'] == 0.5 for m in results.values())
    rows = [line for line in text.splitlines() if line.startswith('| pitch_hold | pid |')]
    assert len(rows) == 2                                  # errors and behaviour tables


def test_report_without_a_readme_file_fails_cleanly(tmp_path: Path, capsys) -> None:
    assert main(['report', '--readme', str(tmp_path / 'nope.md')]) == 2
    assert capsys.readouterr().err.startswith('tiltrov report: error: no README')


def test_committed_results_page_is_up_to_date_with_the_gains_and_figures() -> None:
    # `make figures` regenerates the section; this catches a gain changed without it.
    text = (REPO / 'docs' / 'results.md').read_text()
    section = text[text.index(BEGIN):text.index(END)]
    assert 'Shortened' not in section
    gains = load_controller_config().gains
    for name in ('kp', 'kd', 'ki', 'integral_limit'):
        row = next(line for line in section.splitlines() if line.startswith(f'| `{name}` |'))
        cells = [c.strip() for c in row.split('|')[2:8]]
        assert [float(c) for c in cells] == list(getattr(gains, name)), name
    images = re.findall(r'!\[[^\]]*\]\(([^)]+)\)', section)
    assert len(images) >= 8
    for path in images:
        assert (REPO / 'docs' / path).is_file(), path
