"""The summary of a campaign table: hold rate and error percentiles per configuration.

Per configuration (one row of the comparison table): runs, failed runs (they
raised), runs that hold (by the campaign's ``hold`` bounds), the hold rate,
and percentiles (50, 90, 95, max) over the runs that did not fail of

* the final position error, |(final_error.x, .y, .z)|, mm;
* the final attitude error, the largest of final_error.roll, .pitch, .yaw, deg;

and the worst runs: failed ones first, then by final position error. The runs
that do not hold are counted by verdict (``servo_range``, ``physics``,
``control``: :func:`tiltrov_ros.core.hold.verdict`) and the worst of each
verdict listed; with robot factors (``compare.robot``) a table compares the
levels of the last factor side by side.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from tiltrov_ros.campaign.table import number
from tiltrov_ros.core.campaign import VERDICTS, Bound, CampaignSpec
from tiltrov_ros.core.campaign.spec import TIME_METRICS
from tiltrov_ros.core.hold import HELD
from tiltrov_ros.core.names import DOF_NAMES

PERCENTILES = (50, 90, 95, 100)


def final_position_error(row: Mapping[str, str]) -> float | None:
    """m: the norm of the final x, y, z errors of a row (None for a failed run)."""
    values = [number(row[f'final_error.{d}']) for d in DOF_NAMES[:3]]
    return None if any(v is None for v in values) else math.hypot(*values)  # type: ignore[arg-type]


def final_attitude_error(row: Mapping[str, str]) -> float | None:
    """rad: the largest final roll, pitch, yaw error of a row (None for a failed run)."""
    values = [number(row[f'final_error.{d}']) for d in DOF_NAMES[3:]]
    return None if any(v is None for v in values) else max(values)  # type: ignore[type-var]


@dataclass(frozen=True)
class ConfigSummary:
    configuration: str
    runs: int
    failed: int
    holds: int
    hold_rate: float | None
    position_mm: dict[str, float | None]     # 'p50', 'p90', 'p95', 'max'
    attitude_deg: dict[str, float | None]
    worst: list[str]                          # run ids
    verdicts: dict[str, int]                  # runs that do not hold, by verdict


def _percentiles(values: Sequence[float], scale: float) -> dict[str, float | None]:
    names = [f'p{p}' if p < 100 else 'max' for p in PERCENTILES]
    if not values:
        return dict.fromkeys(names)
    found = np.percentile(np.asarray(values) * scale, PERCENTILES)
    return {name: float(v) for name, v in zip(names, found)}


def _worst_first(row: Mapping[str, str]) -> tuple[bool, bool, float, str]:
    """Sort key: failed runs, then runs that do not hold, then by final position error
    (largest first), then by run id (so the order does not depend on the table's)."""
    error = final_position_error(row)
    return (row['status'] == 'ok', row['holds'] == '1',
            -error if error is not None else -math.inf, row['run_id'])


def summarize(spec: CampaignSpec, rows: Sequence[Mapping[str, str]], *,
              worst: int = 5) -> list[ConfigSummary]:
    """One :class:`ConfigSummary` per configuration of ``spec``, from table rows."""
    out = []
    for config in spec.configurations:
        mine = [r for r in rows if r['configuration'] == config.name]
        ok = [r for r in mine if r['status'] == 'ok']
        holds = sum(r['holds'] == '1' for r in mine)
        positions = [e for e in map(final_position_error, ok) if e is not None]
        attitudes = [e for e in map(final_attitude_error, ok) if e is not None]
        ranked = sorted(mine, key=_worst_first)[:worst]
        out.append(ConfigSummary(config.name, len(mine), len(mine) - len(ok), holds,
                                 holds / len(mine) if mine else None,
                                 _percentiles(positions, 1e3),
                                 _percentiles(attitudes, 180.0 / math.pi),
                                 [r['run_id'] for r in ranked],
                                 {v: sum(r['verdict'] == v for r in mine)
                                  for v in VERDICTS if v != HELD}))
    return out


def worst_by_verdict(rows: Sequence[Mapping[str, str]], worst: int = 5
                     ) -> dict[str, list[Mapping[str, str]]]:
    """The ``worst`` worst runs of each verdict but ``held`` (:func:`_worst_first`)."""
    return {v: sorted((r for r in rows if r['verdict'] == v), key=_worst_first)[:worst]
            for v in VERDICTS if v != HELD}


def factor_rows(spec: CampaignSpec, summaries: Sequence[ConfigSummary]) -> list[list[str]]:
    """The runs that hold per level of the last robot factor (columns) and everything
    else of the configuration (rows), header first; empty without factors."""
    if not spec.factors:
        return []
    factor, levels = spec.factors[-1]
    by_name = {s.configuration: s for s in summaries}
    rows: dict[str, list[str]] = {}
    for config in spec.configurations:
        stem = config.name.removesuffix(f'-{config.levels[-1]}')
        summary = by_name[config.name]
        rows.setdefault(stem, [stem]).append(
            f'{summary.holds} of {summary.runs}' if summary.runs else '-')
    return [[f'configuration / {factor}', *levels], *rows.values()]


#: What the verdicts mean, in summary.md.
VERDICT_TEXT = (
    'A run that does not hold gets a verdict, judged in this order: **physics** when no '
    'tilt on the full circle produces the wrench that holds the final setpoint against '
    'the mean current (the steady-wrench oracle, short by more than the wrench '
    'tolerance), or not even servos turning all the way round follow it while the '
    'current wanders (the wander oracle); **servo_range** when no tilt within the servo '
    'range produces it, or no path of tilts within the range, at the servo rate, follows '
    'it while the current wanders, where the full circle would; **control** otherwise '
    '(the servos could: the controller\'s or the allocator\'s doing). The same run with '
    'servos turning all the way round (+-180 deg) is run too, as evidence '
    '(counterfactual_holds). docs/campaign.md, "Verdicts".')


def _errors(row: Mapping[str, str]) -> str:
    """'final position [mm] | final attitude [deg]' cells of a row."""
    pos, att = final_position_error(row), final_attitude_error(row)
    return (f'{_fmt(None if pos is None else 1e3 * pos)} | '
            f'{_fmt(None if att is None else math.degrees(att), 2)}')


def _missed(row: Mapping[str, str]) -> str:
    return (row['error'] or _shorten(row['violations']) or '-').replace('|', '/')


def describe_bound(bound: Bound) -> str:
    """``final_error: x, y, z <= 50 mm; roll, pitch, yaw <= 2 deg (pid)``."""
    groups: dict[str, list[str]] = {}
    for key, limit in bound.limits:
        if bound.metric in TIME_METRICS:
            text = f'{limit:g} s'
        elif key in DOF_NAMES[:3]:
            text = f'{1e3 * limit:g} mm'
        elif key in DOF_NAMES[3:]:
            text = f'{math.degrees(limit):.4g} deg'
        else:
            text = f'{limit:g}'
        groups.setdefault(text, []).append(key)
    parts = [f'{", ".join(keys)} <= {text}' if keys != [''] else f'<= {text}'
             for text, keys in groups.items()]
    scope = [*bound.controllers, *bound.allocators, *bound.gains]
    return f'{bound.metric}: {"; ".join(parts)}' + (f' ({", ".join(scope)})' if scope else '')


def _shorten(violations: str, most: int = 3) -> str:
    """The first ``most`` missed bounds and how many more."""
    parts = [p for p in violations.split('; ') if p]
    more = f'; {len(parts) - most} more' if len(parts) > most else ''
    return '; '.join(parts[:most]) + more


def _fmt(value: float | None, digits: int = 1) -> str:
    return '-' if value is None else f'{value:.{digits}f}'


def comparison_rows(summaries: Sequence[ConfigSummary]) -> list[list[str]]:
    """The comparison table, header first (text cells)."""
    verdicts = [v for v in VERDICTS if v != HELD]
    header = ['configuration', 'runs', 'failed', 'hold', 'hold rate',
              *(v.replace('_', ' ') for v in verdicts),
              'pos p50 [mm]', 'pos p90 [mm]', 'pos p95 [mm]', 'pos max [mm]',
              'att p50 [deg]', 'att p90 [deg]', 'att max [deg]']
    body = [[s.configuration, str(s.runs), str(s.failed), str(s.holds),
             '-' if s.hold_rate is None else f'{100 * s.hold_rate:.0f} %',
             *(str(s.verdicts[v]) for v in verdicts),
             *(_fmt(s.position_mm[k]) for k in ('p50', 'p90', 'p95', 'max')),
             *(_fmt(s.attitude_deg[k], 2) for k in ('p50', 'p90', 'max'))]
            for s in summaries]
    return [header, *body]


def text_table(rows: Sequence[Sequence[str]]) -> str:
    """Rows as aligned plain text (first column left, the rest right)."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return '\n'.join('  '.join(c.ljust(w) if i == 0 else c.rjust(w)
                               for i, (c, w) in enumerate(zip(r, widths))) for r in rows)


def markdown_table(rows: Sequence[Sequence[str]]) -> str:
    lines = ['| ' + ' | '.join(rows[0]) + ' |', '|' + '---|' * len(rows[0])]
    return '\n'.join(lines + ['| ' + ' | '.join(r) + ' |' for r in rows[1:]])


def write_summary(spec: CampaignSpec, rows: Sequence[Mapping[str, str]],
                  summaries: Sequence[ConfigSummary], out: Path, *, samples: int,
                  exported: Mapping[str, Path], figures: Sequence[Path]) -> list[Path]:
    """summary.md (comparison table, hold criterion, worst runs, figures) and
    summary.json (the same numbers) in ``out``."""
    by_id = {r['run_id']: r for r in rows}
    table = comparison_rows(summaries)
    lines = [f'# Campaign {spec.name}', '',
             f'{samples} samples (seed {spec.seed}) x {len(spec.configurations)} '
             f'configurations = {len(rows)} runs in runs.csv.', '',
             markdown_table(table), '',
             'A run holds when it did not fail and meets every bound:', '']
    lines += [f'- {describe_bound(b)}' for b in spec.hold] or ['- (no bounds given)']
    lines += ['', VERDICT_TEXT]
    factors = factor_rows(spec, summaries)
    if factors:
        lines += ['', '## Robot factors', '', 'Runs that hold:', '', markdown_table(factors)]
    lines += ['', '## Worst runs', '',
              '| run | status | holds | verdict | final position [mm] | final attitude [deg] '
              '| missed | files |', '|---|---|---|---|---|---|---|---|']
    for summary in summaries:
        for run_id in summary.worst:
            row = by_id[run_id]
            folder = exported.get(run_id)
            where = f'{folder.relative_to(out).as_posix()}/' if folder else '-'
            lines.append(f'| {run_id} | {row["status"]} | {row["holds"]} | {row["verdict"]} | '
                         f'{_errors(row)} | {_missed(row)} | {where} |')
    lines += ['', '## Failures by verdict', '']
    for name, worst_rows in worst_by_verdict(rows, len(summaries[0].worst)
                                             if summaries else 0).items():
        count = sum(r['verdict'] == name for r in rows)
        lines += [f'**{name}**: {count} run(s)' + (', the worst:' if worst_rows else '.'), '']
        if worst_rows:
            lines += ['| run | final position [mm] | final attitude [deg] | steady wrench '
                      'short (x tolerance) | missed | servos +-180 deg |',
                      '|---|---|---|---|---|---|']
            for row in worst_rows:
                ratio = row.get('steady_shortfall_ratio_full_circle', '')
                again = {'1': 'holds', '0': 'misses', '': '-'}[row['counterfactual_holds']]
                lines.append(f'| {row["run_id"]} | {_errors(row)} | '
                             f'{_fmt(None if ratio == "" else float(ratio), 2)} | '
                             f'{_missed(row)} | {again} |')
            lines.append('')
    if exported:
        lines += ['', 'Each folder holds the scenario file, the controller and allocator '
                  'parameter files and reproduce.sh, the `tiltrov sim` command that runs it '
                  'again (its metrics.json equals the run\'s row).']
    if figures:
        lines += ['', '## Figures', ''] + [f'![{p.stem}]({p.relative_to(out).as_posix()})'
                                           for p in figures]
    md = out / 'summary.md'
    md.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    doc: dict[str, Any] = {
        'campaign': spec.name, 'seed': spec.seed, 'samples': samples, 'runs': len(rows),
        'hold': [describe_bound(b) for b in spec.hold],
        'configurations': [asdict(s) for s in summaries],
        'factors': {name: list(levels) for name, levels in spec.factors},
        'worst_by_verdict': {v: [r['run_id'] for r in worst]
                             for v, worst in worst_by_verdict(
                                 rows, len(summaries[0].worst) if summaries else 0).items()}}
    js = out / 'summary.json'
    js.write_text(json.dumps(doc, indent=2, allow_nan=False) + '\n', encoding='utf-8')
    return [md, js]
