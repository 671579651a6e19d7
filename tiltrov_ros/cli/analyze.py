"""``tiltrov analyze``: metrics and figures of recorded runs (bags), no ROS needed.

::

    tiltrov analyze runs/pd/bag --out runs/pd/analysis
    tiltrov analyze runs/pd/bag runs/switching/bag runs/pid/bag --out runs/compare
    tiltrov analyze runs/fleet/bag --namespace robot1 --out runs/robot1
    tiltrov analyze runs/pd/bag --hold my_criterion.yaml --out runs/pd/analysis

What is written: :func:`tiltrov_ros.analysis.analyze.analyze`. Bad input (no such
bag, not a bag, a bag without the stack's topics) ends with one line on stderr
and exit code 2.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
import sys

from tiltrov_ros.analysis.analyze import analyze
from tiltrov_ros.analysis.runs import hold_criterion, summary_line

from .output import print_written, report_errors


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bags', nargs='+', metavar='BAG',
                        help='bag directories (or their .mcap files); several are overlaid')
    parser.add_argument('--out', type=Path, default=Path('runs/analyze'), metavar='DIR',
                        help='output directory (default: runs/analyze)')
    parser.add_argument('--namespace', default=None, metavar='NS',
                        help="the stack's namespace in the bags (default: the namespace of "
                             "the bag's one odom topic)")
    parser.add_argument('--hold', type=Path, metavar='FILE',
                        help="hold criterion of metrics.json's hold: a campaign file (its "
                             'hold section) or a hold file (default: '
                             'config/campaigns/station_keeping.yaml)')
    parser.add_argument('--no-figures', action='store_true', help='skip the PNG figures')
    parser.add_argument('--dpi', type=int, default=100, help='figure resolution (default 100)')


def run(args: argparse.Namespace) -> int:
    def task() -> int:
        result = analyze(args.bags, args.out, namespace=args.namespace,
                         figures=not args.no_figures, dpi=args.dpi,
                         criterion=hold_criterion(args.hold))
        for note in result.notes:
            print(f'tiltrov analyze: note: {note}', file=sys.stderr)
        for name, values in result.metrics.items():
            print(summary_line(values, label=name))
        print_written(result.written, args.out)
        return 0

    return report_errors('tiltrov analyze', task)


def main(argv: Sequence[str] | None = None) -> int:
    """Run as ``python -m tiltrov_ros.cli.analyze`` (same as ``tiltrov analyze``)."""
    parser = argparse.ArgumentParser(prog='tiltrov analyze')
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == '__main__':
    sys.exit(main())
