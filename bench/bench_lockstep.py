"""Benchmark of the ROS stack (not a test): lockstep speed and realtime latency.

Measured in one run, so the ratios hold on any machine:

* the real-time factor of ``run_scenario`` (the headless runner, what
  ``tiltrov sim`` runs) on the scenario, the baseline;
* the real-time factor of the same scenario through ``tiltrov launch`` in
  lockstep, every node its own process and, with ``--single-process``, all in
  one (per executor asked for). It is the plant's own figure: sim time over
  the wall time from its initial state to the end (process start-up and
  discovery excluded; the total wall time of the launch is reported too);
* the same without ``robot_markers`` (``--no-markers``), separate processes and
  single process: what the plant's markers cost lockstep (``--repeat N``: N
  interleaved runs of each kind, medians);
* the odom -> thrust_cmd latency in realtime mode, separate processes and
  single process: for each control tick, the time between a probe receiving the ``odom`` stamped
  t_i and the ``thrust_cmd`` stamped t_i (both DDS reception times in the
  probe's process), median and 99th percentile.

Aims: RTF >= 10 with separate processes, >= 20 in a single process;
latency < 2 ms at the 99th percentile.

Run ``python bench/bench_lockstep.py`` (about a minute); ``main()`` returns the
numbers as a dict and prints a table.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

import numpy as np

from tiltrov_ros.core.runner import run_scenario, stack_config

_END = re.compile(r'reached the end of the run at ([0-9.]+) s: ([0-9.]+) s wall since the '
                  r'initial state, real-time factor ([0-9.]+)')


def headless(scenario: str, duration: float | None) -> dict[str, float]:
    config = stack_config(scenario)
    sim = config.scenario.duration if duration is None else duration
    start = time.perf_counter()
    run_scenario(config, duration=sim)
    wall = time.perf_counter() - start
    return {'sim': sim, 'wall': wall, 'rtf': sim / wall}


def _launch_argv(*args: str) -> list[str]:
    return [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', *args]


def lockstep(scenario: str, duration: float | None, *, single_process: bool,
             executor: str, markers: bool = True, controller: str | None = None,
             extra: tuple[str, ...] = ()) -> dict[str, float]:
    """One ``tiltrov launch`` in lockstep (``extra`` arguments added); the plant's
    real-time factor."""
    args = ['--scenario', scenario, '--executor', executor, *extra]
    if controller is not None:
        args += ['--controller', controller]
    if not markers:
        args.append('--no-markers')
    if duration is not None:
        args += ['--duration', repr(float(duration))]
    if single_process:
        args.append('--single-process')
    start = time.perf_counter()
    result = subprocess.run(_launch_argv(*args), capture_output=True, text=True,
                            timeout=3600, cwd=tempfile.gettempdir())
    total = time.perf_counter() - start
    output = result.stdout + result.stderr
    match = _END.search(output)
    if result.returncode != 0 or match is None:
        raise RuntimeError(f'tiltrov launch {" ".join(args)} failed:\n{output[-3000:]}')
    sim, wall, rtf = (float(g) for g in match.groups())
    return {'sim': sim, 'wall': wall, 'rtf': rtf, 'total_wall': total}


def latency(seconds_of_sim: float, real_time_factor: float,
            single_process: bool = False) -> dict[str, float]:
    """odom -> thrust_cmd latency (ms) in realtime mode.

    Headline: probe reception of ``thrust_cmd`` stamped t_i minus probe
    reception of ``odom`` stamped t_i. Breakdown from the writers' source
    timestamps (publish to publish): odom -> wrench_cmd (controller) and
    wrench_cmd -> thrust_cmd (allocator).
    """
    from geometry_msgs.msg import WrenchStamped
    from nav_msgs.msg import Odometry
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState

    from tiltrov_ros.cli.launch import add_arguments, options_from_args
    from tiltrov_ros.core.names import ODOM, THRUST_CMD, WRENCH_CMD
    from tiltrov_ros.nodes.conversions import stamp_ns
    from tiltrov_ros.nodes.handshake import Handshake
    from tiltrov_ros.stack.specs import run_node_names

    args = ['--scenario', 'pitch_hold', '--realtime', '--real-time-factor',
            repr(float(real_time_factor)), '--duration', repr(seconds_of_sim),
            # The probe joins the run's handshake: time starts once it has matched the
            # stack's writers and they have matched it, seen from both sides.
            '--join', 'latency_probe']
    if single_process:
        args.append('--single-process')
    # topic -> stamp -> (source timestamp, reception timestamp), ns
    times: dict[str, dict[int, tuple[int, int]]] = {'odom': {}, 'wrench': {}, 'thrust': {}}

    def keep(kind: str):
        def callback(msg: Any, info: Any) -> None:
            times[kind].setdefault(stamp_ns(msg.header.stamp),
                                   (int(info['source_timestamp']),
                                    int(info['received_timestamp'])))
        return callback

    launch = subprocess.Popen(_launch_argv(*args), stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, cwd=tempfile.gettempdir())
    lines: list[str] = []
    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('latency_probe', context=context)
    qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_ALL)
    node.create_subscription(WrenchStamped, WRENCH_CMD, keep('wrench'), qos)
    node.create_subscription(JointState, THRUST_CMD, keep('thrust'), qos)
    node.create_subscription(Odometry, ODOM, keep('odom'), qos)
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    Handshake(node, run_node_names(options_from_args(parser.parse_args(args)))).start()
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    reader = threading.Thread(target=lambda: lines.extend(launch.stdout or ()), daemon=True)
    reader.start()
    try:
        while launch.poll() is None:
            executor.spin_once(timeout_sec=0.05)
        reader.join(timeout=5.0)
        output = ''.join(lines)
        if launch.returncode != 0:
            raise RuntimeError(f'realtime launch failed:\n{output[-3000:]}')
        deadline = time.monotonic() + 0.2
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.02)
    finally:
        if launch.poll() is None:
            launch.kill()
            launch.wait()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    odom, wrench, thrust = times['odom'], times['wrench'], times['thrust']
    samples = np.array([(thrust[t][1] - odom[t][1]) / 1e6 for t in thrust if t in odom])
    if samples.size == 0:
        raise RuntimeError(f'no odom/thrust_cmd pair was received ({len(odom)} odom, '
                           f'{len(thrust)} thrust_cmd)')
    controller = [(wrench[t][0] - odom[t][0]) / 1e6 for t in wrench if t in odom]
    allocator = [(thrust[t][0] - wrench[t][0]) / 1e6 for t in thrust if t in wrench]
    return {'samples': float(samples.size), 'median_ms': float(np.median(samples)),
            'p99_ms': float(np.percentile(samples, 99)), 'max_ms': float(samples.max()),
            'controller_median_ms': float(np.median(controller)) if controller else math.nan,
            'allocator_median_ms': float(np.median(allocator)) if allocator else math.nan,
            'controller_p99_ms': (float(np.percentile(controller, 99)) if controller
                                  else math.nan),
            'allocator_p99_ms': (float(np.percentile(allocator, 99)) if allocator
                                 else math.nan)}


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scenario', default='trajectory')
    parser.add_argument('--duration', type=float, default=None,
                        help="sim seconds (default: the scenario's, 120 s for trajectory)")
    parser.add_argument('--executors', default='events',
                        help='comma-separated executors for the single-process runs '
                             '(events, single, multi; default: events)')
    parser.add_argument('--repeat', type=int, default=1,
                        help='lockstep runs of each kind, interleaved; medians reported')
    parser.add_argument('--latency-duration', type=float, default=20.0,
                        help='sim seconds of the realtime latency run (default 20)')
    parser.add_argument('--latency-rtf', type=float, default=1.0)
    parser.add_argument('--latency-runs', default='separate,single',
                        help='comma-separated: separate (processes), single (process); '
                             'empty: no latency run')
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')

    out: dict[str, float] = {}
    rows: list[tuple[str, str, str, str]] = []
    base = headless(args.scenario, args.duration)
    out.update(headless_wall=base['wall'], headless_rtf=base['rtf'])
    rows.append(('run_scenario (headless)', f"{base['wall']:.2f}", f"{base['rtf']:.1f}", '1.00'))
    runs = [('separate processes', False, 'events', True)]
    runs += [(f'--single-process ({kind})', True, kind, True)
             for kind in args.executors.split(',') if kind]
    runs += [('separate processes, --no-markers', False, 'events', False),
             ('--single-process (events), --no-markers', True, 'events', False)]
    measured: dict[str, list[dict[str, float]]] = {}
    for _ in range(args.repeat):        # interleaved, so a change of load hits all alike
        for label, single, kind, markers in runs:
            measured.setdefault(label, []).append(lockstep(
                args.scenario, args.duration, single_process=single, executor=kind,
                markers=markers))
    for label, single, kind, markers in runs:
        r = {k: float(np.median([m[k] for m in measured[label]]))
             for k in measured[label][0]}
        key = 'single_process' if single else 'separate'
        if single and kind != 'events':
            key += f'_{kind}'
        if not markers:
            key += '_no_markers'
        out.update({f'{key}_wall': r['wall'], f'{key}_rtf': r['rtf'],
                    f'{key}_total_wall': r['total_wall']})
        rows.append((f'lockstep, {label}', f"{r['wall']:.2f} ({r['total_wall']:.2f})",
                     f"{r['rtf']:.1f}", f"{r['rtf'] / base['rtf']:.2f}"))
    for key in ('separate', 'single_process'):
        # > 1: lockstep is that much faster without the plant's robot_markers.
        out[f'{key}_markers_cost'] = out[f'{key}_no_markers_rtf'] / out[f'{key}_rtf']
    sim = base['sim']
    print(f'{args.scenario}: {sim:g} s of sim time')
    print(f"{'run':<46} {'wall s (launch)':>16} {'RTF':>7} {'/headless':>10}")
    for row in rows:
        print(f'{row[0]:<46} {row[1]:>16} {row[2]:>7} {row[3]:>10}')
    print(f"robot_markers cost (RTF without / with): separate processes "
          f"{out['separate_markers_cost']:.2f}, single process "
          f"{out['single_process_markers_cost']:.2f}")
    runs_wanted = {r for r in args.latency_runs.split(',') if r}
    if runs_wanted - {'separate', 'single'}:
        parser.error(f'--latency-runs: unknown {sorted(runs_wanted - {"separate", "single"})}')
    for label, single in (('separate processes', False), ('--single-process', True)):
        if ('single' if single else 'separate') in runs_wanted:
            lat = latency(args.latency_duration, args.latency_rtf, single_process=single)
            prefix = 'latency_single_process_' if single else 'latency_'
            out.update({f'{prefix}{k}': v for k, v in lat.items()})
            print(f"odom -> thrust_cmd, realtime x{args.latency_rtf:g}, {label}: "
                  f"median {lat['median_ms']:.2f} ms, p99 {lat['p99_ms']:.2f} ms, "
                  f"max {lat['max_ms']:.2f} ms ({lat['samples']:.0f} ticks); publish to "
                  f"publish: controller {lat['controller_median_ms']:.2f} ms, allocator "
                  f"{lat['allocator_median_ms']:.2f} ms (medians)")
    return out


if __name__ == '__main__':
    main()
