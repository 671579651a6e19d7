"""Messages of the stack's topics and comparisons, shared by the bag tests.

Imported as ``stack_messages`` (test/ is on sys.path: it holds conftest.py).
"""

from __future__ import annotations

from collections.abc import Callable
import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tiltrov_ros.bag.msgdefs import typestore
from tiltrov_ros.core.timebase import NS_PER_S as NS

RUN_INFO = {'scenario': 'positioning', 'controller': 'pd', 'max_thrust': 40.0}


def stamp(msg: Any, ns: int) -> Any:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, NS)
    return msg


def odom(i: int) -> Odometry:
    m = stamp(Odometry(), i * 10_000_000)
    m.header.frame_id, m.child_frame_id = 'odom_ned', 'base_link_frd'
    p = m.pose.pose
    p.position.x, p.position.y, p.position.z = 0.1 * i, -0.2 * i, 1.5
    p.orientation.x, p.orientation.y, p.orientation.z = 0.1, -0.2, 0.3
    p.orientation.w = math.sqrt(1 - 0.14)
    m.twist.twist.linear.x, m.twist.twist.angular.z = 0.01 * i, -0.5
    m.pose.covariance[0] = float(i)
    return m


def joints(i: int) -> JointState:
    m = stamp(JointState(), i * 10_000_000)
    m.name = ['thruster_1', 'thruster_2', 'thruster_3', 'thruster_4', 'tilt_front', 'tilt_rear']
    m.position = [0.0, 0.0, 0.0, 0.0, 0.01 * i, -0.01 * i]
    m.velocity = [0.0, 0.0, 0.0, 0.0, 0.5, -0.5]
    m.effort = [1.0 * i, 2.0, -3.0, 4.5, 0.0, 0.0]
    return m


def setpoint(i: int) -> PoseStamped:
    m = stamp(PoseStamped(), i * 50_000_000)
    m.header.frame_id = 'odom_ned'
    m.pose.position.x, m.pose.orientation.w = 1.0 + i, 1.0
    return m


def setpoint_velocity(i: int) -> TwistStamped:
    m = stamp(TwistStamped(), i * 50_000_000)
    m.twist.linear.y, m.twist.angular.x = 0.25, -0.001 * i
    return m


def wrench(i: int) -> WrenchStamped:
    m = stamp(WrenchStamped(), i * 50_000_000)
    m.header.frame_id = 'base_link_frd'
    m.wrench.force.x, m.wrench.torque.z = 3.0 * i, -0.75
    return m


def thrust_cmd(i: int) -> JointState:
    m = stamp(JointState(), i * 50_000_000)
    m.name = ['thruster_1', 'thruster_2', 'thruster_3', 'thruster_4']
    m.effort = [float(i), -float(i), 0.5, 40.0]
    return m


def tilt_cmd(i: int) -> JointState:
    m = stamp(JointState(), i * 50_000_000)
    m.name, m.position = ['tilt_front', 'tilt_rear'], [0.001 * i, 1.5]
    return m


def clock(i: int) -> Clock:
    m = Clock()
    m.clock.sec, m.clock.nanosec = divmod(i * 10_000_000, NS)
    return m


def diagnostics(i: int) -> DiagnosticArray:
    m = stamp(DiagnosticArray(), i * NS)
    m.status = [DiagnosticStatus(level=DiagnosticStatus.WARN, name='plant', message=f'#{i}',
                                 values=[KeyValue(key='stall', value=str(i))])]
    return m


# topic -> (type, message factory)
STACK: dict[str, tuple[type, Callable[[int], Any]]] = {
    'odom': (Odometry, odom),
    'joint_states': (JointState, joints),
    'setpoint': (PoseStamped, setpoint),
    'setpoint_velocity': (TwistStamped, setpoint_velocity),
    'wrench_cmd': (WrenchStamped, wrench),
    'thrust_cmd': (JointState, thrust_cmd),
    'tilt_cmd': (JointState, tilt_cmd),
    'wrench_achieved': (WrenchStamped, wrench),
    '/clock': (Clock, clock),
    '/diagnostics': (DiagnosticArray, diagnostics),
}


def absolute(name: str) -> str:
    return name if name.startswith('/') else f'/{name}'


def assert_same(ros_msg: Any, decoded: Any, path: str = '') -> None:
    """Field-by-field equality of an rclpy message and a decoded one."""
    if hasattr(ros_msg, 'get_fields_and_field_types'):
        for name in ros_msg.get_fields_and_field_types():
            assert_same(getattr(ros_msg, name), getattr(decoded, name), f'{path}.{name}')
    elif isinstance(ros_msg, bytes) and len(ros_msg) == 1 and isinstance(decoded, int):
        assert ros_msg[0] == decoded, path  # 'byte' fields: b'\x01' in rclpy, 1 decoded
    elif isinstance(ros_msg, (str, bytes, int, float, bool)):
        assert ros_msg == decoded, path
    else:  # sequences and arrays
        assert len(ros_msg) == len(decoded), path
        for k, (a, b) in enumerate(zip(ros_msg, decoded)):
            assert_same(a, b, f'{path}[{k}]')


def canonical(data: bytes, msgtype: str) -> bytes:
    """CDR with zeroed alignment padding and no trailing bytes (decode, re-encode).

    rclpy's serialize_message (rmw_serialize) leaves the padding between fields
    uninitialized and may return bytes past the end of the CDR content, so its
    output is compared with what DDS delivered only in this normal form.
    """
    store = typestore()
    msgdef = store.get_msgdef(msgtype)
    assert data[:4] == b'\x00\x01\x00\x00'  # little-endian CDR
    msg, _ = msgdef.deserialize_cdr_le(memoryview(data)[4:], 0, msgdef.cls, store)
    return bytes(store.serialize_cdr(msg, msgtype))


def wait_matched(ros: Any, publishers: list[Any], timeout: float = 10.0,
                 subscribers: int = 1, process: Any = None) -> None:
    """Spin until each of ``publishers`` has matched ``subscribers`` readers: within
    ``timeout`` wall seconds, or, with ``process`` (a Popen whose node is the reader),
    for as long as that process keeps using CPU (it may still be starting on a loaded
    machine; a hang is what stops the wait)."""
    def matched() -> bool:
        return all(p.get_subscription_count() >= subscribers for p in publishers)

    if process is None:
        done = ros.spin_until(matched, timeout=timeout)
    else:
        from harness import TreeProgress
        done = ros.spin_while_progressing(matched, TreeProgress(process.pid))
    assert done, [p.topic_name for p in publishers
                  if p.get_subscription_count() < subscribers]
