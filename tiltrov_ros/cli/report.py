"""``tiltrov report``: the paper's scenarios with every controller, headless, into
the results page and its figures (``make figures``: ``--page docs/results.md``;
what is run and written: :mod:`tiltrov_ros.analysis.report`)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys

from tiltrov_ros.analysis.report import (
    build_section,
    checks,
    relative,
    run_scenarios,
    update_readme,
    write_report_figures,
)
from tiltrov_ros.analysis.runs import InputError, one_line
from tiltrov_ros.core.metrics import compute_metrics


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--page', '--readme', dest='page', type=Path, metavar='FILE',
                        help='Markdown page to update between the results markers, e.g. '
                             'docs/results.md (default: only print the section)')
    parser.add_argument('--out', type=Path, metavar='DIR',
                        help='figure directory (default: the docs/figures directory of the '
                             "page's project: beside a page in docs/, else under it)")
    parser.add_argument('--dpi', type=int, default=80, help='figure resolution (default 80)')
    parser.add_argument('--duration', type=float, metavar='SEC',
                        help='shorten every run to SEC (for trying the command; the '
                             'published numbers are for the full scenarios)')



def figure_dir(page: Path | None) -> Path:
    """Where the figures go by default: ``docs/figures`` of the page's project (the
    page's directory, or its parent when the page is in ``docs/``)."""
    base = page.parent if page is not None else Path('.')
    if base.name == 'docs':
        base = base.parent
    return base / 'docs' / 'figures'


def run(args: argparse.Namespace) -> int:
    readme: Path | None = args.page
    out: Path = args.out or figure_dir(readme)
    try:
        if readme is not None and not readme.is_file():
            raise InputError(f'no README or page at {readme}')
        runs = run_scenarios(args.duration)
        results = [(config, compute_metrics(log)) for config, log in runs]
        out.mkdir(parents=True, exist_ok=True)
        figures = write_report_figures(runs, out, args.dpi)
        table = {f'{c.scenario.name}/{c.controller.kind}': m for c, m in results}
        (out / 'results.json').write_text(json.dumps(table, indent=1, allow_nan=False) + '\n',
                                          encoding='utf-8')
        base = readme.parent if readme else Path('.')
        section = build_section(results, [relative(f, base) for f in figures],
                                duration=args.duration)
        if readme is None:
            print(section)
        else:
            readme.write_text(update_readme(readme.read_text(encoding='utf-8'), section),
                              encoding='utf-8')
            print(f'updated {readme} ({len(results)} runs, {len(figures)} figures in {out})')
        for line in checks(results):
            print(line.replace('**', ''))
    except InputError as exc:
        print(f'tiltrov report: error: {exc}', file=sys.stderr)
        return 2
    except OSError as exc:
        print(f'tiltrov report: error: {one_line(exc)}', file=sys.stderr)
        return 1
    return 0
