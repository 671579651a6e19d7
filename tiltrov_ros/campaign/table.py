"""The campaign table ``runs.csv``: one row per finished run, appended as runs finish.

Columns, in order:

* ``run_id`` (``s00042-pid-robust``), ``sample``, ``configuration``,
  ``controller``, ``allocator``, ``gains``;
* ``status`` (``ok`` or ``failed``: the run raised), ``holds`` (1 or 0, by the
  campaign's ``hold`` bounds; a failed run does not hold), ``violations`` (the
  bounds it missed, ``; ``-separated), ``verdict`` (``held``, ``servo_range``,
  ``physics``, ``control``: :func:`tiltrov_ros.core.hold.verdict`; the same as
  ``hold.verdict`` where the run has a ``hold``),
  ``counterfactual_holds`` (1 or 0: the same run with servos at +-180 deg, run
  for the runs that do not hold, evidence beside the verdict; empty when not run)
  and
  ``counterfactual_violations``, ``error`` (the exception of a failed run),
  ``seconds`` (its wall time on the worker, the counterfactual's included),
  ``worker`` (host:pid);
* ``param.<key>``: the sample's parameters
  (:attr:`tiltrov_ros.core.campaign.Sample.params`);
* every key of ``metrics.json``, nested keys joined by dots
  (``final_error.x``, ``run.controller``, ``hold.verdict``), empty where the value
  is null (a null ``hold``: its four columns empty).

Floats are written with ``repr``, so reading them back gives the same numbers.
CSV, not Parquet: each batch of rows is appended and flushed, so a campaign
killed at any moment leaves a table that ``--resume`` reads (a torn last line
is cut off) and continues.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
import csv
import os
from pathlib import Path
from typing import Any, TextIO

from tiltrov_ros.core.campaign import metrics_template
from tiltrov_ros.core.errors import CampaignError
from tiltrov_ros.core.yamlfile import flatten

TABLE = 'runs.csv'
RUN_COLUMNS = ('run_id', 'sample', 'configuration', 'controller', 'allocator', 'gains',
               'status', 'holds', 'violations', 'verdict', 'counterfactual_holds',
               'counterfactual_violations', 'error', 'seconds', 'worker')
#: Columns that depend on where and when a run ran, not on what it computed.
TIMING_COLUMNS = ('seconds', 'worker')
PARAM = 'param.'


def metric_columns() -> list[str]:
    return list(flatten(metrics_template()))


def columns(param_keys: Iterable[str]) -> list[str]:
    """The table's header for samples with these parameters."""
    return [*RUN_COLUMNS, *(PARAM + k for k in param_keys), *metric_columns()]


def cell(value: Any) -> str:
    if value is None:
        return ''
    if isinstance(value, bool):
        return str(int(value))
    return repr(value) if isinstance(value, float) else str(value)


def number(text: str) -> float | None:
    """A numeric cell (None when empty)."""
    return float(text) if text != '' else None


def row_metrics(row: Mapping[str, str]) -> dict[str, Any]:
    """``metrics.json`` of a row, with its types (counts int, ``run.*`` text, null None)."""

    def rebuild(template: Mapping[str, Any], prefix: str) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key, shape in template.items():
            name = f'{prefix}{key}'
            if isinstance(shape, Mapping):
                out[key] = rebuild(shape, f'{name}.')
                continue
            text = row[name]
            if text == '':
                out[key] = None
            elif name.startswith('run.') or isinstance(shape, str):
                out[key] = text
            elif isinstance(shape, bool):
                out[key] = text == '1'
            elif isinstance(shape, int):
                out[key] = int(text)
            else:
                out[key] = float(text)
        return out

    metrics = rebuild(metrics_template(), '')
    hold = metrics.get('hold')
    if isinstance(hold, Mapping) and all(v is None for v in hold.values()):
        metrics['hold'] = None              # a run without a hold verdict: null
    return metrics


def read_table(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    """Header and rows of a table (a torn last line, from a kill mid-write, is skipped)."""
    text = path.read_text(encoding='utf-8')
    if text and not text.endswith('\n'):
        text = text[:text.rfind('\n') + 1]
    reader = csv.reader(text.splitlines())
    header = next(reader, [])
    rows = []
    for number_, values in enumerate(reader, start=2):
        if len(values) != len(header):
            raise CampaignError(f'{path}: line {number_}: {len(values)} fields, the header '
                                f'has {len(header)}')
        rows.append(dict(zip(header, values)))
    return header, rows


class RunTable:
    """Appends rows to ``runs.csv`` (see the module docstring)."""

    def __init__(self, path: Path, header: Sequence[str], *, resume: bool) -> None:
        """Create the table, or with ``resume`` continue an existing one (its header must
        be ``header``; a torn last line is cut off). ``done`` holds the run ids in it."""
        self.path = path
        self.header = list(header)
        self.done: dict[str, dict[str, str]] = {}
        exists = path.is_file() and path.stat().st_size > 0
        if exists and not resume:
            raise CampaignError(f'{path} already holds runs: --resume to continue that '
                                'campaign, or choose another --out')
        if exists:
            old_header, rows = read_table(path)
            if old_header != self.header:
                raise CampaignError(f'{path}: its columns differ from this campaign\'s (made '
                                    'by another campaign file or version); use another --out')
            with path.open('r+b') as raw:       # cut a torn last line
                data = raw.read()
                raw.truncate(data.rfind(b'\n') + 1)
            for row in rows:
                if row['run_id'] in self.done:
                    raise CampaignError(f'{path}: run {row["run_id"]} appears twice')
                self.done[row['run_id']] = row
        path.parent.mkdir(parents=True, exist_ok=True)
        self._stream: TextIO = path.open('a', encoding='utf-8', newline='')
        self._writer = csv.writer(self._stream, lineterminator='\n')
        if not exists:
            self._writer.writerow(self.header)
            self._flush()

    def append(self, rows: Iterable[Mapping[str, Any]]) -> None:
        """Write rows (mappings of column -> value; missing columns empty) and flush them
        to disk."""
        for row in rows:
            unknown = set(row) - set(self.header)
            if unknown:
                raise ValueError(f'not a column of the table: {sorted(unknown)[0]}')
            self._writer.writerow([cell(row.get(name)) for name in self.header])
            self.done[str(row['run_id'])] = {k: cell(v) for k, v in row.items()}
        self._flush()

    def _flush(self) -> None:
        self._stream.flush()
        os.fsync(self._stream.fileno())

    def close(self) -> None:
        self._stream.close()

    def __enter__(self) -> RunTable:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
