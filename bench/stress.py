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
  bag's odometry;
* ``replay``: how closely ``tiltrov replay``'s player keeps its schedule, quiet and
  beside the busy loops (the residuals' median and 90th percentile);
* ``restarts``: per launch path (``tiltrov launch --respawn``, and ``ros2 launch
  respawn:=`` where the ros2 command line is installed: the package colcon-built in a
  temporary workspace), the allocator killed about 10 s and the controller about 17 s
  into a recorded realtime ``current_hold`` pid run, ``--restart-tries`` times quiet and
  beside the busy loops, each with the same run without kills: its errors after t = 8 s
  against that run's (the bound: + 50 mm, + 3 deg), and the longest time without a new
  ``thrust_cmd`` (the takeovers' gap in the commands); and ``--lockstep-kills`` recorded
  120 s lockstep runs with both killed at seeded random sim times: the largest
  difference from the headless run without kills (the contract: 0) and steps or ticks
  missing from the bag.

Run ``.venv/bin/python bench/stress.py [--only short recorded realtime restarts]
[--busy 2]``; the numbers go to ``--out`` (default ``runs/stress/stress.json``) and
stdout.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
import json
import math
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
    yaw) after ``after`` s, against the scenario's setpoint (current_hold: hold the origin);
    NaN for a bag that is missing or cannot be read (a run that lost it: reported as such,
    never within the bound)."""
    from tiltrov_ros.bag.reader import read_runlog
    from tiltrov_ros.core.errors import TiltrovError
    from tiltrov_ros.core.kinematics import euler_from_quat_rows

    try:
        log = read_runlog(bag)
    except (TiltrovError, OSError):
        return math.nan, math.nan
    keep = log.t >= after
    position = np.linalg.norm(log.position[keep], axis=1)
    euler = euler_from_quat_rows(log.quaternion[keep])
    return float(position.max()), float(np.abs(euler).max())


def _command_gap(bag: Path, after: float = 8.0, topic: str = '/thrust_cmd') -> float:
    """The longest time (s of log time, which is sim time) between two ``topic`` messages
    after ``after`` s: in a realtime restart run, how long the plant went without a new
    command while a node was taken over (NaN for a bag that cannot be read)."""
    from rosbags.rosbag2 import Reader

    try:
        with Reader(bag) as reader:
            connections = [c for c in reader.connections if c.topic == topic]
            times = np.array([t for _, t, _ in reader.messages(connections=connections)],
                             dtype=np.int64)
    except Exception:
        return math.nan
    times = times[times >= after * 1e9]
    return float(np.diff(times).max() / 1e9) if len(times) > 1 else math.nan


def realtime(busy: int, duration: float = 30.0) -> dict[str, Any]:
    """A recorded realtime current_hold pid run, quiet and beside ``busy`` loops."""
    out = {}
    for label, loops in (('quiet', 0), (f'busy{busy}', busy)):
        with busy_loops(loops), tempfile.TemporaryDirectory() as tmp:
            bag = Path(tmp) / 'bag'
            code, _, wall = _launch('--scenario', 'current_hold', '--controller', 'pid',
                                    '--realtime', '--duration', f'{duration:g}',
                                    '--record', str(bag))
            position, attitude = _tracking_errors(bag)
            out[label] = {'exit_code': code, 'max_position_error_m': position,
                          'max_attitude_error_deg': float(np.degrees(attitude)),
                          'wall_s': wall}
    return out


# --------------------------------------------------------------------------- restarts

RUN = ('--scenario', 'current_hold', '--controller', 'pid')
VICTIMS = ('thrust_allocator', 'wrench_controller')


def _workspace(root: Path) -> dict[str, str] | None:
    """The environment of the package colcon-built in ``root`` (None: no ros2 launch)."""
    import shutil

    if shutil.which('ros2') is None and not Path(sys.executable).with_name('ros2').exists():
        return None
    repo = Path(__file__).resolve().parent.parent
    shutil.copytree(repo, root / 'src' / 'tiltrov_ros', ignore=shutil.ignore_patterns(
        '.venv', '.git', 'build', 'install', 'log', 'runs', '__pycache__', '*.egg-info'))
    env = dict(os.environ, PATH=os.pathsep.join([str(Path(sys.executable).parent),
                                                os.environ.get('PATH', '')]))
    colcon = shutil.which('colcon') or str(Path(sys.executable).with_name('colcon'))
    if subprocess.run([colcon, 'build'], cwd=root, env=env, capture_output=True).returncode:
        return None
    sourced = subprocess.run(['bash', '-c', 'source install/setup.bash && env -0'], cwd=root,
                             env=env, capture_output=True, text=True, check=True)
    env = dict(line.split('=', 1) for line in sourced.stdout.split('\0') if '=' in line)
    env['AMENT_PREFIX_PATH'] = os.pathsep.join(
        [*filter(None, env.get('AMENT_PREFIX_PATH', '').split(os.pathsep)), sys.prefix])
    return env


def _start(path: str, bag: Path, extra: Sequence[str], kills: bool, env: dict[str, str] | None,
           cwd: Path) -> subprocess.Popen[str]:
    if path == 'tiltrov launch':
        respawn = [a for v in VICTIMS for a in ('--respawn', v)] if kills else []
        argv = [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', *RUN, *extra, *respawn,
                '--record', str(bag), '--status-file', str(cwd / 'status.json')]
    else:
        mode = 'mode:=realtime' if '--realtime' in extra else 'mode:=lockstep'
        duration = extra[extra.index('--duration') + 1]
        argv = [str(Path(sys.executable).with_name('ros2')), 'launch', 'tiltrov_ros',
                'tiltrov.launch.py', 'scenario:=current_hold', 'controller:=pid', mode,
                f'duration:={duration}', f'record:={bag}',
                *((f'respawn:={",".join(VICTIMS)}',) if kills else ())]
    log = (cwd / 'launch.log').open('w')
    return subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, text=True, env=env,
                            cwd=cwd, start_new_session=True)


def _pid_of(path: str, victim: str, cwd: Path) -> int | None:
    if path == 'tiltrov launch':
        try:
            return int(json.loads((cwd / 'status.json').read_text())['nodes'][victim]['pid'])
        except (OSError, KeyError, ValueError):
            return None
    found = re.search(rf'\[{victim}-\d+\]: process started with pid \[(\d+)\]',
                      (cwd / 'launch.log').read_text())
    return int(found[1]) if found else None


def _run_with_kills(path: str, extra: Sequence[str], kill_at: Sequence[float],
                    env: dict[str, str] | None, tmp: Path) -> tuple[int, Path, str]:
    """One recorded run, the victims killed when the sim time reaches ``kill_at`` (none
    when empty): exit code, bag, output."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from tiltrov_ros.core.timebase import NS_PER_S
    from tiltrov_ros.nodes.conversions import stamp_ns

    cwd = Path(tempfile.mkdtemp(dir=tmp))
    bag = cwd / 'bag'
    proc = _start(path, bag, extra, bool(kill_at), env, cwd)
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('stress_sim_time', context=context)
    now = [-1]
    from nav_msgs.msg import Odometry
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    node.create_subscription(Odometry, 'odom', lambda m: now.__setitem__(
        0, stamp_ns(m.header.stamp)), QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    try:
        for victim, at in zip(VICTIMS, kill_at):
            while now[0] < at * NS_PER_S and proc.poll() is None:
                executor.spin_once(timeout_sec=0.05)
            pid = _pid_of(path, victim, cwd)
            if pid is not None and proc.poll() is None:
                os.kill(pid, 9)
        code = proc.wait(timeout=1800)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, 9)
            proc.wait()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return code, bag, (cwd / 'launch.log').read_text()


def restarts(tries: int, lockstep_kills: int, busy: int, seed: int = 2026) -> dict[str, Any]:
    """See the module docstring (``tries`` 0: no realtime runs; ``lockstep_kills`` 0: no
    lockstep ones)."""
    from tiltrov_ros.bag.losses import missing_stamps

    rng = np.random.default_rng(seed)
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp_dir:
        tmp = Path(tmp_dir)
        paths: dict[str, dict[str, str] | None] = {'tiltrov launch': None}
        ws = _workspace(tmp / 'ws')
        if ws is not None:
            paths['ros2 launch'] = ws
        for path, env in paths.items():
            rows: dict[str, Any] = {}
            for label, loops in (('quiet', 0), (f'busy{busy}', busy)) if tries else ():
                with busy_loops(loops):
                    realtime_args = ('--realtime', '--duration', '30')
                    code, bag, _ = _run_with_kills(path, realtime_args, (), env, tmp)
                    base = _tracking_errors(bag)
                    base_gap = _command_gap(bag)
                    tries_out = []
                    for _ in range(tries):
                        code, bag, log = _run_with_kills(path, realtime_args, (10.0, 17.0),
                                                         env, tmp)
                        errors = _tracking_errors(bag)
                        tries_out.append({
                            'exit_code': code, 'position_m': errors[0],
                            'attitude_deg': float(np.degrees(errors[1])),
                            'within_bound': bool(errors[0] <= base[0] + 0.05 and np.degrees(
                                errors[1]) <= np.degrees(base[1]) + 3.0),
                            'takeovers': log.count(': taking over ('),
                            'command_gap_s': _command_gap(bag)})
                    rows[label] = {'without_kills': {'position_m': base[0],
                                                     'attitude_deg': float(np.degrees(base[1])),
                                                     'command_gap_s': base_gap},
                                   'with_kills': tries_out}
            lock = []
            for _ in range(lockstep_kills):
                kill_at = sorted(float(t) for t in rng.uniform(5.0, 100.0, 2))
                code, bag, log = _run_with_kills(path, ('--duration', '120'), kill_at, env, tmp)
                lock.append({
                    'kill_at': kill_at, 'exit_code': code,
                    'max_difference': (_same_run(bag, 'current_hold', 'pid', 120.0)
                                       if code == 0 else float('nan')),
                    'missing': missing_stamps(bag, 120 * 10**9, 10**7, 5 * 10**7)
                    if bag.exists() else {'(no bag)': 1}})
            rows['lockstep'] = lock
            out[path] = rows
    return out


def replay(busy: int) -> dict[str, Any]:
    """How closely a replay keeps its schedule: a recorded 4 s lockstep run replayed at
    rate 2 by stamp, in this process (its reader matches the player on both sides at once),
    quiet and beside the busy loops: the residuals of the reception times from the
    schedule (s), median and 90th percentile."""
    import threading

    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile

    from tiltrov_ros.bag.msgdefs import message_class
    from tiltrov_ros.bag.replay import Player, ReplayOptions
    from tiltrov_ros.core.timebase import cdr_stamp_ns

    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / 'bag'
        code, output, _ = _launch('--duration', '4', '--record', str(bag))
        if code != 0:
            return {'error': output[-500:]}
        for label, loops in (('quiet', 0), (f'busy{busy}', busy)):
            context = Context()
            rclpy.init(context=context)
            node = rclpy.create_node('stress_replay', context=context)
            got: list[tuple[int, int]] = []
            node.create_subscription(message_class('nav_msgs/msg/Odometry'), '/odom',
                                     lambda data, info, got=got: got.append(
                                         (cdr_stamp_ns(data), int(info['received_timestamp']))),
                                     QoSProfile(depth=1000), raw=True)
            player = Player(str(bag), rclpy.create_node('stress_player', context=context),
                            ReplayOptions(rate=2.0, by_stamp=True, topics=['odom']))
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(node)
            with busy_loops(loops):
                thread = threading.Thread(target=player.run, daemon=True)
                thread.start()
                deadline = time.monotonic() + 60
                while thread.is_alive() and time.monotonic() < deadline:
                    executor.spin_once(timeout_sec=0.01)
                for _ in range(50):
                    executor.spin_once(timeout_sec=0.01)
            executor.shutdown()
            rclpy.try_shutdown(context=context)
            stamps = np.array([s for s, _ in got], dtype=float) / 1e9 / 2.0
            wall = np.array([w for _, w in got], dtype=float) / 1e9
            residual = (wall - wall.min()) - (stamps - stamps.min())
            residual -= np.median(residual)
            out[label] = {'messages': len(got),
                          'median_ms': float(np.median(np.abs(residual)) * 1e3),
                          'p90_ms': float(np.percentile(np.abs(residual), 90) * 1e3)}
    return out


SECTIONS: dict[str, Callable[[argparse.Namespace], dict[str, Any]]] = {
    'short': lambda a: short(a.short_tries),
    'recorded': lambda a: recorded(a.recorded_runs, a.busy),
    'realtime': lambda a: realtime(a.busy),
    'restarts': lambda a: restarts(a.restart_tries, a.lockstep_kills, a.busy),
    'restarts_realtime': lambda a: restarts(a.restart_tries, 0, a.busy),
    'restarts_lockstep': lambda a: restarts(0, a.lockstep_kills, a.busy),
    'replay': lambda a: replay(a.busy),
}


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--only', nargs='+', choices=SECTIONS,
                        default=['short', 'recorded', 'realtime', 'replay', 'restarts'])
    parser.add_argument('--busy', type=int, default=2, help='busy loops beside the loaded runs')
    parser.add_argument('--short-tries', type=int, default=20)
    parser.add_argument('--recorded-runs', type=int, default=5)
    parser.add_argument('--restart-tries', type=int, default=5)
    parser.add_argument('--lockstep-kills', type=int, default=10)
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
