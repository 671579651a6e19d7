"""Fields read straight from CDR bytes."""

from __future__ import annotations

from rosbags.typesys import Stores, get_typestore

from tiltrov_ros.bag.cdr import has_leading_stamp, leading_stamp_ns

STORE = get_typestore(Stores.ROS2_JAZZY)
T = STORE.types


def test_stamp_of_stamped_messages_and_clock_in_both_byte_orders() -> None:
    time = T['builtin_interfaces/msg/Time'](sec=12, nanosec=345_678_901)
    wrench = T['geometry_msgs/msg/WrenchStamped'](
        header=T['std_msgs/msg/Header'](stamp=time, frame_id='base_link_frd'),
        wrench=T['geometry_msgs/msg/Wrench'](force=T['geometry_msgs/msg/Vector3'](x=1, y=2, z=3),
                                             torque=T['geometry_msgs/msg/Vector3'](x=4, y=5, z=6)))
    clock = T['rosgraph_msgs/msg/Clock'](clock=time)
    for msg, msgtype in ((wrench, 'geometry_msgs/msg/WrenchStamped'),
                         (clock, 'rosgraph_msgs/msg/Clock')):
        assert has_leading_stamp(msgtype)
        little = bytes(STORE.serialize_cdr(msg, msgtype))
        big = bytes(STORE.serialize_cdr(msg, msgtype, little_endian=False))
        assert little[1] == 1 and big[1] == 0
        assert leading_stamp_ns(little, msgtype) == leading_stamp_ns(big, msgtype) == 12_345_678_901


def test_types_without_a_leading_stamp() -> None:
    string = bytes(STORE.serialize_cdr(T['std_msgs/msg/String'](data='hello world'),
                                       'std_msgs/msg/String'))
    assert not has_leading_stamp('std_msgs/msg/String')
    assert leading_stamp_ns(string, 'std_msgs/msg/String') is None
    assert not has_leading_stamp('my_pkg/msg/Unknown')
    assert leading_stamp_ns(b'\x00\x01\x00\x00', 'geometry_msgs/msg/WrenchStamped') is None  # short
