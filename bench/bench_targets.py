"""The hot path's targets (not a test): every figure in a fresh process, compiled and reference.

``make bench`` prints this table. Each measure runs in its own process through
the public API or the CLI, once with the backend this machine has (the
compiled kernels when numba imports: core/jit.py) and once with
``TILTROV_BACKEND=numpy`` (the numpy reference); the table gives both, the
speed-up of the first over the second, the target and whether it is met.
The quick measures run in ``--repeat`` rounds (3), the two backends
interleaved so that a change of load hits both alike, and the table gives
the medians; lockstep, latency and the campaign run ``--slow-repeat`` times (1).
Construction (and so compiling or loading the kernels) is never timed, except
in the start-up section, which measures it: ``import numba``, ``tiltrov
warmup`` on an empty cache (cold) and again (warm), and each stack node's
constructor with a warm cache.

Whatever runs is measured: a part not compiled yet (the allocator before its
kernels land) shows a speed-up near 1. A measure that fails prints its error
in the table and the others go on.

::

    .venv/bin/python bench/bench_targets.py                    # everything (10-15 min)
    .venv/bin/python bench/bench_targets.py --only plant pid   # some measures
    .venv/bin/python bench/bench_targets.py --campaign-samples 20

``main()`` returns every number as a dict (``tiltrov bench targets --json F``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time
from typing import Any, NamedTuple

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
BACKEND_ENV = 'TILTROV_BACKEND'


class Row(NamedTuple):
    label: str
    measure: str          # the child measure that gives it
    key: str              # its number in the child's answer
    unit: str
    target: float
    lower_is_better: bool


ROWS = [
    Row('attainable allocation p99, family path included', 'allocation',
        'attainable_p99_us', 'us', 30.0, True),
    Row('unattainable allocation p99, with previous (7.5 deg)', 'allocation',
        'unattainable_previous_p99_us', 'us', 300.0, True),
    Row('unattainable allocation p99, without previous (full range)', 'allocation',
        'unattainable_first_p99_us', 'us', 600.0, True),
    Row('allocate_batch, attainable wrenches with previous', 'allocation', 'batch_per_s',
        '/s', 1e6, False),
    Row('plant step', 'plant', 'step_us', 'us', 3.0, True),
    Row('pid law', 'pid', 'update_us', 'us', 20.0, True),
    Row('headless loop RTF, current_hold (pid)', 'headless', 'current_hold_rtf', 'x', 150.0,
        False),
    Row('headless loop RTF, pitch_hold (pid)', 'headless', 'pitch_hold_rtf', 'x', 300.0, False),
    Row('lockstep trajectory RTF, separate processes', 'lockstep', 'separate_rtf', 'x', 30.0,
        False),
    Row('lockstep trajectory RTF, one process', 'lockstep', 'single_rtf', 'x', 60.0, False),
    Row('odom -> thrust_cmd p99, realtime pitch_hold, separate processes', 'latency',
        'separate_p99_ms', 'ms', 3.0, True),
    Row('odom -> thrust_cmd p99, realtime pitch_hold, one process', 'latency',
        'single_p99_ms', 'ms', 2.0, True),
    Row('allocator node, publish to publish p99 (separate processes)', 'latency',
        'allocator_p99_ms', 'ms', 0.5, True),
    Row('station-keeping campaign, 2 workers (wall)', 'campaign', 'wall_s', 's', 60.0, True),
    Row('short launch: pitch_hold 0.1 s, separate processes (wall)', 'stack',
        'short_launch_s', 's', 4.0, True),
    Row('recorded / unrecorded lockstep RTF (current_hold pid, 60 s)', 'stack',
        'recorded_ratio', 'x', 0.5, False),
    Row('recorded / unrecorded, --respawn: paced tick by tick', 'stack',
        'respawn_ratio', 'x', math.nan, False),
    Row('bag_recorder: messages written per second (flat out)', 'recorder',
        'written_per_s', '/s', 50_000.0, False),
]
MEASURES = ('allocation', 'plant', 'pid', 'headless', 'lockstep', 'latency', 'campaign',
            'stack', 'recorder')
#: Measures of minutes: run --slow-repeat times (default once) instead of --repeat.
SLOW = ('lockstep', 'latency', 'campaign', 'stack', 'recorder')


# --------------------------------------------------------------------------- child measures

def _median_of(repeats: int, fn: Any) -> float:
    return float(np.median([fn() for _ in range(repeats)]))


def _bench_module(name: str) -> Any:
    sys.path.insert(0, str(HERE))
    return __import__(name)


def measure_allocation(args: argparse.Namespace) -> dict[str, Any]:
    """bench_allocation's sets (with and without ``previous``), the attainable ticks of the
    pitch_hold pid loop (the family path), allocate_batch."""
    from tiltrov_ros.core.allocation import ThrustAllocator
    from tiltrov_ros.core.runner import run, stack_config
    from tiltrov_ros.core.thrust_map import thrust_wrench

    ba = _bench_module('bench_allocation')
    rng = np.random.default_rng(0)
    alloc = ThrustAllocator(ba.L, ba.D, ba.FMAX, max_tilt_step=ba.STEP)
    paper = ThrustAllocator(ba.L, ba.D, ba.FMAX, mode='paper')
    n = 400
    f = rng.uniform(-ba.FMAX, ba.FMAX, size=(n, 4))
    tilts = rng.uniform(-ba.HALF_PI, ba.HALF_PI, size=(n, 2))
    attainable = thrust_wrench(f, tilts[:, 0], tilts[:, 1], ba.L, ba.D)
    near = np.clip(tilts + rng.uniform(-ba.STEP, ba.STEP, size=(n, 2)), -ba.HALF_PI,
                   ba.HALF_PI)
    unattainable = ba._unattainable(rng, paper, 200)
    far = rng.uniform(-ba.HALF_PI, ba.HALF_PI, size=(len(unattainable), 2))

    def previous(t: np.ndarray) -> Any:
        return alloc.allocate_fixed(np.zeros(6), float(t[0]), float(t[1]))

    att = [(tau, previous(p)) for tau, p in zip(attainable, near)]
    un = [(tau, previous(p)) for tau, p in zip(unattainable, far)]
    us = 1e6
    out: dict[str, Any] = {
        'random_attainable_p99_us': float(np.percentile(
            ba._timed(lambda item: alloc.allocate(item[0], item[1]), att), 99) * us),
        'unattainable_previous_p99_us': float(np.percentile(
            ba._timed(lambda item: alloc.allocate(item[0], item[1]), un), 99) * us),
        'unattainable_first_p99_us': float(np.percentile(
            ba._timed(lambda tau: alloc.allocate(tau), unattainable), 99) * us)}

    class Timed:
        """The runner's allocator, each allocate() call timed (the loop's own calls)."""

        def __init__(self, inner: Any) -> None:
            self.inner, self.calls = inner, []

        def allocate(self, wrench: Any, previous: Any = None) -> Any:
            start = time.perf_counter()
            result = self.inner.allocate(wrench, previous=previous)
            self.calls.append((time.perf_counter() - start, bool(result.feasible)))
            return result

        def allocate_fixed(self, *a: Any, **k: Any) -> Any:
            return self.inner.allocate_fixed(*a, **k)

    for scenario in ('pitch_hold', 'current_hold'):
        config = stack_config(scenario, 'pid')
        timed = Timed(config.build_allocator())
        run(config.build_plant(), config.build_controller(), timed,
            config.scenario.reference.at, config.scenario.duration,
            control_period_ns=config.control_period_ns)
        for feasible, name in ((True, 'attainable'), (False, 'unattainable')):
            t = [s for s, ok in timed.calls if ok == feasible]
            out[f'{scenario}_loop_{name}_p99_us'] = (float(np.percentile(t, 99) * us) if t
                                                     else math.nan)
            out[f'{scenario}_loop_{name}_calls'] = len(t)
    out['attainable_p99_us'] = float(np.nanmax([out['random_attainable_p99_us'],
                                                out['pitch_hold_loop_attainable_p99_us']]))
    m = 100_000
    big_tilts = rng.uniform(-ba.HALF_PI, ba.HALF_PI, size=(m, 2))
    big = thrust_wrench(rng.uniform(-ba.FMAX, ba.FMAX, size=(m, 4)), big_tilts[:, 0],
                        big_tilts[:, 1], ba.L, ba.D)
    big_prev = np.clip(big_tilts + rng.uniform(-ba.STEP, ba.STEP, size=(m, 2)), -ba.HALF_PI,
                       ba.HALF_PI)
    alloc.allocate_batch(big[:100], big_prev[:100])

    def batch() -> float:
        start = time.perf_counter()
        alloc.allocate_batch(big, big_prev)
        return m / (time.perf_counter() - start)

    out['batch_per_s'] = _median_of(3, batch)
    return out


def measure_plant(args: argparse.Namespace) -> dict[str, Any]:
    """Plant.step() one call per step, as the node calls it."""
    from tiltrov_ros.core.disturbances import PAPER_COM_ERROR, Disturbances
    from tiltrov_ros.core.params import load_robot_params
    from tiltrov_ros.core.plant import Plant

    plant = Plant(load_robot_params(), Disturbances(com_error=PAPER_COM_ERROR,
                                                    current=(0.1, 0.05, 0.0)),
                  nu=(0.2, -0.1, 0.05, 0.1, -0.2, 0.05))
    plant.command([12.0, -8.0, 5.0, 10.0], [0.6, -0.3])
    steps = 2000

    def once() -> float:
        start = time.perf_counter()
        for _ in range(steps):
            plant.step()
        return (time.perf_counter() - start) / steps * 1e6

    once()
    return {'step_us': _median_of(5, once)}


def measure_pid(args: argparse.Namespace) -> dict[str, Any]:
    """PIDController.update() with odometry-shaped arrays, as the node and the runner call it."""
    from tiltrov_ros.core.controllers import Reference, load_controller_config, make_controller
    from tiltrov_ros.core.kinematics import quat_from_euler
    from tiltrov_ros.core.params import load_robot_params

    controller = make_controller(load_controller_config().with_kind('pid'), load_robot_params())
    rng = np.random.default_rng(1)
    states = [(rng.normal(size=3), quat_from_euler(*rng.uniform(-0.5, 0.5, 3)),
               rng.normal(size=6)) for _ in range(500)]
    reference = Reference(np.array([0.0, 0.0, 1.0]), quat_from_euler(0.0, -0.5, 0.0),
                          np.zeros(6))

    def once() -> float:
        start = time.perf_counter()
        for k, (p, q, nu) in enumerate(states):
            controller.update(0.05 * k, p, q, nu, reference)
        return (time.perf_counter() - start) / len(states) * 1e6

    once()
    return {'update_us': _median_of(5, once)}


def measure_headless(args: argparse.Namespace) -> dict[str, Any]:
    """runner.run of the whole scenario with pid, construction excluded (the loop only)."""
    from tiltrov_ros.core.runner import run, stack_config

    out: dict[str, Any] = {}
    for scenario in ('current_hold', 'pitch_hold'):
        config = stack_config(scenario, 'pid')

        def once(config: Any = config) -> float:
            plant, controller = config.build_plant(), config.build_controller()
            allocator = config.build_allocator()
            start = time.perf_counter()
            run(plant, controller, allocator, config.scenario.reference.at,
                config.scenario.duration, control_period_ns=config.control_period_ns,
                faults=config.scenario.faults, rebuild_allocator=config.build_allocator)
            return config.scenario.duration / (time.perf_counter() - start)

        out[f'{scenario}_rtf'] = once()
    return out


def measure_lockstep(args: argparse.Namespace) -> dict[str, Any]:
    """tiltrov launch of trajectory in lockstep: the plant's own real-time factor."""
    bl = _bench_module('bench_lockstep')
    out = {}
    for key, single in (('separate', False), ('single', True)):
        out[f'{key}_rtf'] = bl.lockstep('trajectory', None, single_process=single,
                                        executor='events')['rtf']
    return out


def measure_latency(args: argparse.Namespace) -> dict[str, Any]:
    """bench_lockstep's realtime pitch_hold latency run, separate processes and one."""
    bl = _bench_module('bench_lockstep')
    out: dict[str, Any] = {}
    for key, single in (('separate', False), ('single', True)):
        lat = bl.latency(args.latency_duration, 1.0, single_process=single)
        out.update({f'{key}_{k}': v for k, v in lat.items()})
    out['allocator_p99_ms'] = out['separate_allocator_p99_ms']
    return out


def measure_campaign(args: argparse.Namespace) -> dict[str, Any]:
    """tiltrov campaign of the shipped station-keeping file on 2 workers: the command's wall."""
    with tempfile.TemporaryDirectory() as tmp:
        argv = [sys.executable, '-m', 'tiltrov_ros.cli', 'campaign',
                str(REPO / 'config' / 'campaigns' / 'station_keeping.yaml'), '--samples',
                str(args.campaign_samples), '--workers', '2', '--out', str(Path(tmp) / 'c'),
                '--no-figures']
        start = time.perf_counter()
        result = subprocess.run(argv, capture_output=True, text=True, timeout=7200, cwd=tmp)
        wall = time.perf_counter() - start
    if result.returncode != 0:
        raise RuntimeError(f'tiltrov campaign failed: {result.stderr[-2000:]}')
    return {'wall_s': wall, 'samples': args.campaign_samples}


def measure_stack(args: argparse.Namespace) -> dict[str, Any]:
    """The whole stack's wall times: the short launch (process start, the handshake, the
    run, the stop; median of 3) and a 60 s current_hold pid run unrecorded, recorded (the
    recorder paces it, 1 s window) and recorded with --respawn (window 0): plant RTFs."""
    bl = _bench_module('bench_lockstep')
    walls = []
    for _ in range(3):
        start = time.perf_counter()
        result = subprocess.run([sys.executable, '-m', 'tiltrov_ros.cli', 'launch', '--scenario',
                                 'pitch_hold', '--duration', '0.1'], capture_output=True,
                                text=True, timeout=600, cwd=tempfile.gettempdir())
        walls.append(time.perf_counter() - start)
        if result.returncode != 0:
            raise RuntimeError(f'the short launch failed: {result.stdout[-2000:]}')
    out: dict[str, Any] = {'short_launch_s': float(np.median(walls))}
    runs = {'unrecorded': (), 'recorded': ('--record',), 'respawn': ('--record', '--respawn',
                                                                     'thrust_allocator')}
    for key, extra in runs.items():
        with tempfile.TemporaryDirectory() as tmp:
            args_ = [a if a != '--record' else f'--record={Path(tmp) / "bag"}' for a in extra]
            out[f'{key}_rtf'] = bl.lockstep('current_hold', 60.0, single_process=False,
                                            executor='events', controller='pid',
                                            extra=tuple(args_))['rtf']
    out['recorded_ratio'] = out['recorded_rtf'] / out['unrecorded_rtf']
    out['respawn_ratio'] = out['respawn_rtf'] / out['unrecorded_rtf']
    return out


def measure_recorder(args: argparse.Namespace) -> dict[str, Any]:
    """bag_recorder fed flat out by a KEEP_ALL publisher process (bench_recorder)."""
    br = _bench_module('bench_recorder')
    with tempfile.TemporaryDirectory() as tmp:
        got = br.bench_recorder(60_000, 0, 0.0, Path(tmp) / 'bag')
    return {'written_per_s': got['rate'], 'lost': got['lost']}


def measure_node(args: argparse.Namespace) -> dict[str, Any]:
    """One stack node's constructor (shipped parameters) and its kernel warm-up, s."""
    import rclpy
    from rclpy.context import Context

    from tiltrov_ros.stack.inprocess import build_node
    from tiltrov_ros.stack.specs import LaunchOptions, stack_specs

    specs, _, _ = stack_specs(LaunchOptions(scenario='pitch_hold', controller='pid'))
    spec = next(s for s in specs if s.name == args.node)
    context = Context()
    rclpy.init(context=context)
    start = time.perf_counter()
    node = build_node(spec, context)
    out = {'construct_s': time.perf_counter() - start, 'warmup_s': node.kernel_warmup}
    node.destroy_node()
    rclpy.try_shutdown(context=context)
    return out


CHILDREN = {'allocation': measure_allocation, 'plant': measure_plant, 'pid': measure_pid,
            'headless': measure_headless, 'lockstep': measure_lockstep,
            'latency': measure_latency, 'campaign': measure_campaign, 'stack': measure_stack,
            'recorder': measure_recorder, 'node': measure_node}


# --------------------------------------------------------------------------- the parent

def _child(measure: str, backend: str | None, args: argparse.Namespace,
           env: dict[str, str] | None = None, extra: tuple[str, ...] = ()) -> dict[str, Any]:
    """One measure in a fresh process; ``backend`` None: this machine's default."""
    child_env = dict(os.environ if env is None else env)
    child_env.pop(BACKEND_ENV, None)
    if backend is not None:
        child_env[BACKEND_ENV] = backend
    argv = [sys.executable, str(Path(__file__).resolve()), '--child', measure,
            '--latency-duration', str(args.latency_duration),
            '--campaign-samples', str(args.campaign_samples), *extra]
    start = time.perf_counter()
    result = subprocess.run(argv, capture_output=True, text=True, env=child_env, timeout=7200,
                            cwd=tempfile.gettempdir())
    wall = time.perf_counter() - start
    lines = result.stdout.strip().splitlines()
    if result.returncode != 0 or not lines:
        error = (result.stderr.strip().splitlines() or ['no output'])[-1]
        return {'error': error[:200], 'process_s': wall}
    answer: dict[str, Any] = json.loads(lines[-1])
    answer['process_s'] = wall
    return answer


def _median_answer(answers: list[dict[str, Any]]) -> dict[str, Any]:
    """Per number, the median over the rounds that did not fail (an error if all did)."""
    good = [a for a in answers if 'error' not in a]
    if not good:
        return answers[-1]
    out: dict[str, Any] = {}
    for key in good[0]:
        values = [a[key] for a in good if isinstance(a.get(key), (int, float))]
        out[key] = float(np.median(values)) if values else good[0][key]
    out['rounds'] = len(good)
    return out


def _startup(args: argparse.Namespace) -> dict[str, Any]:
    """import numba, tiltrov warmup cold and warm, each stack node's constructor (warm)."""
    out: dict[str, Any] = {}
    code = 'import time; t = time.perf_counter(); import numba; print(time.perf_counter() - t)'
    times = []
    for _ in range(3):
        r = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
        if r.returncode != 0:
            return {'error': 'numba does not import: no compiled kernels here'}
        times.append(float(r.stdout))
    out['import_numba_s'] = float(np.median(times))
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, 'NUMBA_CACHE_DIR': cache}
        env.pop(BACKEND_ENV, None)
        for kind in ('cold', 'warm'):
            r = subprocess.run([sys.executable, '-m', 'tiltrov_ros.cli', 'warmup'],
                               capture_output=True, text=True, env=env, timeout=3600)
            for line in r.stdout.splitlines():
                parts = line.split()
                if len(parts) >= 3 and parts[2] == 's' and parts[0] != 'cache:':
                    out[f'warmup_{kind}_{parts[0]}_s'] = float(parts[1])
    for node in ('plant_simulator', 'wrench_controller', 'thrust_allocator',
                 'reference_publisher'):
        answer = _child('node', None, args, extra=('--node', node))
        for key, value in answer.items():
            out[f'node_{node}_{key}'] = value
    return out


def _fmt(value: float, unit: str) -> str:
    if not isinstance(value, (int, float)) or math.isnan(value):
        return '-'
    if unit == '/s':
        return f'{value:,.0f}/s'
    if unit == 'x':
        return f'{value:.1f}'
    return f'{value:.3g} {unit}' if value < 10 else f'{value:.0f} {unit}'


def table(results: dict[str, dict[str, Any]]) -> list[str]:
    """The Markdown table of :data:`ROWS` from the measures' answers."""
    lines = ['| measure | target | compiled | numpy reference | speed-up | met |',
             '|---|---|---|---|---|---|']
    for row in ROWS:
        if f'{row.measure}:default' not in results:
            continue
        fast = results[f'{row.measure}:default']
        ref = results.get(f'{row.measure}:numpy', {})
        value, base = fast.get(row.key, math.nan), ref.get(row.key, math.nan)
        unit = '' if row.unit == 'x' else row.unit
        target = ('(reported)' if math.isnan(row.target) else
                  f'{"<=" if row.lower_is_better else ">="} '
                  f'{_fmt(row.target, row.unit) if unit == "/s" else f"{row.target:g} {unit}"}')
        if 'error' in fast:
            lines.append(f'| {row.label} | {target} | failed: {fast["error"]} | '
                         f'{_fmt(base, row.unit)} | - | - |')
            continue
        speedup = (base / value if row.lower_is_better else value / base) \
            if value and base else math.nan
        met = '-' if math.isnan(value) or math.isnan(row.target) else (
            'yes' if (value <= row.target if row.lower_is_better else value >= row.target)
            else 'no')
        lines.append(f'| {row.label} | {target} | {_fmt(value, row.unit)} | '
                     f'{_fmt(base, row.unit)} | '
                     f'{"-" if math.isnan(speedup) else f"{speedup:.1f}x"} | {met} |')
    return lines


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--only', nargs='+', choices=(*MEASURES, 'startup'),
                        help='these measures only (default: all, and the start-up section)')
    parser.add_argument('--repeat', type=int, default=3,
                        help='rounds of each quick measure, both backends interleaved, a fresh '
                             'process each; medians (default 3)')
    parser.add_argument('--slow-repeat', type=int, default=1,
                        help='rounds of lockstep, latency and the campaign (default 1)')
    parser.add_argument('--latency-duration', type=float, default=20.0,
                        help='sim seconds of each realtime latency run (default 20)')
    parser.add_argument('--campaign-samples', type=int, default=200,
                        help='samples of the station-keeping campaign (x pd, pid runs)')
    parser.add_argument('--child', choices=tuple(CHILDREN), help=argparse.SUPPRESS)
    parser.add_argument('--node', help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if args.child:
        print(json.dumps(CHILDREN[args.child](args), default=float))
        return {}

    wanted = args.only or [*MEASURES, 'startup']
    results: dict[str, dict[str, Any]] = {}
    load = os.getloadavg()
    for measure in (m for m in MEASURES if m in wanted):
        rounds = args.slow_repeat if measure in SLOW else args.repeat
        answers: dict[str, list[dict[str, Any]]] = {'default': [], 'numpy': []}
        for k in range(rounds):     # interleaved: a change of load hits both alike
            for backend, label in ((None, 'default'), ('numpy', 'numpy')):
                print(f'  {measure} ({label}, round {k + 1} of {rounds}) ...',
                      file=sys.stderr, flush=True)
                answers[label].append(_child(measure, backend, args))
        for label, got in answers.items():
            results[f'{measure}:{label}'] = _median_answer(got)
    info = subprocess.run([sys.executable, '-c', 'from tiltrov_ros.core import jit; '
                           'import json; print(json.dumps(jit.describe()))'],
                          capture_output=True, text=True)
    described = json.loads(info.stdout) if info.returncode == 0 else {}
    print(f'hot-path targets: compiled = backend {described.get("backend", "?")} '
          f'({described.get("reason", "")}), numpy reference = {BACKEND_ENV}=numpy; '
          f'{os.cpu_count()} cores, load average {load[0]:.2f} at start, '
          f'{os.getloadavg()[0]:.2f} at the end')
    if results:
        for line in table(results):
            print(line)
    if 'startup' in wanted:
        start = _startup(args)
        results['startup'] = start
        print('start-up (compiled kernels):')
        for key, value in start.items():
            print(f'  {key:48s} {value if isinstance(value, str) else f"{value:.3f}"}')
    flat: dict[str, Any] = {'describe': described}
    for name, answer in results.items():
        flat.update({f'{name}.{k}': v for k, v in answer.items()})
    return flat


if __name__ == '__main__':
    main()
