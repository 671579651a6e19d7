"""A recorded run carries the transform tree, as Foxglove and rosbag2 read it.

``tiltrov launch --namespace r1 --record`` (separate processes, the launcher's
remappings): the bag has ``/r1/tf`` at every step and ``/r1/tf_static`` with
transient-local durability in its metadata (rosbag2's player then latches it
again), ``/r1/robot_description``; the tree read back from the bag is complete
at every ``odom`` stamp and gives the odometry; nothing went to the root tree;
``tiltrov analyze`` reads the bag as before.
"""

from __future__ import annotations

from pathlib import Path
import sys
from typing import Any

from harness import HANG_BOUND, run_while_progressing
import pytest
from rclpy.serialization import deserialize_message
from ros_stack import require_tf2_msgs
from rosbags.interfaces import QosDurability
from tf_tree import assert_is_the_odometry, assert_one_tree, body_in_odom_ned, tf_stamp

from tiltrov_ros import cli
from tiltrov_ros.bag.bagfile import bag_info, iter_raw
from tiltrov_ros.core.timebase import to_ns

DURATION = 2.0


#: A whole launch records the module's bag (its time counts in the first test that uses
#: it): its wait gives up on a hang, not on a slow machine.
pytestmark = pytest.mark.timeout(HANG_BOUND)


@pytest.fixture(scope='module')
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    require_tf2_msgs()
    root = tmp_path_factory.mktemp('tf_bag')
    bag = root / 'bag'
    result = run_while_progressing(
        [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', '--scenario', 'pitch_hold',
         '--duration', str(DURATION), '--namespace', 'r1', '--record', str(bag)], cwd=root)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return bag


def _messages(bag: Path, topic: str, msg_type: Any) -> list[Any]:
    return [deserialize_message(raw.data, msg_type) for raw in iter_raw(bag, [topic])]


@pytest.mark.slow
def test_the_bag_has_the_namespaced_tree_with_rosbag2s_qos(bag: Path) -> None:
    topics = bag_info(bag).topics
    assert topics['/r1/tf'].msgtype == 'tf2_msgs/msg/TFMessage'
    # One /tf per odometry (a stall's republished state has both again; the tree read
    # from the bag has every step, below).
    assert topics['/r1/tf'].count == topics['/r1/odom'].count >= round(DURATION * 100) + 1
    static = topics['/r1/tf_static']
    assert static.count == 1
    assert [q.durability for q in static.qos] == [QosDurability.TRANSIENT_LOCAL]
    assert [q.durability for q in topics['/r1/tf'].qos] == [QosDurability.VOLATILE]
    assert topics['/r1/robot_description'].count == 1
    assert not {'/tf', '/tf_static'} & set(topics)


@pytest.mark.slow
def test_the_tree_read_from_the_bag_is_complete_and_gives_the_odometry(bag: Path) -> None:
    from nav_msgs.msg import Odometry

    TFMessage = require_tf2_msgs()
    (static,) = _messages(bag, '/r1/tf_static', TFMessage)
    odom = {}
    for msg in _messages(bag, '/r1/odom', Odometry):
        odom[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = msg
    tf = {tf_stamp(m): m for m in _messages(bag, '/r1/tf', TFMessage)}
    assert sorted(tf) == sorted(odom) == list(range(0, to_ns(DURATION) + 1, to_ns(0.01)))
    for ns, message in tf.items():
        assert_one_tree(static, message)
        assert_is_the_odometry(body_in_odom_ned(static, message), odom[ns])


@pytest.mark.slow
def test_analyze_reads_a_bag_with_the_tree(bag: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(['analyze', str(bag), '--out', str(tmp_path), '--no-figures']) == 0
    capsys.readouterr()
    assert (tmp_path / 'metrics.json').is_file()
