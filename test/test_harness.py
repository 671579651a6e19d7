"""The harness itself: real rclpy, real DDS, isolated per test session."""

from __future__ import annotations

import os

from geometry_msgs.msg import WrenchStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy


def test_dds_isolation_is_set() -> None:
    domain = int(os.environ['ROS_DOMAIN_ID'])
    assert 1 <= domain <= 101
    assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'


def test_message_round_trip_through_dds(ros) -> None:
    """Two nodes in one context exchange a message through Fast DDS."""
    import rclpy

    assert 'rmw_fastrtps' in rclpy.get_rmw_implementation_identifier()
    talker = ros.node('talker')
    listener = ros.node('listener')
    received: list[WrenchStamped] = []
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    listener.create_subscription(WrenchStamped, 'wrench_cmd', received.append, qos)
    pub = talker.create_publisher(WrenchStamped, 'wrench_cmd', qos)
    assert ros.spin_until(lambda: pub.get_subscription_count() > 0, timeout=10.0)

    msg = WrenchStamped()
    msg.header.frame_id = 'base_link_frd'
    msg.header.stamp.sec = 12
    msg.header.stamp.nanosec = 500_000_000
    msg.wrench.force.z = -7.25
    msg.wrench.torque.y = 1.5
    pub.publish(msg)

    assert ros.spin_until(lambda: len(received) == 1, timeout=10.0)
    got = received[0]
    assert got.header.frame_id == 'base_link_frd'
    assert (got.header.stamp.sec, got.header.stamp.nanosec) == (12, 500_000_000)
    assert got.wrench.force.z == -7.25
    assert got.wrench.torque.y == 1.5
    assert got is not msg


def test_each_test_gets_its_own_context(ros) -> None:
    node = ros.node('probe')
    assert node.context is ros.context
    assert ros.context.ok()
