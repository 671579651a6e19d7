"""The ``tiltrov`` command line: one entry point, one subcommand per task.

Each subcommand lives in its own module, which provides
``add_arguments(parser)`` and ``run(args) -> int``; modules are imported only
when their subcommand runs, so ``tiltrov --help`` stays fast and a broken
optional dependency only affects the subcommand that needs it.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import NamedTuple


class Command(NamedTuple):
    module: str
    help: str


# name -> implementing module (in this package, named as the command) and one-line help.
COMMANDS: dict[str, Command] = {
    'demo': Command('.demo', "run the full stack on the paper's positioning scenario "
                             '(bag, figures, metrics)'),
    'launch': Command('.launch', 'start the ROS stack (plant, controller, allocator, '
                                 'reference) for a scenario, lockstep or realtime'),
    'sim': Command('.sim', 'run a scenario headless (no ROS): time series, metrics.json, '
                           'figures'),
    'analyze': Command('.analyze', 'metrics.json and figures of recorded runs (bags)'),
    'replay': Command('.replay', 'publish a recorded bag into a live graph'),
    'bag': Command('.bag', 'look into a bag (info) or repair one whose recorder was killed'),
    'report': Command('.report', "run the paper's scenarios with every controller; results "
                                 'page and figures'),
    'bench': Command('.bench', 'run the benchmarks of a source checkout (speed ratios '
                               'against baselines measured in the same run)'),
    'soak': Command('.soak', 'one hour of simulated time in lockstep, recorded: RSS of each '
                             'process, messages published vs recorded, stalls'),
    'warmup': Command('.warmup', 'compile (or load) the compiled kernels ahead of use; time '
                                 'per group and the cache directory'),
    'campaign': Command('.campaign', 'Monte-Carlo runs of a campaign file on Dask: hold '
                                         'rate per configuration, table, figures'),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='tiltrov',
        description='Underwater robot with four tilting thrusters: simulate, control, '
                    'record and analyze.')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND', required=True)
    for name, command in COMMANDS.items():
        sub.add_parser(name, help=command.help, description=command.help)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    # Parse the subcommand name first, then let its module define the rest.
    first, _ = parser.parse_known_args(argv[:1] if argv and not argv[0].startswith('-')
                                       else argv)
    command = COMMANDS[first.command]
    module = importlib.import_module(command.module, __package__)
    full = argparse.ArgumentParser(prog=f'tiltrov {first.command}', description=command.help)
    module.add_arguments(full)
    args = full.parse_args(argv[1:])
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        return 130

