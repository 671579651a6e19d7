"""bag_recorder on a live graph: every message, byte for byte, readable by rosbags
and by the mcap library's ROS 2 decoder; QoS, run_info, sim-time log times,
parameters."""

from __future__ import annotations

import json
from pathlib import Path
import signal
import subprocess
import threading
from typing import Any

from harness import wait_while_progressing
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from nav_msgs.msg import Odometry
import pytest
import rclpy
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.exceptions import InvalidParameterValueException
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from ros_stack import HANG_BOUND, installed
from rosbags.interfaces import QosDurability, QosReliability
from rosbags.rosbag2 import Reader
from rosgraph_msgs.msg import Clock
from stack_messages import (
    RUN_INFO,
    STACK,
    absolute,
    assert_same,
    canonical,
    clock,
    odom,
    wait_matched,
)
from std_msgs.msg import String

from tiltrov_ros.bag.bagfile import RUN_INFO_KEY
from tiltrov_ros.bag.losses import losses
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.timebase import cdr_stamp_ns
from tiltrov_ros.nodes.bag_recorder import BagRecorder
from tiltrov_ros.nodes.recorder_config import recorder_command
from tiltrov_ros.paths import config_file


def test_records_a_live_run_byte_for_byte(ros: Any, tmp_path: Path) -> None:
    bag = tmp_path / 'run'
    recorder = ros.add(BagRecorder(context=ros.context, parameter_overrides={
        'output': str(bag), 'run_info': json.dumps(RUN_INFO), 'discovery_period': 0.1,
        'exclude_topics': ['/rosout', '/parameter_events']}))  # every other topic
    recorder._diagnostics_timer.cancel()     # its own /diagnostics: none here, only the stack's
    stack = ros.node('stack')
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    publishers = {
        topic: stack.create_publisher(cls, topic, best_effort if topic == '/diagnostics' else 10)
        for topic, (cls, _) in STACK.items()}
    # A topic that appears after start-up, not one of the stack's.
    late = stack.create_publisher(String, 'late_topic', 10)
    # An independent raw subscriber sees the bytes DDS delivers.
    witness = ros.node('witness')
    wire: dict[str, list[bytes]] = {}
    deep_best_effort = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT)
    for topic, cls in [*((t, c) for t, (c, _) in STACK.items()), ('late_topic', String)]:
        witness.create_subscription(cls, topic, wire.setdefault(absolute(topic), []).append,
                                    deep_best_effort if topic == '/diagnostics' else 1000,
                                    raw=True)
    wait_matched(ros, [*publishers.values(), late], subscribers=2)

    sent: dict[str, list[Any]] = {absolute(t): [] for t in [*STACK, 'late_topic']}
    for i in range(120):
        for topic, (_, make) in STACK.items():
            if topic in ('odom', 'joint_states', '/clock') or i % 5 == 0:
                msg = make(i)
                publishers[topic].publish(msg)
                sent[absolute(topic)].append(msg)
        if i % 10 == 0:
            msg = String(data=f'late {i}')
            late.publish(msg)
            sent['/late_topic'].append(msg)
        ros.executor.spin_once(timeout_sec=0)
    expected = {topic: len(msgs) for topic, msgs in sent.items()}
    assert ros.spin_until(lambda: recorder.stats().received == expected, timeout=15.0), \
        (recorder.stats().received, expected)
    stats = recorder.close()
    assert stats.written == stats.flushed == expected
    assert stats.lost == {} and stats.errors == 0

    assert ros.spin_until(lambda: {t: len(w) for t, w in wire.items()} == expected), \
        {t: (len(w), expected[t]) for t, w in wire.items() if len(w) != expected[t]}
    with Reader(bag) as reader:
        assert {t: (i.msgtype, i.msgcount) for t, i in reader.topics.items()} == {
            topic: (type(msgs[0]).__module__.split('.')[0] + '/msg/' + type(msgs[0]).__name__,
                    len(msgs)) for topic, msgs in sent.items()}
        got: dict[str, list[bytes]] = {topic: [] for topic in sent}
        for conn, _, data in reader.messages():
            got[conn.topic].append(bytes(data))
        types = {c.topic: c.msgtype for c in reader.connections}
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
        custom = reader.storage.metadata.custom
    assert got == wire  # the delivered CDR bytes, untouched, in publication order
    for topic, msgs in sent.items():
        normal = [canonical(serialize_message(m), types[topic]) for m in msgs]
        assert got[topic] == normal, topic
    # The stack's /diagnostics writer (best effort) and the recorder's own (reliable).
    assert sorted(q.reliability.value for q in qos['/diagnostics']) == [
        QosReliability.RELIABLE.value, QosReliability.BEST_EFFORT.value]
    assert [q.reliability for q in qos['/odom']] == [QosReliability.RELIABLE]
    assert json.loads(custom[RUN_INFO_KEY]) == RUN_INFO

    with (bag / 'run.mcap').open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == sum(expected.values())
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        decoded: dict[str, list[Any]] = {topic: [] for topic in sent}
        for _, channel, _, msg in reader.iter_decoded_messages():
            decoded[channel.topic].append(msg)
    for topic, msgs in sent.items():
        assert len(decoded[topic]) == len(msgs), topic
        for original, back in zip(msgs, decoded[topic]):
            assert_same(original, back, topic)


def test_log_time_is_sim_time_with_clock_handled_before_data(ros: Any, tmp_path: Path) -> None:
    """With use_sim_time, /clock is logged at its value and the data published after
    it at that value, even when the executor serves the data subscription first."""
    bag = tmp_path / 'sim'
    recorder = ros.add(BagRecorder(context=ros.context, parameter_overrides={
        'output': str(bag), 'use_sim_time': True, 'topics': ['odom', '/clock']}))
    stack = ros.node('plant')
    clock_pub = stack.create_publisher(Clock, '/clock', 10)
    odom_pub = stack.create_publisher(Odometry, 'odom', 10)
    wait_matched(ros, [clock_pub, odom_pub])
    steps = range(1, 41)
    for i in steps:
        clock_pub.publish(clock(1000 + i))   # advances sim time to t_i ...
        odom_pub.publish(odom(1000 + i))     # ... then the data stamped t_i
        assert ros.spin_until(lambda i=i: recorder.stats().received.get('/odom') == i,
                              timeout=5.0)
    recorder.close()
    with Reader(bag) as reader:
        log = {topic: [] for topic in ('/clock', '/odom')}
        for conn, log_time, data in reader.messages():
            log[conn.topic].append((log_time, data))
    assert [t for t, _ in log['/clock']] == [cdr_stamp_ns(d) for _, d in log['/clock']]
    assert [t for t, _ in log['/odom']] == [(1000 + i) * 10_000_000 for i in steps]


def test_the_urdf_is_recorded_without_waiting_for_discovery(ros: Any, tmp_path: Path) -> None:
    """robot_description (transient local, written once at start) is read from the
    recorder's start like /tf_static, not found by polling: a short run may end before a
    poll (none here after start-up within the wait: the period is the longest allowed)."""
    bag = tmp_path / 'urdf'
    recorder = ros.add(BagRecorder(context=ros.context, parameter_overrides={
        'output': str(bag), 'discovery_period': 60.0}))
    plant = ros.node('plant')
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    plant.create_publisher(String, 'robot_description', latched).publish(String(data='<robot/>'))
    assert ros.spin_until(lambda: recorder.stats().received.get('/robot_description') == 1,
                          timeout=30.0)
    recorder.close()
    with Reader(bag) as reader:
        (conn,) = [c for c in reader.connections if c.topic == '/robot_description']
        assert conn.msgcount == 1
        assert [q.durability for q in conn.ext.offered_qos_profiles] == [
            QosDurability.TRANSIENT_LOCAL]


def test_parameters_from_the_shipped_file_and_their_limits(ros: Any, tmp_path: Path) -> None:
    shipped = config_file('bag_recorder.yaml')
    recorder = ros.add(BagRecorder(
        context=ros.context, cli_args=['--ros-args', '--params-file', str(shipped)],
        parameter_overrides={'output': str(tmp_path / 'a')}))
    assert recorder.config.topics == ()          # every topic
    assert recorder.config.compression == 'none'
    assert recorder.config.queue_depth == 10000
    assert recorder.config.flush_period == 1.0
    assert recorder.output == tmp_path / 'a'
    descriptor = recorder.describe_parameter('flush_period')
    assert descriptor.read_only and descriptor.description
    assert descriptor.floating_point_range[0].to_value == 3600.0

    # run_info may change while recording; invalid JSON is refused.
    result = recorder.set_parameters([Parameter('run_info', value='{"scenario": "late"}')])
    assert result[0].successful
    assert not recorder.set_parameters([Parameter('run_info', value='[1, 2]')])[0].successful
    recorder.close()
    with Reader(tmp_path / 'a') as reader:
        assert json.loads(reader.storage.metadata.custom[RUN_INFO_KEY]) == {'scenario': 'late'}

    with pytest.raises(ParameterError, match='compression'):
        BagRecorder(context=ros.context, parameter_overrides={
            'output': str(tmp_path / 'b'), 'compression': 'lz4'}).destroy_node()
    # rclpy refuses the value out of range; the node names it (as every node does).
    with pytest.raises(ParameterError, match='queue_depth') as info:
        BagRecorder(context=ros.context, parameter_overrides={
            'output': str(tmp_path / 'c'), 'queue_depth': -1}).destroy_node()
    assert isinstance(info.value.__cause__, InvalidParameterValueException)
    with pytest.raises(ParameterError, match='run_info'):
        BagRecorder(context=ros.context, parameter_overrides={
            'output': str(tmp_path / 'd'), 'run_info': 'not json'}).destroy_node()


def test_defaults_without_a_parameter_file(ros: Any, tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    recorder = ros.add(BagRecorder(context=ros.context))
    assert recorder.output.parent == Path('.')
    assert recorder.output.name.startswith('rosbag2_')
    assert set(recorder.subscribed_topics) >= {'/odom', '/joint_states', '/clock', '/wrench_cmd'}
    recorder.close()
    assert (tmp_path / recorder.output / 'metadata.yaml').is_file()


@pytest.mark.timeout(HANG_BOUND)
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_a_signal_closes_the_bag(ros: Any, tmp_path: Path, sig: signal.Signals) -> None:
    """The standalone process records what it was sent and writes a complete bag."""
    bag = tmp_path / 'signalled'
    argv = recorder_command(str(bag), params={'topics': ['odom']})
    argv[0] = str(installed('bag_recorder'))
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, '')),
                              daemon=True)
    reader.start()
    try:
        pub = ros.node('plant').create_publisher(Odometry, 'odom', 100)
        wait_matched(ros, [pub], process=proc)
        # The node has started once it logs where it records.
        assert ros.spin_while_progressing(lambda: any('] [bag_recorder]: recording' in line
                                                      for line in lines),
                                          lambda: len(lines)), lines
        for i in range(100):
            pub.publish(odom(i))
        # Acknowledged: in the recorder's queue, which it empties before closing.
        assert pub.wait_for_all_acked(Duration(seconds=10))
        proc.send_signal(sig)
        wait_while_progressing(proc)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=5)
    err = ''.join(lines)
    assert proc.returncode == 0, err
    assert 'recorded 100 messages on 1 topics' in err
    assert 'Traceback' not in err and 'Failed to publish' not in err, err
    with Reader(bag) as bag_reader:
        assert bag_reader.message_count == 100
        assert [bytes(d) for _, _, d in bag_reader.messages()] == [
            canonical(serialize_message(odom(i)), 'nav_msgs/msg/Odometry') for i in range(100)]


def test_recorder_command_quotes_strings() -> None:
    argv = recorder_command('runs/x', run_info={'scenario': "it's"},
                            params={'compression': 'zstd', 'flush_period': 0.5,
                                    'topics': ['odom', '/clock']})
    assert argv == ['bag_recorder', '--ros-args', '-p', "output:='runs/x'",
                    '-p', "compression:='zstd'", '-p', 'flush_period:=0.5',
                    '-p', "topics:=['odom', '/clock']",
                    '-p', """run_info:='{"scenario": "it''s"}'"""]


def test_discovery_racing_a_shutdown_is_not_a_loss(tmp_path: Path) -> None:
    """A discovery tick that runs as a signal shuts the context down finds the graph
    gone: that loses nothing, and the recorder must not exit as if it had."""
    context = Context()
    rclpy.init(context=context)
    recorder = BagRecorder(context=context, parameter_overrides={'output': str(tmp_path / 'b')})
    try:
        rclpy.shutdown(context=context)
        recorder._discover()
        assert recorder.stats().errors == 0 and not recorder.lost_data
    finally:
        recorder.destroy_node()
    assert losses(tmp_path / 'b').recorder['write_errors'] == 0


def test_discovery_failing_mid_run_is_reported(ros: Any, tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """While the context is up, a failed discovery may leave a topic unrecorded: the
    recorder counts it and names it as its first error."""
    recorder = ros.add(BagRecorder(context=ros.context,
                                   parameter_overrides={'output': str(tmp_path / 'b')}))

    def broken() -> list[Any]:
        raise RuntimeError('graph unavailable')
    monkeypatch.setattr(recorder, 'get_topic_names_and_types', broken)
    recorder._discover()
    assert recorder.lost_data and recorder.stats().errors == 1
    assert recorder.first_error == 'graph discovery failed: graph unavailable'
    recorder.close()
    account = losses(tmp_path / 'b').recorder
    assert account['write_errors'] == 1 and 'graph unavailable' in account['first_error']
