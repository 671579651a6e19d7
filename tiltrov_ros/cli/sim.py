"""``tiltrov sim``: a scenario headless, with the same core code as the ROS stack.

::

    tiltrov sim --scenario pitch_hold --controller pd --out runs/sim
    tiltrov sim --scenario trajectory --compare            # pd, pid and switching overlaid
    tiltrov sim --scenario my_dive.yaml --duration 20 --allocator paper
    tiltrov sim --scenario current_hold --robot robot_past_vertical   # servos past vertical
    tiltrov sim --scenario my_hold.yaml --hold config/campaigns/servo_range.yaml

One run writes into ``--out``: ``run.npz`` (the whole RunLog,
:meth:`RunLog.save_npz`), ``control.csv`` (the control grid, one row per tick,
for spreadsheets), ``metrics.json`` (:func:`tiltrov_ros.core.metrics.
compute_metrics`; its ``hold`` judged by the shipped station-keeping criterion or
``--hold``'s) and the figures of :mod:`tiltrov_ros.analysis.figures`. With
``--compare`` each controller's data go into ``--out/<controller>/`` and the
figures, runs overlaid, into ``--out``.

Bad input (unknown scenario, invalid YAML, a parameter out of range) ends with
one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
import sys

from tiltrov_ros.analysis.runs import (
    InputError,
    hold_criterion,
    resolve,
    simulate,
    summary_line,
    write_run,
)
from tiltrov_ros.core.controllers import CONTROLLER_KINDS
from tiltrov_ros.core.names import ALLOCATOR_MODES

from .output import print_written, report_errors


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--scenario', default='pitch_hold', metavar='NAME|FILE',
                        help='a shipped scenario name (config/scenarios/) or a scenario YAML '
                             'file (default: pitch_hold)')
    which = parser.add_mutually_exclusive_group()
    which.add_argument('--controller', choices=CONTROLLER_KINDS,
                       help='default: the one in config/wrench_controller.yaml')
    which.add_argument('--compare', nargs='?', const=','.join(CONTROLLER_KINDS),
                       metavar='LIST',
                       help='run several controllers (comma-separated; alone: '
                            f'{",".join(CONTROLLER_KINDS)}) and overlay them')
    parser.add_argument('--allocator', choices=ALLOCATOR_MODES,
                        help='allocator mode (default: config/thrust_allocator.yaml)')
    parser.add_argument('--controller-file', type=Path, metavar='FILE',
                        help='wrench_controller parameter file (default: the shipped one)')
    parser.add_argument('--allocator-file', type=Path, metavar='FILE',
                        help='thrust_allocator parameter file (default: the shipped one)')
    parser.add_argument('--robot', metavar='NAME|FILE',
                        help='robot parameter file, or the name of a shipped one '
                             '(robot_past_vertical: servos past vertical; default: '
                             "config/robot.yaml, the paper's +-90 deg)")
    parser.add_argument('--duration', type=float, metavar='SEC',
                        help="simulated seconds (default: the scenario's)")
    parser.add_argument('--out', type=Path, default=Path('runs/sim'), metavar='DIR',
                        help='output directory (default: runs/sim)')
    parser.add_argument('--hold', type=Path, metavar='FILE',
                        help="hold criterion of metrics.json's hold: a campaign file (its "
                             'hold section) or a hold file (default: '
                             'config/campaigns/station_keeping.yaml)')
    parser.add_argument('--no-figures', action='store_true', help='skip the PNG figures')
    parser.add_argument('--dpi', type=int, default=100, help='figure resolution (default 100)')


def _controllers(args: argparse.Namespace) -> list[str | None]:
    if args.compare is None:
        return [args.controller]
    names = [c.strip() for c in args.compare.split(',') if c.strip()]
    bad = [c for c in names if c not in CONTROLLER_KINDS]
    if bad or not names:
        raise InputError(f'--compare: unknown controller {bad[0] if bad else "(none)"!r}; '
                         f'allowed: {", ".join(CONTROLLER_KINDS)}')
    return list(dict.fromkeys(names))


def _run(args: argparse.Namespace) -> list[Path]:
    kinds = _controllers(args)
    configs = [resolve(args.scenario, kind, args.allocator, controller_file=args.controller_file,
                       allocator_file=args.allocator_file, robot=args.robot) for kind in kinds]
    criterion = hold_criterion(args.hold)
    logs = [simulate(config, args.duration) for config in configs]
    written: list[Path] = []
    out: Path = args.out
    for config, log in zip(configs, logs):
        paths, metrics = write_run(log, out if args.compare is None
                                   else out / config.controller.kind, criterion)
        written += paths
        print(summary_line(metrics))
    if not args.no_figures:
        from tiltrov_ros.analysis.figures import write_figures
        written += write_figures(logs, out, dpi=args.dpi)
    return written


def run(args: argparse.Namespace) -> int:
    def task() -> int:
        print_written(_run(args), args.out)
        return 0

    return report_errors('tiltrov sim', task)


def main(argv: Sequence[str] | None = None) -> int:
    """Run as ``python -m tiltrov_ros.cli.sim`` (same as ``tiltrov sim``)."""
    parser = argparse.ArgumentParser(prog='tiltrov sim')
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == '__main__':
    sys.exit(main())
