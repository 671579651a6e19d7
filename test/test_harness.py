"""The harness itself: real rclpy, real DDS, isolated per test session."""

from __future__ import annotations

import os
import subprocess
import sys

from geometry_msgs.msg import WrenchStamped
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

_TALKER = """
import sys, time
import rclpy
from rclpy.context import Context
from std_msgs.msg import String

publishers = []
for label, domain in (('other', int(sys.argv[1])), ('inherited', None)):
    context = Context()
    rclpy.init(context=context, domain_id=domain)   # None: the environment's ROS_DOMAIN_ID
    node = rclpy.create_node(f'isolation_{label}', context=context)
    publishers.append((label, node.create_publisher(String, 'isolation_probe', 10)))
deadline = time.monotonic() + 60
while time.monotonic() < deadline:
    for label, publisher in publishers:
        publisher.publish(String(data=label))
    time.sleep(0.02)
"""


def test_subprocesses_hear_this_session_and_other_domains_are_not_heard(ros) -> None:
    """What the session's DDS isolation promises: a process a test starts inherits the
    session's domain (the launch tests rely on it), and a participant in another domain
    on this machine (another test run) is not heard."""
    own = int(os.environ['ROS_DOMAIN_ID'])
    other = own % 101 + 1
    listener = ros.node('isolation_listener')
    heard: list[str] = []
    listener.create_subscription(String, 'isolation_probe', lambda m: heard.append(m.data),
                                 QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    talker = subprocess.Popen([sys.executable, '-c', _TALKER, str(other)])
    try:
        assert ros.spin_until(lambda: 'inherited' in heard, timeout=60.0)
        # Long enough for any participant of this domain on this machine to be found
        # (without multicast, periodic announcements come up to 3 s apart).
        ros.spin_for(5.0)
        assert heard.count('inherited') >= 100
    finally:
        talker.kill()
        talker.wait(timeout=10)
    assert 'other' not in heard
    assert 1 <= own <= 101 and other != own


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


def test_no_two_sessions_on_the_machine_take_the_same_domain() -> None:
    """Each session holds a lock on its domain for its whole life: a second claim (as a
    test session started meanwhile makes it) gets another one, and this session's own
    lock stays held while the other is taken and released."""
    from domains import claim_domain
    own = int(os.environ['ROS_DOMAIN_ID'])
    claims = [claim_domain() for _ in range(3)]
    try:
        domains = [d for d, _ in claims]
        assert own not in domains and len(set(domains)) == 3
    finally:
        for _, handle in claims:
            handle.close()
    again, handle = claim_domain()
    handle.close()
    assert again != own
