"""Message definitions for the MCAP schemas: from rosbags' Jazzy type store, and
the fallback built from the generated Python class (for types the store lacks)."""

from __future__ import annotations

from nav_msgs.msg import Odometry
import pytest
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from tiltrov_ros.bag.msgdefs import (
    definition_from_python,
    hash_of_definition,
    message_definition,
    typestore,
)
from tiltrov_ros.core.errors import BagError
from tiltrov_ros.core.names import STACK_TOPICS

TYPES = sorted({*STACK_TOPICS.values(), 'rcl_interfaces/msg/Log',
                'rcl_interfaces/msg/ParameterEvent', 'sensor_msgs/msg/CameraInfo',
                'rcl_interfaces/msg/ParameterDescriptor'})


@pytest.mark.parametrize('msgtype', TYPES)
def test_python_fallback_matches_the_type_store(msgtype: str) -> None:
    """Same fields (names, types, bounds) and the same RIHS01 hash as rosbags' store."""
    text = definition_from_python(msgtype)
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, msgtype))
    jazzy = typestore()
    for name, (_, fields) in store.fielddefs.items():
        assert fields == jazzy.fielddefs[name][1], name
    assert hash_of_definition(msgtype, text) == jazzy.hash_rihs01(msgtype)


def test_fallback_definition_decodes_real_messages() -> None:
    text = definition_from_python('nav_msgs/msg/Odometry')
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, 'nav_msgs/msg/Odometry'))
    msg = Odometry()
    msg.header.frame_id = 'odom_ned'
    msg.pose.pose.orientation.w = 0.5
    msg.pose.covariance[35] = 3.0
    decoded = store.deserialize_cdr(serialize_message(msg), 'nav_msgs/msg/Odometry')
    assert decoded.header.frame_id == 'odom_ned'
    assert decoded.pose.pose.orientation.w == 0.5
    assert decoded.pose.covariance[35] == 3.0


def test_store_types_come_with_their_hash() -> None:
    text, rihs01 = message_definition('geometry_msgs/WrenchStamped')
    assert text.startswith('std_msgs/Header header\ngeometry_msgs/Wrench wrench\n')
    assert 'MSG: geometry_msgs/Vector3' in text
    assert rihs01 == typestore().hash_rihs01('geometry_msgs/msg/WrenchStamped')


def test_unknown_type_is_a_bag_error() -> None:
    with pytest.raises(BagError, match='no_such_pkg/msg/Thing'):
        message_definition('no_such_pkg/msg/Thing')
