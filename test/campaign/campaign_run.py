"""The tiny campaign of the campaign tests and how they run ``tiltrov campaign``.

Four samples of two simulated seconds, pd and pid: eight runs. A wrench pulse
of 1e200 N present with probability 0.3 makes some runs diverge (the plant
raises on the NaN attitude): the failed runs the table must record.
"""

from __future__ import annotations

import csv
from pathlib import Path
import sys
from typing import NamedTuple

from harness import run_while_progressing

TINY = {
    'name': 'tiny', 'seed': 3, 'samples': 4, 'duration': 2.0, 'angle_unit': 'deg',
    'reference': {'x': [{'type': 'step', 'at': 0.0, 'value': {'uniform': [-0.2, 0.2]}}],
                  'yaw': [{'type': 'step', 'at': 0.0, 'value': {'uniform': [-20, 20]}}]},
    'disturbances': {
        'current': {'speed': {'uniform': [0.0, 0.3]}, 'direction': {'uniform': [0, 360]}},
        'com_error': {'magnitude': {'uniform': [0.0, 0.01]}},
        'external_wrench': [{'probability': 0.3, 'start': 0.5, 'duration': 0.1,
                             'wrench': [1.0e200, 0, 0, 0, 0, 0]}]},
    'robot': {'tilt_rate_limit': {'uniform': [60, 150]}},
    'compare': {'controllers': ['pd', 'pid']},
    'hold': [{'metric': 'final_error', 'position': 0.1},
             {'metric': 'max_error', 'angle': 30.0}],
}
IDS = {f's{i:05d}-{c}-robust' for i in range(4) for c in ('pd', 'pid')}


class CampaignRun(NamedTuple):
    out: Path
    returncode: int
    stdout: str
    stderr: str


def tiltrov_campaign(*args: str | Path) -> CampaignRun:
    """``tiltrov campaign ARGS`` in a subprocess, as a user runs it, to its end however
    slowly a loaded machine runs it (a hang fails it: :func:`run_while_progressing`)."""
    argv = [str(a) for a in args]
    result = run_while_progressing([sys.executable, '-m', 'tiltrov_ros.cli', 'campaign',
                                    *argv])
    out = Path(argv[argv.index('--out') + 1]) if '--out' in argv else Path()
    return CampaignRun(out, result.returncode, result.stdout, result.stderr)


def read_rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline='', encoding='utf-8') as stream:
        return list(csv.DictReader(stream))


def comparable(rows: list[dict[str, str]]) -> list[dict[str, str]]:
    """Rows sorted by run id, without the columns of where and how long a run ran."""
    return sorted(({k: v for k, v in r.items() if k not in ('seconds', 'worker')}
                   for r in rows), key=lambda r: r['run_id'])
