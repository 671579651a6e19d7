"""``tiltrov demo`` (``make demo``): the first command of the README, the main job end to end.

The full ROS stack on the paper's positioning scenario (Section 4.1,
``pitch_hold``), once per controller, each run recorded into an MCAP bag, then
the bags analyzed into metrics and figures::

    tiltrov demo                                  # pd, switching, pid into runs/demo
    tiltrov demo --controllers pd,switching --out runs/paper

Steps, for each controller (default: the paper's PD, its switching baseline and
this package's PID):

1. ``tiltrov launch --scenario pitch_hold --controller C --record OUT/bags/C``:
   plant simulator, wrench controller, thrust allocator, reference publisher and
   bag recorder as separate processes over DDS, in lockstep (the plant waits for
   each control tick), the nodes' output into ``OUT/logs/C.log``;
2. ``tiltrov analyze OUT/bags/* --out OUT/analysis``: ``metrics.json`` per run
   and the index of all runs, ``control.csv``, ``run.npz``, the paper's
   Figs. 5-7 and the wrench figures, runs overlaid;
3. the same scenario through the headless runner (no ROS, the same core code):
   the metrics of each bag must equal the headless ones (floats to 1e-9), else
   the demo says where they differ and exits 1.

Finally a table of the results (also ``OUT/summary.md``) and the paths. Exit
codes: 0 done, 1 a run failed or disagreed with the headless run, 2 bad options.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
import shutil
import sys
import time
from typing import Any

import numpy as np

from tiltrov_ros.core.controllers import CONTROLLER_KINDS
from tiltrov_ros.core.errors import TiltrovError
from tiltrov_ros.core.metrics import compute_metrics, metric_differences

SCENARIO = 'pitch_hold'
DEFAULT_CONTROLLERS = ('pd', 'switching', 'pid')
EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', type=Path, default=Path('runs/demo'), metavar='DIR',
                        help='output directory (default: runs/demo); its bags/, logs/ and '
                             'analysis/ are replaced')
    parser.add_argument('--scenario', default=SCENARIO, metavar='NAME|FILE',
                        help=f'scenario (default: {SCENARIO}, the paper\'s Section 4.1)')
    parser.add_argument('--controllers', default=','.join(DEFAULT_CONTROLLERS),
                        metavar='C1,C2,...',
                        help=f'controllers to run, comma-separated (default: '
                             f'{",".join(DEFAULT_CONTROLLERS)}; known: '
                             f'{", ".join(CONTROLLER_KINDS)})')
    parser.add_argument('--duration', type=float, default=None, metavar='SEC',
                        help="simulated seconds (default: the scenario's)")
    parser.add_argument('--single-process', action='store_true',
                        help='all nodes in one process (default: one process per node)')


class DemoError(Exception):
    """Bad options: one line on stderr, exit code 2."""


def parse_controllers(text: str) -> list[str]:
    names = list(dict.fromkeys(c.strip() for c in text.split(',') if c.strip()))
    bad = [c for c in names if c not in CONTROLLER_KINDS]
    if bad or not names:
        raise DemoError(f'--controllers: unknown controller {bad[0] if bad else "(none)"!r}; '
                        f'known: {", ".join(CONTROLLER_KINDS)}')
    return names


def _say(text: str) -> None:
    print(f'[demo] {text}', flush=True)


def record_run(controller: str, args: argparse.Namespace, bag: Path, log_path: Path) -> int:
    """One recorded lockstep launch; the launcher's exit code."""
    from tiltrov_ros.stack.launch import launch
    from tiltrov_ros.stack.specs import LaunchOptions

    options = LaunchOptions(scenario=args.scenario, controller=controller,
                            duration=args.duration, record=bag,
                            single_process=args.single_process)
    with log_path.open('w', encoding='utf-8') as stream:
        return launch(options, stream=stream)


def headless_metrics(scenario: str, controller: str,
                     duration: float | None) -> dict[str, Any]:
    """metrics.json of the same run through the headless runner (no ROS)."""
    from tiltrov_ros.core.runner import run_scenario, stack_config

    return compute_metrics(run_scenario(stack_config(scenario, controller),
                                        duration=duration))


def summary_table(metrics: dict[str, dict[str, Any]]) -> str:
    """Markdown table: final and RMS errors, tilt use, saturation, per run."""

    def mm(value: Any) -> str:
        return '-' if value is None else f'{1e3 * value:.1f}'

    def deg(value: Any) -> str:
        return '-' if value is None else f'{np.degrees(value):.2f}'

    lines = ['| run | final x / y / z [mm] | final roll / pitch / yaw [deg] | '
             'RMS x / z [mm] | RMS pitch [deg] | servo travel front / rear [deg] | '
             'thrust saturation |',
             '|---|---|---|---|---|---|---|']
    for name, m in metrics.items():
        final, rms, travel = m['final_error'], m['rms_error'], m.get('servo_travel') or {}
        lines.append(
            f"| {name} | {' / '.join(mm(final[d]) for d in ('x', 'y', 'z'))} | "
            f"{' / '.join(deg(final[d]) for d in ('roll', 'pitch', 'yaw'))} | "
            f"{mm(rms['x'])} / {mm(rms['z'])} | {deg(rms['pitch'])} | "
            f"{deg(travel.get('front'))} / {deg(travel.get('rear'))} | "
            f"{100 * (m.get('thrust_saturation_fraction') or 0.0):.1f} % |")
    return '\n'.join(lines)


def _demo(args: argparse.Namespace) -> int:
    from tiltrov_ros.analysis.analyze import analyze
    from tiltrov_ros.nodes.transforms import NO_TF2_MSGS, TFMessage

    controllers = parse_controllers(args.controllers)
    if args.duration is not None and not args.duration > 0:
        raise DemoError(f'--duration must be > 0 s, got {args.duration}')
    out: Path = args.out
    for sub in ('bags', 'logs', 'analysis'):
        shutil.rmtree(out / sub, ignore_errors=True)
    (out / 'logs').mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    mode = 'one process' if args.single_process else 'one process per node'
    _say(f'the full ROS stack ({mode}, lockstep, Fast DDS) on {args.scenario}, '
         f'controllers: {", ".join(controllers)}')
    if TFMessage is None:
        _say(f'{NO_TF2_MSGS}: the bags have no transform tree')
    bags = []
    for controller in controllers:
        bag, log_path = out / 'bags' / controller, out / 'logs' / f'{controller}.log'
        t0 = time.monotonic()
        code = record_run(controller, args, bag, log_path)
        if code != 0:
            _say(f'{controller}: the launch failed (exit {code}); its output: {log_path}')
            tail = log_path.read_text(encoding='utf-8').splitlines()[-15:]
            print('\n'.join(f'    {line}' for line in tail), file=sys.stderr)
            return EXIT_FAILED
        _say(f'{controller}: recorded {bag} in {time.monotonic() - t0:.1f} s '
             f'(node output: {log_path})')
        bags.append(bag)

    analysis_dir = out / 'analysis'
    t0 = time.monotonic()
    result = analyze(bags, analysis_dir)
    _say(f'analyzed {len(bags)} bags in {time.monotonic() - t0:.1f} s')
    for note in result.notes:
        _say(f'note: {note}')

    disagreements = []
    for controller, (name, recorded) in zip(controllers, result.metrics.items()):
        differences = metric_differences(
            recorded, headless_metrics(args.scenario, controller, args.duration))
        if differences:
            disagreements.append((name, differences))
    if disagreements:
        for name, differences in disagreements:
            _say(f'{name}: the bag and the headless runner disagree:')
            for line in differences[:20]:
                print(f'    {line}', file=sys.stderr)
    else:
        _say('every bag gives the metrics of the headless runner (no ROS), floats to 1e-9')

    table = summary_table(result.metrics)
    summary = out / 'summary.md'
    summary.write_text(
        f'# tiltrov demo: {args.scenario}\n\n'
        f'Full ROS stack in lockstep ({mode}); bags in `bags/`, analysis in `analysis/`.\n'
        f'Final errors: mean |e| over the last 10 s; RMS over the run.\n\n{table}\n',
        encoding='utf-8')
    print()
    print(table)
    print()
    figures = sorted(p for p in result.written if p.suffix == '.png')
    _say(f'done in {time.monotonic() - started:.1f} s; results in {out}:')
    print(f'  bags (MCAP, rosbag2):   {", ".join(str(b) for b in bags)}')
    print(f'  metrics:                {analysis_dir / "metrics.json"} (each run: '
          f'{analysis_dir}/<run>/metrics.json)')
    print(f'  figures:                {", ".join(p.name for p in figures)} in {analysis_dir}')
    print(f'  summary table:          {summary}')
    print(f'  node output:            {out / "logs"}')
    return EXIT_FAILED if disagreements else EXIT_OK


def run(args: argparse.Namespace) -> int:
    try:
        return _demo(args)
    except DemoError as exc:
        print(f'tiltrov demo: error: {exc}', file=sys.stderr)
        return EXIT_USAGE
    except (TiltrovError, OSError) as exc:
        print(f'tiltrov demo: error: {" ".join(str(exc).split())}', file=sys.stderr)
        return EXIT_FAILED


def main(argv: Sequence[str] | None = None) -> int:
    """Run as ``python -m tiltrov_ros.cli.demo`` (same as ``tiltrov demo``)."""
    parser = argparse.ArgumentParser(prog='tiltrov demo')
    add_arguments(parser)
    return run(parser.parse_args(argv))
