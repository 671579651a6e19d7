"""How many messages per second bag_recorder records without losing any.

Cases, all with the stack's message mix (per 50 ms of sim time: 5 odom, 5
joint_states, 5 /clock and one each of setpoint, setpoint_velocity,
wrench_cmd, thrust_cmd, tilt_cmd, wrench_achieved), pre-serialized:

* baseline: the same messages written straight to a bag with rosbags' Writer,
  no ROS at all (the ceiling for anything that writes with rosbags);
* BagWriter: the recorder's writer, no ROS;
* the recorder node (in this process) fed by a publisher process publishing
  as fast as it can with KEEP_ALL reliable QoS, so DDS flow control paces the
  publisher to what the recorder takes: the recorder's sustained rate; counted
  on both sides, and in the bag afterwards;
* the same with zstd chunk compression;
* the recorder fed at fixed rates by publishers with KEEP_LAST depth 10 (rclpy's
  default QoS, what the stack's nodes use): where loss begins.

Every process runs with the stack's Fast DDS profile (config/fastdds.xml), as the
launchers start the recorder, unless the environment names another.

Run: ``.venv/bin/python bench/bench_recorder.py [--messages N]``. Prints a
table and returns the numbers from ``main()``.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import random
import subprocess
import sys
import tempfile
import time
from typing import Any

from tiltrov_ros.stack.specs import dds_environment

# Isolate DDS like the test suite does, before rclpy is imported.
os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(102, 200)))
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
# The Fast DDS profile the launchers give the recorder and every node (config/fastdds.xml),
# unless the environment names one: with Fast DDS's defaults (3 s heartbeats) a burst
# that overflows a shared-memory port waits seconds for its repair.
os.environ.update(dds_environment(os.environ))

RATES = (10_000, 20_000, 30_000, 40_000)  # msg/s, for the depth-10 publishers
TOPICS = {
    'odom': ('nav_msgs.msg', 'Odometry', 5),
    'joint_states': ('sensor_msgs.msg', 'JointState', 5),
    '/clock': ('rosgraph_msgs.msg', 'Clock', 5),
    'setpoint': ('geometry_msgs.msg', 'PoseStamped', 1),
    'setpoint_velocity': ('geometry_msgs.msg', 'TwistStamped', 1),
    'wrench_cmd': ('geometry_msgs.msg', 'WrenchStamped', 1),
    'thrust_cmd': ('sensor_msgs.msg', 'JointState', 1),
    'tilt_cmd': ('sensor_msgs.msg', 'JointState', 1),
    'wrench_achieved': ('geometry_msgs.msg', 'WrenchStamped', 1),
}


def message_mix(count: int) -> list[tuple[str, str, bytes]]:
    """``count`` (topic, type, CDR bytes) in the stack's proportions and order."""
    import importlib

    from rclpy.serialization import serialize_message

    payloads = {}
    for topic, (module, name, _) in TOPICS.items():
        cls = getattr(importlib.import_module(module), name)
        msg = cls()
        if name == 'JointState':
            msg.name = ['thruster_1', 'thruster_2', 'thruster_3', 'thruster_4',
                        'tilt_front', 'tilt_rear']
            msg.position = msg.velocity = msg.effort = [0.5] * 6
        payloads[topic] = (f"{module.split('.')[0]}/msg/{name}", serialize_message(msg))
    cycle = [t for t, (_, _, n) in TOPICS.items() for _ in range(n)]
    return [(t, *payloads[t]) for t in (cycle * (count // len(cycle) + 1))[:count]]


def absolute(topic: str) -> str:
    return topic if topic.startswith('/') else f'/{topic}'


# -- baselines without ROS ---------------------------------------------------------

def bench_rosbags(messages: list[tuple[str, str, bytes]], out: Path) -> float:
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin

    from tiltrov_ros.bag.msgdefs import message_definition

    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for topic, msgtype, _ in messages[:len(TOPICS) * 5]:
            if topic not in conns:
                msgdef, rihs01 = message_definition(msgtype)
                conns[topic] = writer.add_connection(absolute(topic), msgtype,
                                                     msgdef=msgdef, rihs01=rihs01)
        start = time.perf_counter()
        for i, (topic, _, data) in enumerate(messages):
            writer.write(conns[topic], i, data)
        elapsed = time.perf_counter() - start
    return len(messages) / elapsed


def bench_bag_writer(messages: list[tuple[str, str, bytes]], out: Path) -> float:
    from tiltrov_ros.bag.writer import BagWriter

    with BagWriter(out) as bag:
        conns = {}
        for topic, msgtype, _ in messages[:len(TOPICS) * 5]:
            if topic not in conns:
                conns[topic] = bag.add_topic(absolute(topic), msgtype)
        start = time.perf_counter()
        for i, (topic, _, data) in enumerate(messages):
            bag.write(conns[topic], i, data)
        elapsed = time.perf_counter() - start
    return len(messages) / elapsed


# -- the publisher process ------------------------------------------------------------

def publisher(count: int, depth: int, rate: float) -> dict[str, Any]:
    """Publish ``count`` messages of the mix (raw bytes); KEEP_ALL when depth is 0."""
    import importlib

    import rclpy
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.duration import Duration
    from rclpy.qos import HistoryPolicy, QoSProfile

    rclpy.init()
    node = rclpy.create_node('bench_publisher')
    qos = (QoSProfile(history=HistoryPolicy.KEEP_ALL) if depth == 0
           else QoSProfile(depth=depth))
    pubs = {t: node.create_publisher(getattr(importlib.import_module(m), n), t, qos)
            for t, (m, n, _) in TOPICS.items()}
    messages = message_mix(count)
    deadline = time.monotonic() + 30.0
    while (time.monotonic() < deadline
           and not all(p.get_subscription_count() for p in pubs.values())):
        time.sleep(0.01)
    time.sleep(0.3)  # let the recorder's side finish matching
    batch = 50
    blocked = 0
    start = time.perf_counter()
    for k in range(0, len(messages), batch):
        if rate > 0:
            delay = start + k / rate - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
        for topic, _, data in messages[k:k + batch]:
            while True:
                try:
                    pubs[topic].publish(data)
                    break
                except RCLError:  # KEEP_ALL history full for 100 ms: flow control, retry
                    blocked += 1
    elapsed = time.perf_counter() - start
    for p in pubs.values():
        p.wait_for_all_acked(Duration(seconds=5))
    node.destroy_node()
    rclpy.try_shutdown()
    return {'published': len(messages), 'seconds': elapsed, 'blocked': blocked}


# -- the recorder -----------------------------------------------------------------------

def bench_recorder(count: int, depth: int, rate: float, out: Path,
                   compression: str = 'none') -> dict[str, Any]:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rosbags.rosbag2 import Reader

    from tiltrov_ros.nodes.bag_recorder import BagRecorder

    context = Context()
    rclpy.init(context=context)
    recorder = BagRecorder(context=context, parameter_overrides={
        'output': str(out), 'topics': list(TOPICS), 'compression': compression})
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(recorder)
    proc = subprocess.Popen(
        [sys.executable, __file__, '--publisher', '--messages', str(count),
         '--depth', str(depth), '--rate', str(rate)],
        stdout=subprocess.PIPE, text=True)
    first = last = 0.0
    seen = 0
    try:
        while True:
            executor.spin_once(timeout_sec=0.01)
            total = sum(recorder.stats().received.values())
            now = time.perf_counter()
            if total != seen:
                first = first or now
                seen, last = total, now
            if total >= count or (proc.poll() is not None and now - max(last, first) > 2.0
                                  and (seen or now - first > 30)):
                break
        output, _ = proc.communicate(timeout=60)
        stats = recorder.close()
    finally:
        if proc.poll() is None:
            proc.kill()
        executor.shutdown()
        recorder.destroy_node()
        rclpy.try_shutdown(context=context)
    sent = json.loads(output.strip().splitlines()[-1])
    with Reader(out) as reader:
        in_bag = reader.message_count
    received = sum(stats.received.values())
    return {
        'published': sent['published'],
        'publisher_rate': sent['published'] / sent['seconds'],
        'received': received,
        'in_bag': in_bag,
        'lost': sent['published'] - in_bag,
        'dds_lost': sum(stats.lost.values()),
        'rate': received / (last - first) if last > first else 0.0,
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--messages', type=int, default=60_000)
    parser.add_argument('--publisher', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--depth', type=int, default=0, help=argparse.SUPPRESS)
    parser.add_argument('--rate', type=float, default=0.0, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.publisher:
        result = publisher(args.messages, args.depth, args.rate)
        print(json.dumps(result), flush=True)
        return result

    n = args.messages
    results: dict[str, Any] = {'messages': n, 'cpus': os.cpu_count()}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        messages = message_mix(n)
        results['rosbags_writer'] = bench_rosbags(messages, root / 'rosbags')
        results['bag_writer'] = bench_bag_writer(messages, root / 'bag_writer')
        results['recorder_keep_all'] = bench_recorder(n, 0, 0.0, root / 'keep_all')
        results['recorder_keep_all_zstd'] = bench_recorder(n, 0, 0.0, root / 'zstd', 'zstd')
        for rate in RATES:
            results[f'recorder_depth10_{rate}'] = bench_recorder(
                min(n, 2 * rate), 10, float(rate), root / f'depth10_{rate}')

    base = results['rosbags_writer']
    rows = [('rosbags Writer, no ROS (baseline)', n, '-', base, ''),
            ('BagWriter (the recorder\'s writer), no ROS', n, '-', results['bag_writer'], '')]
    labels = {'recorder_keep_all': 'recorder, KEEP_ALL publisher, flat out',
              'recorder_keep_all_zstd': 'recorder + zstd, KEEP_ALL publisher, flat out'}
    for rate in RATES:
        labels[f'recorder_depth10_{rate}'] = f'recorder, depth-10 publisher at {rate}/s'
    for key, label in labels.items():
        r = results[key]
        rows.append((label, r['published'], r['lost'], r['rate'],
                     f"publisher {r['publisher_rate']:,.0f}/s"))
    print(f"\nbag_recorder throughput ({n} messages of the stack's mix, "
          f'{results["cpus"]} CPUs)')
    print(f'{"case":<48} {"messages":>9} {"lost":>6} {"msg/s":>9} {"vs baseline":>11}  note')
    for label, count, lost, rate, note in rows:
        print(f'{label:<48} {count:>9} {lost!s:>6} {rate:>9,.0f} {rate / base:>10.2f}x  {note}')
    lossless = [results[key]['rate'] for key in labels if results[key]['lost'] == 0]
    results['sustained_without_loss'] = max(lossless, default=0.0)
    print(f'recorder sustains {results["sustained_without_loss"]:,.0f} msg/s without loss')
    return results


if __name__ == '__main__':
    main()
