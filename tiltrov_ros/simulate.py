"""``tiltrov sim``: a scenario headless, with the same core code as the ROS stack.

::

    tiltrov sim --scenario pitch_hold --controller pd --out runs/sim
    tiltrov sim --scenario trajectory --compare            # pd, pid and switching overlaid
    tiltrov sim --scenario my_dive.yaml --duration 20 --allocator paper

One run writes into ``--out``: ``run.npz`` (the whole RunLog,
:meth:`RunLog.save_npz`), ``control.csv`` (the control grid, one row per tick,
for spreadsheets), ``metrics.json`` (:func:`tiltrov_ros.core.metrics.
compute_metrics`) and the figures of :mod:`tiltrov_ros.figures`. With
``--compare`` each controller's data go into ``--out/<controller>/`` and the
figures, runs overlaid, into ``--out``.

Bad input (unknown scenario, invalid YAML, a parameter out of range) ends with
one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path
import sys
from typing import Any

import numpy as np
import yaml

from tiltrov_ros.core.controllers import CONTROLLER_KINDS, DOF_NAMES
from tiltrov_ros.core.errors import TiltrovError
from tiltrov_ros.core.metrics import compute_metrics, control_errors, write_metrics
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.runner import StackConfig, run_scenario, stack_config
from tiltrov_ros.progress import ProgressBar

EXIT_BAD_INPUT = 2
EXIT_IO = 1
ALLOCATOR_MODES = ('robust', 'paper')
_UNITS = ('m', 'm', 'm', 'rad', 'rad', 'rad')
_WRENCH = (('X', 'N'), ('Y', 'N'), ('Z', 'N'), ('K', 'N m'), ('M', 'N m'), ('N', 'N m'))


class InputError(Exception):
    """Bad user input: reported on one line, exit code 2."""


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
    parser.add_argument('--duration', type=float, metavar='SEC',
                        help="simulated seconds (default: the scenario's)")
    parser.add_argument('--out', type=Path, default=Path('runs/sim'), metavar='DIR',
                        help='output directory (default: runs/sim)')
    parser.add_argument('--no-figures', action='store_true', help='skip the PNG figures')
    parser.add_argument('--dpi', type=int, default=100, help='figure resolution (default 100)')


def one_line(exc: BaseException) -> str:
    """An exception's message on one line."""
    return ' '.join(str(exc).split()) or type(exc).__name__


def resolve(scenario: str, controller: str | None, allocator: str | None, *,
            controller_file: Path | None = None,
            allocator_file: Path | None = None) -> StackConfig:
    """A StackConfig, or :class:`InputError` for anything wrong in the input files."""
    try:
        return stack_config(scenario, controller, allocator_mode=allocator,
                            controller_file=controller_file, allocator_file=allocator_file)
    except (TiltrovError, yaml.YAMLError, OSError) as exc:
        raise InputError(one_line(exc)) from exc


def simulate(config: StackConfig, duration: float | None = None, *,
             label: str | None = None) -> RunLog:
    """Run one configuration with a progress bar on stderr (shown after 1 s)."""
    if duration is not None and not duration > 0:
        raise InputError(f'--duration must be > 0 s, got {duration}')
    name = label or f'{config.scenario.name} {config.controller.kind}'
    try:
        with ProgressBar(name) as bar:
            return run_scenario(config, duration=duration, progress=bar)
    except TiltrovError as exc:
        raise InputError(one_line(exc)) from exc


def write_control_csv(log: RunLog, path: str | Path) -> Path:
    """The control grid as CSV (SI units in the header), one row per tick with odometry.

    Columns: t, the setpoint eta_d, the pose eta (odometry at the tick), the
    error e = eta_d - eta (angles wrapped), wrench_cmd, wrench_achieved,
    thrust_cmd, tilt_cmd and the actual tilts at the tick.
    """
    err = control_errors(log)
    header = ['t [s]']
    header += [f'{n}_d [{u}]' for n, u in zip(DOF_NAMES, _UNITS)]
    header += [f'{n} [{u}]' for n, u in zip(DOF_NAMES, _UNITS)]
    header += [f'e_{n} [{u}]' for n, u in zip(DOF_NAMES, _UNITS)]
    header += [f'{n}_cmd [{u}]' for n, u in _WRENCH]
    header += [f'{n}_achieved [{u}]' for n, u in _WRENCH]
    header += [f'thrust_{i}_cmd [N]' for i in range(1, 5)]
    header += ['tilt_front_cmd [rad]', 'tilt_rear_cmd [rad]', 'tilt_front [rad]',
               'tilt_rear [rad]']
    k = err.ticks
    table = np.hstack([err.t[:, None], err.eta_d, err.eta, err.e, log.wrench_cmd[k],
                       log.wrench_achieved[k], log.thrust_cmd[k], log.tilt_cmd[k],
                       log.tilt_position[err.rows]])
    target = Path(path)
    np.savetxt(target, table, delimiter=',', header=','.join(header), comments='',
               fmt='%.10g')
    return target


def write_run(log: RunLog, out: Path) -> tuple[list[Path], dict[str, Any]]:
    """run.npz, control.csv and metrics.json of one run into ``out``; paths and metrics."""
    out.mkdir(parents=True, exist_ok=True)
    log.save_npz(out / 'run.npz')
    metrics = compute_metrics(log)
    paths = [out / 'run.npz', write_control_csv(log, out / 'control.csv'),
             write_metrics(metrics, out / 'metrics.json')]
    return paths, metrics


def summary_line(metrics: dict[str, Any], label: str | None = None) -> str:
    """Final and RMS errors of one run, in mm and deg, for the terminal.

    ``label`` leads the line (default: the run's scenario and controller).
    """

    def fmt(values: dict[str, Any]) -> str:
        pos = ' '.join(f'{1e3 * (values[d] or 0.0):.2f}' for d in DOF_NAMES[:3])
        ang = ' '.join(f'{np.degrees(values[d] or 0.0):.3f}' for d in DOF_NAMES[3:])
        return f'{pos} mm, {ang} deg'

    run = metrics['run']
    if label is None:
        label = f"{run['scenario']} {run['controller']}"
    return (f'{label}: '
            f"final |e| (x y z, roll pitch yaw) {fmt(metrics['final_error'])}; "
            f"RMS {fmt(metrics['rms_error'])}")


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
                       allocator_file=args.allocator_file) for kind in kinds]
    logs = [simulate(config, args.duration) for config in configs]
    written: list[Path] = []
    out: Path = args.out
    for config, log in zip(configs, logs):
        paths, metrics = write_run(log, out if args.compare is None
                                   else out / config.controller.kind)
        written += paths
        print(summary_line(metrics))
    if not args.no_figures:
        from tiltrov_ros.figures import write_figures
        written += write_figures(logs, out, dpi=args.dpi)
    return written


def report_errors(prog: str, task: Callable[[], int]) -> int:
    """``task()``'s exit code; bad input (:class:`InputError`) one line on stderr and
    exit 2, a file that cannot be written one line and exit 1. ``tiltrov sim``,
    ``analyze`` and ``replay --through`` report alike with it."""
    try:
        return task()
    except InputError as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:
        print(f'{prog}: error: cannot write the results: {one_line(exc)}', file=sys.stderr)
        return EXIT_IO


def print_written(written: Sequence[Path], out: Path) -> None:
    """The files a command wrote, one per line."""
    print(f'wrote {len(written)} files into {out}:')
    for path in written:
        print(f'  {path}')


def run(args: argparse.Namespace) -> int:
    def task() -> int:
        print_written(_run(args), args.out)
        return 0

    return report_errors('tiltrov sim', task)


def main(argv: Sequence[str] | None = None) -> int:
    """Run as ``python -m tiltrov_ros.simulate`` (same as ``tiltrov sim``)."""
    parser = argparse.ArgumentParser(prog='tiltrov sim')
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == '__main__':
    sys.exit(main())
