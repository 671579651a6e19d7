"""Messages without rclpy's field conversions: templates rewritten in place (out) and
messages read straight from their bytes into one object (in) give exactly what rclpy's
serialization gives."""

from __future__ import annotations

import math
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from ros_stack import KEEP_ALL, Probe
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from tiltrov_ros.core import names
from tiltrov_ros.nodes import plant_simulator
from tiltrov_ros.nodes.base import TiltrovNode
from tiltrov_ros.nodes.conversions import (
    fill_joint_state,
    fill_odometry,
    fill_pose,
    fill_twist,
    fill_wrench,
    new_joint_state,
    new_odometry,
    new_wrench,
)
from tiltrov_ros.nodes.serialized import MessageReader, SerializedTemplate

try:
    from tf2_msgs.msg import TFMessage
except ImportError:     # the venv before make install's tf2_msgs build
    TFMessage = None


def _odometry(rng: np.random.Generator, frame: str = names.FRAME_EARTH) -> Odometry:
    msg = fill_odometry(new_odometry(), int(rng.integers(0, 10**12)), rng.normal(size=3),
                        rng.normal(size=4), rng.normal(size=6))
    msg.header.frame_id = frame
    msg.pose.covariance = rng.normal(size=36)
    return msg


def _joints(rng: np.random.Generator, joint_names: tuple[str, ...]) -> JointState:
    n = len(joint_names)
    return fill_joint_state(new_joint_state(joint_names), int(rng.integers(0, 10**12)),
                            position=rng.normal(size=n), effort=rng.normal(size=n))


def _wrench(rng: np.random.Generator) -> WrenchStamped:
    return fill_wrench(new_wrench(), int(rng.integers(0, 10**12)), rng.normal(size=6))


def _clock(rng: np.random.Generator) -> Clock:
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = int(rng.integers(0, 2**31)), int(rng.integers(0, 10**9))
    return msg


def _pose(rng: np.random.Generator) -> PoseStamped:
    return fill_pose(PoseStamped(), int(rng.integers(0, 10**12)), rng.normal(size=3),
                     rng.normal(size=4))


def _twist(rng: np.random.Generator) -> TwistStamped:
    return fill_twist(TwistStamped(), int(rng.integers(0, 10**12)), rng.normal(size=6))


MAKERS = {Odometry: _odometry, WrenchStamped: _wrench, Clock: _clock, PoseStamped: _pose,
          TwistStamped: _twist,
          JointState: lambda rng: _joints(rng, names.TILTS + names.THRUSTERS)}


@pytest.mark.parametrize('msg_type', list(MAKERS), ids=lambda t: t.__name__)
def test_read_messages_equal_rclpys(msg_type: type) -> None:
    """The first message is deserialized, the next ones (same layout) are read straight
    into the same object: each equals what rclpy's deserialization gives."""
    rng = np.random.default_rng(3)
    reader = MessageReader(msg_type)
    first = None
    for _ in range(6):
        data = serialize_message(MAKERS[msg_type](rng))
        msg = reader.read(data)
        assert msg == deserialize_message(data, msg_type)
        first = msg if first is None else first
        assert msg is first             # refilled in place: one object per layout


def test_a_new_layout_is_deserialized_then_read() -> None:
    rng = np.random.default_rng(4)
    reader = MessageReader(JointState)
    layouts = [names.THRUSTERS, names.TILTS, ('a',), names.THRUSTERS, ()]
    for joint_names in layouts:
        one, two = (serialize_message(_joints(rng, joint_names)) for _ in range(2))
        first = reader.read(one)
        assert first == deserialize_message(one, JointState)
        second = reader.read(two)
        assert second is first and second == deserialize_message(two, JointState)
    odometry = MessageReader(Odometry)
    for frame in (names.FRAME_EARTH, names.FRAME_EARTH_ENU, names.FRAME_EARTH):
        data = serialize_message(_odometry(rng, frame))
        assert odometry.read(data) == deserialize_message(data, Odometry)


def test_non_finite_numbers_are_read_as_they_are() -> None:
    reader = MessageReader(WrenchStamped)
    reader.read(serialize_message(fill_wrench(new_wrench(), 5, [0.0] * 6)))
    values = [math.nan, math.inf, -math.inf, -0.0, 1e-310, 1.0]
    msg = reader.read(serialize_message(fill_wrench(new_wrench(), 7, values)))
    f, t = msg.wrench.force, msg.wrench.torque
    got = [f.x, f.y, f.z, t.x, t.y, t.z]
    assert np.array(got).tobytes() == np.array(values).tobytes()      # bit for bit


def test_bytes_that_are_no_message_raise_as_rclpy_does() -> None:
    reader = MessageReader(Odometry)
    good = serialize_message(_odometry(np.random.default_rng(5)))
    reader.read(good)
    for bad in (good[:40], good[:-8], b'', good + b'\x00' * 3):
        try:
            expected = deserialize_message(bad, Odometry)
        except Exception as exc:        # rclpy's RMWError
            with pytest.raises(type(exc)):
                reader.read(bad)
        else:
            assert reader.read(bad) == expected
    assert reader.read(good) == deserialize_message(good, Odometry)


def test_types_with_fields_it_does_not_read_are_deserialized() -> None:
    """A MarkerArray has booleans and bytes: every message goes through rclpy."""
    from tiltrov_ros.nodes.markers import new_marker_array
    reader = MessageReader(MarkerArray)
    data = serialize_message(new_marker_array())
    first = reader.read(data)
    assert first == deserialize_message(data, MarkerArray)
    assert reader.read(data) is not first


@pytest.mark.skipif(TFMessage is None, reason='tf2_msgs is not built (make install)')
def test_sequences_of_messages_are_read_too() -> None:
    from tiltrov_ros.nodes.transforms import transform
    rng = np.random.default_rng(6)
    reader = MessageReader(TFMessage)
    for _ in range(3):
        msg = TFMessage(transforms=[transform('odom', child, int(rng.integers(0, 10**12)),
                                              rng.normal(size=3), rng.normal(size=4))
                                    for child in ('base_link', 'thruster_1_link')])
        data = serialize_message(msg)
        assert reader.read(data) == deserialize_message(data, TFMessage)


@pytest.mark.parametrize('msg_type, fill, count', [
    (Clock, plant_simulator._clock_message, 0),
    (JointState, plant_simulator._joint_message, plant_simulator._JOINT_VALUES),
    (Odometry, plant_simulator._odom_message, plant_simulator._ODOM_VALUES)],
    ids=['clock', 'joint_states', 'odom'])
def test_the_plants_state_templates_serialize_the_filled_messages(msg_type: type, fill: Any,
                                                                  count: int) -> None:
    stamps = (lambda m: [m.clock]) if msg_type is Clock else (lambda m: [m.header.stamp])
    template = SerializedTemplate(msg_type, fill, stamps, count)
    rng = np.random.default_rng(7)
    for _ in range(5):
        values, ns = rng.normal(size=count), int(rng.integers(0, 10**12))
        expected = deserialize_message(serialize_message(fill(values, ns)), msg_type)
        assert deserialize_message(template.serialize(ns, values), msg_type) == expected
        assert deserialize_message(template.serialize(ns, list(values)), msg_type) == expected
        assert template.message(values, ns) == expected


def test_publish_serialized_never_sends_a_non_finite_value(ros) -> None:
    """Finite values go out as the template's bytes; a value not finite is withheld,
    counted and replaced by the safe answer, as SafePublisher.publish does."""
    node = ros.add(TiltrovNode('serialized_test', context=ros.context))
    template = SerializedTemplate(
        WrenchStamped, lambda v, ns: fill_wrench(new_wrench(), ns, v),
        lambda m: [m.header.stamp], 6)
    topic = names.WRENCH_CMD
    pub = node.create_safe_publisher(
        WrenchStamped, topic, KEEP_ALL, lambda msg: template.message([0.0] * 6, 99))
    probe = Probe(ros.node('serialized_probe'), [topic])
    assert ros.spin_until(lambda: pub.get_subscription_count() == 1)
    assert pub.publish_serialized(template, 5, [1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    assert not pub.publish_serialized(template, 6, [1.0, math.nan, 3.0, 4.0, 5.0, 6.0])
    assert ros.spin_until(lambda: len(probe[topic]) == 2)
    sent = [[m.wrench.force.x, m.wrench.torque.z] for m in probe[topic]]
    assert sent == [[1.0, 6.0], [0.0, 0.0]]
    assert probe.stamps(topic) == [5, 99]
    assert node.unsafe == {topic: 1} and pub.published == 2


def test_wrench_and_joint_templates_hold_their_messages_and_no_other() -> None:
    from tiltrov_ros.nodes.conversions import joint_template, wrench_template
    rng = np.random.default_rng(8)
    template, values = wrench_template()
    msg = _wrench(rng)
    ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    assert deserialize_message(template.serialize(ns, values(msg)), WrenchStamped) == msg
    msg.header.frame_id = names.FRAME_BODY_FLU
    assert values(msg) is None
    template, values = joint_template(names.THRUSTERS, 'effort')
    msg = fill_joint_state(new_joint_state(names.THRUSTERS), 12345, effort=rng.normal(size=4))
    assert deserialize_message(template.serialize(12345, values(msg)), JointState) == msg
    for other in (fill_joint_state(new_joint_state(names.TILTS), 1, effort=[1.0, 2.0]),
                  fill_joint_state(new_joint_state(names.THRUSTERS), 1, effort=[1.0] * 4,
                                   position=[0.0] * 4),
                  fill_joint_state(new_joint_state(names.THRUSTERS), 1, effort=[1.0] * 3)):
        assert values(other) is None
    failsafe = fill_joint_state(new_joint_state(names.THRUSTERS), 1, effort=[0.0] * 4)
    failsafe.header.frame_id = names.FAILSAFE_FRAME
    assert values(failsafe) is None


def test_a_publisher_serializing_as_a_template_sends_what_rclpy_would(ros) -> None:
    """serialize_as: the template's messages go out as its bytes, any other message through
    rclpy, a message not finite is withheld and replaced: the reader cannot tell."""
    from tiltrov_ros.nodes.conversions import joint_template
    node = ros.add(TiltrovNode('serialize_as_test', context=ros.context))
    topic = names.THRUST_CMD
    pub = node.create_safe_publisher(
        JointState, topic, KEEP_ALL,
        lambda msg: fill_joint_state(new_joint_state(names.THRUSTERS), 77, effort=[0.0] * 4))
    pub.serialize_as(*joint_template(names.THRUSTERS, 'effort'))
    probe = Probe(ros.node('serialize_as_probe'), [topic])
    assert ros.spin_until(lambda: pub.get_subscription_count() == 1)
    plain = fill_joint_state(new_joint_state(names.THRUSTERS), 5, effort=[1.0, 2.0, 3.0, 4.0])
    marked = fill_joint_state(new_joint_state(names.THRUSTERS), 6, effort=[0.0] * 4)
    marked.header.frame_id = names.FAILSAFE_FRAME
    broken = fill_joint_state(new_joint_state(names.THRUSTERS), 7, effort=[1.0, math.nan, 0, 0])
    assert pub.publish(plain) and pub.publish(marked) and not pub.publish(broken)
    assert ros.spin_until(lambda: len(probe[topic]) == 3)
    assert probe[topic][:2] == [plain, marked]
    assert probe.stamps(topic) == [5, 6, 77] and list(probe[topic][2].effort) == [0.0] * 4
    assert node.unsafe == {topic: 1} and pub.published == 3


@pytest.mark.parametrize('names_field', [(names.TILTS, 'position'),
                                         (names.THRUSTERS, 'effort')],
                         ids=['tilt_cmd', 'thrust_cmd'])
def test_joint_templates_are_the_bytes_a_writer_sends(names_field: Any) -> None:
    """rclpy's serialize_message gives a JointState with empty velocity and effort 8
    bytes longer than the message: the template is cut to it, padded to 4 bytes as a
    writer pads it, so that rosbags (which refuses more than 3 bytes past the end)
    reads what the stack recorded."""
    from rosbags.typesys import Stores, get_typestore

    from tiltrov_ros.nodes.conversions import joint_template
    joints, field = names_field
    template, _ = joint_template(joints, field)
    values = np.linspace(-1.0, 1.0, len(joints))
    data = template.serialize(123_456_789, values)
    assert len(data) % 4 == 0
    assert len(data) < len(serialize_message(template.message(values, 123_456_789)))
    decoded = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(data, 'sensor_msgs/msg/JointState')
    assert list(getattr(decoded, field)) == list(values) and list(decoded.name) == list(joints)
    assert deserialize_message(data, JointState) == template.message(values, 123_456_789)
