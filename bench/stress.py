"""``make stress``: what only wall time on a loaded machine can judge (a report, not a test).

The suite asserts what holds on any machine; these runs measure what a loaded machine
does to the stack, beside CPU-bound busy loops (``python3 -c 'while True: pass'``):

* ``short``: ``tiltrov launch --scenario pitch_hold --duration 0.1`` N times (quiet):
  the wall time of each, and whether any stalled (the run starts on its handshake);
* ``recorded``: a recorded 120 s lockstep ``current_hold`` pid run N times beside
  ``--busy`` loops: exit code, steps and ticks missing from the bag, and the largest
  difference of the bag's run from the headless runner's (every series of
  ``assert_same_run``; the contract is 1e-9);
* ``realtime``: a recorded realtime ``current_hold`` pid run, quiet and beside the busy
  loops: the largest position error (norm) and attitude error after t = 8 s, from the
  bag's odometry.

Run ``.venv/bin/python bench/stress.py [--only short recorded realtime] [--busy 2]``;
the numbers go to ``--out`` (default ``runs/stress/stress.json``) and stdout.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
import json
import os
from pathlib import Path
import random
import re
import subprocess
import sys
import tempfile
import time
from typing import Any

import numpy as np

# Isolate DDS like the test suite does, before anything starts a node.
os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(102, 200)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

#: The series a recorded lockstep run shares with the headless runner.
SERIES = ('position', 'quaternion', 'nu', 'thrust', 'wrench_cmd', 'thrust_cmd', 'tilt_cmd',
          'wrench_achieved')
_STALL = re.compile(r'stall at ')


@contextmanager
def busy_loops(count: int) -> Iterator[None]:
    """``count`` CPU-bound processes for the duration of the block."""
    loops = [subprocess.Popen([sys.executable, '-c', 'while True: pass'])
             for _ in range(count)]
    try:
        yield
    finally:
        for loop in loops:
            loop.kill()
            loop.wait()


def _launch(*args: str, timeout: float = 1800.0) -> tuple[int, str, float]:
    start = time.perf_counter()
    result = subprocess.run([sys.executable, '-m', 'tiltrov_ros.cli', 'launch', *args],
                            capture_output=True, text=True, timeout=timeout,
                            cwd=tempfile.gettempdir())
    return result.returncode, result.stdout + result.stderr, time.perf_counter() - start


def short(tries: int) -> dict[str, Any]:
    """The short multi-process launch, ``tries`` times."""
    walls, stalls, codes = [], [], []
    for _ in range(tries):
        code, output, wall = _launch('--scenario', 'pitch_hold', '--duration', '0.1')
        walls.append(wall)
        codes.append(code)
        stalls.append(len(_STALL.findall(output)))
    return {'tries': tries, 'exit_codes': codes, 'stalled_runs': sum(s > 0 for s in stalls),
            'wall_s': walls, 'wall_median_s': float(np.median(walls)),
            'wall_max_s': float(np.max(walls))}


def _same_run(bag: Path, scenario: str, controller: str, duration: float) -> float:
    """The largest difference between the bag's run and the headless runner's."""
    from tiltrov_ros.bag.reader import read_runlog
    from tiltrov_ros.core.runner import run_scenario, stack_config

    recorded = read_runlog(bag)
    expected = run_scenario(stack_config(scenario, controller), duration=duration)
    worst = 0.0
    for name in SERIES:
        a, b = getattr(recorded, name), getattr(expected, name)
        if a.shape != b.shape:
            return float('inf')
        worst = max(worst, float(np.max(np.abs(a - b))))
    return worst


def recorded(runs: int, busy: int, duration: float = 120.0) -> dict[str, Any]:
    """Recorded lockstep ``current_hold`` pid runs beside ``busy`` loops."""
    from tiltrov_ros.bag.losses import missing_stamps

    rows = []
    with busy_loops(busy), tempfile.TemporaryDirectory() as tmp:
        for i in range(runs):
            bag = Path(tmp) / f'bag{i}'
            code, output, wall = _launch('--scenario', 'current_hold', '--controller', 'pid',
                                         '--duration', f'{duration:g}', '--record', str(bag))
            missing = (missing_stamps(bag, int(duration * 1e9), 10_000_000, 50_000_000)
                       if bag.exists() else {'(no bag)': 1})
            diff = _same_run(bag, 'current_hold', 'pid', duration) if code == 0 else float('nan')
            rtf = re.search(r'real-time factor ([0-9.]+)', output)
            rows.append({'exit_code': code, 'missing': missing, 'max_difference': diff,
                         'wall_s': wall, 'plant_rtf': float(rtf.group(1)) if rtf else None,
                         'stalls': len(_STALL.findall(output))})
    return {'runs': rows, 'busy_loops': busy, 'duration': duration}


def _tracking_errors(bag: Path, after: float = 8.0) -> tuple[float, float]:
    """Largest position error norm (m) and attitude error (rad, the largest of roll, pitch,
    yaw) after ``after`` s, against the scenario's setpoint (current_hold: hold the origin)."""
    from tiltrov_ros.bag.reader import read_runlog
    from tiltrov_ros.core.kinematics import euler_from_quat_rows

    log = read_runlog(bag)
    keep = log.t >= after
    position = np.linalg.norm(log.position[keep], axis=1)
    euler = euler_from_quat_rows(log.quaternion[keep])
    return float(position.max()), float(np.abs(euler).max())


def realtime(busy: int, duration: float = 30.0) -> dict[str, Any]:
    """A recorded realtime current_hold pid run, quiet and beside ``busy`` loops."""
    out = {}
    for label, loops in (('quiet', 0), (f'busy{busy}', busy)):
        with busy_loops(loops), tempfile.TemporaryDirectory() as tmp:
            bag = Path(tmp) / 'bag'
            code, _, wall = _launch('--scenario', 'current_hold', '--controller', 'pid',
                                    '--realtime', '--duration', f'{duration:g}',
                                    '--record', str(bag))
            position, attitude = _tracking_errors(bag) if bag.exists() else (np.nan, np.nan)
            out[label] = {'exit_code': code, 'max_position_error_m': position,
                          'max_attitude_error_deg': float(np.degrees(attitude)),
                          'wall_s': wall}
    return out


SECTIONS: dict[str, Callable[[argparse.Namespace], dict[str, Any]]] = {
    'short': lambda a: short(a.short_tries),
    'recorded': lambda a: recorded(a.recorded_runs, a.busy),
    'realtime': lambda a: realtime(a.busy),
}


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--only', nargs='+', choices=SECTIONS, default=list(SECTIONS))
    parser.add_argument('--busy', type=int, default=2, help='busy loops beside the loaded runs')
    parser.add_argument('--short-tries', type=int, default=20)
    parser.add_argument('--recorded-runs', type=int, default=5)
    parser.add_argument('--out', type=Path, default=Path('runs/stress/stress.json'))
    args = parser.parse_args(argv)
    results: dict[str, Any] = {}
    for name in args.only:
        started = time.perf_counter()
        results[name] = SECTIONS[name](args)
        results[name]['section_wall_s'] = time.perf_counter() - started
        print(f'{name}: {json.dumps(results[name], default=str)}', flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1, default=str) + '\n')
    print(f'written: {args.out}')
    return results


if __name__ == '__main__':
    main()
