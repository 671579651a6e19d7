"""A :class:`~tiltrov_ros.core.runlog.RunLog` written as a bag of the stack's topics.

The inverse of :func:`tiltrov_ros.bag.reader.read_runlog`: the messages the
nodes would have published for that run (ARCHITECTURE.md, "Time and stamps";
frames and joint names of :mod:`tiltrov_ros.core.names`), serialized by rosbags and written
with the project's :class:`~tiltrov_ros.bag.writer.BagWriter`, no ROS needed.
Uses: turning a headless run into a bag for bag tools (Foxglove, ``tiltrov
replay``), bags with known content for tests, and large bags for benchmarks.

Per plant row: ``odom``, ``joint_states`` (tilts' position and velocity,
thrusters' effort, 0.0 elsewhere, as ``plant_simulator`` fills it) and
``/clock``; per control row: ``setpoint``, ``setpoint_velocity``,
``wrench_cmd``, ``tilt_cmd``, ``thrust_cmd`` and ``wrench_achieved``. Every
message is stamped with its row's time and logged at it (a recorder on sim
time). ``run_info`` (default: the RunLog's meta without its ``bag`` entry) is
stored as the recorder stores it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
import json
from pathlib import Path
from typing import Any

import numpy as np

from tiltrov_ros.core.names import (
    CLOCK,
    FRAME_BODY,
    FRAME_EARTH,
    JOINT_STATES,
    ODOM,
    SETPOINT,
    SETPOINT_VELOCITY,
    STACK_TOPICS,
    THRUST_CMD,
    THRUSTERS,
    TILT_CMD,
    TILTS,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
    join_namespace,
)
from tiltrov_ros.core.runlog import RunLog
from tiltrov_ros.core.timebase import ns_to_stamp, to_ns

from .bagfile import RUN_INFO_KEY
from .msgdefs import typestore
from .writer import BagWriter

PLANT_TOPICS = (ODOM, JOINT_STATES, CLOCK)
CONTROL_TOPICS = (SETPOINT, SETPOINT_VELOCITY, WRENCH_CMD, TILT_CMD, THRUST_CMD, WRENCH_ACHIEVED)
#: joint_states fields a joint does not have: 0.0, as the plant fills them (no NaN on a topic).
ABSENT2 = (0.0, 0.0)
ABSENT4 = (0.0,) * 4


class _Messages:
    """rosbags message builders of the stack's topics."""

    def __init__(self) -> None:
        self.store = typestore()
        t = self.store.types
        self.Time, self.Header = t['builtin_interfaces/msg/Time'], t['std_msgs/msg/Header']
        self.Vector3, self.Point = t['geometry_msgs/msg/Vector3'], t['geometry_msgs/msg/Point']
        self.Quaternion, self.Pose = t['geometry_msgs/msg/Quaternion'], t['geometry_msgs/msg/Pose']
        self.Twist, self.Wrench = t['geometry_msgs/msg/Twist'], t['geometry_msgs/msg/Wrench']
        self.types = t
        self.zeros36 = np.zeros(36)

    def header(self, ns: int, frame: str) -> Any:
        sec, nanosec = ns_to_stamp(ns)
        return self.Header(stamp=self.Time(sec=sec, nanosec=nanosec), frame_id=frame)

    def pose(self, p: Any, q_wxyz: Any) -> Any:
        return self.Pose(position=self.Point(x=p[0], y=p[1], z=p[2]),
                         orientation=self.Quaternion(x=q_wxyz[1], y=q_wxyz[2], z=q_wxyz[3],
                                                     w=q_wxyz[0]))

    def twist(self, v: Any) -> Any:
        return self.Twist(linear=self.Vector3(x=v[0], y=v[1], z=v[2]),
                          angular=self.Vector3(x=v[3], y=v[4], z=v[5]))

    def odom(self, ns: int, p: Any, q: Any, nu: Any) -> Any:
        t = self.types
        return t['nav_msgs/msg/Odometry'](
            header=self.header(ns, FRAME_EARTH), child_frame_id=FRAME_BODY,
            pose=t['geometry_msgs/msg/PoseWithCovariance'](pose=self.pose(p, q),
                                                           covariance=self.zeros36),
            twist=t['geometry_msgs/msg/TwistWithCovariance'](twist=self.twist(nu),
                                                             covariance=self.zeros36))

    def joints(self, ns: int, names: tuple[str, ...], position: Any = (), velocity: Any = (),
               effort: Any = ()) -> Any:
        return self.types['sensor_msgs/msg/JointState'](
            header=self.header(ns, ''), name=list(names),
            position=np.asarray(position, dtype=float), velocity=np.asarray(velocity, dtype=float),
            effort=np.asarray(effort, dtype=float))

    def pose_stamped(self, ns: int, p: Any, q: Any) -> Any:
        return self.types['geometry_msgs/msg/PoseStamped'](header=self.header(ns, FRAME_EARTH),
                                                           pose=self.pose(p, q))

    def twist_stamped(self, ns: int, v: Any) -> Any:
        return self.types['geometry_msgs/msg/TwistStamped'](
            header=self.header(ns, FRAME_EARTH), twist=self.twist(v))

    def wrench(self, ns: int, w: Any) -> Any:
        return self.types['geometry_msgs/msg/WrenchStamped'](
            header=self.header(ns, FRAME_BODY),
            wrench=self.Wrench(force=self.Vector3(x=w[0], y=w[1], z=w[2]),
                               torque=self.Vector3(x=w[3], y=w[4], z=w[5])))

    def clock(self, ns: int) -> Any:
        sec, nanosec = ns_to_stamp(ns)
        return self.types['rosgraph_msgs/msg/Clock'](clock=self.Time(sec=sec, nanosec=nanosec))


def _rows(log: RunLog, m: _Messages) -> Iterator[tuple[int, str, Any]]:
    """(stamp ns, relative topic, message) in the order the stack publishes them."""
    plant_ns = [to_ns(float(t)) for t in log.t]
    control_ns = [to_ns(float(t)) for t in log.tc]
    k = 0
    builders: dict[str, Callable[[int, int], Any]] = {
        SETPOINT: lambda j, ns: m.pose_stamped(ns, log.setpoint_position[j],
                                                 log.setpoint_quaternion[j]),
        SETPOINT_VELOCITY: lambda j, ns: m.twist_stamped(ns, log.setpoint_velocity[j]),
        WRENCH_CMD: lambda j, ns: m.wrench(ns, log.wrench_cmd[j]),
        TILT_CMD: lambda j, ns: m.joints(ns, TILTS, position=log.tilt_cmd[j]),
        THRUST_CMD: lambda j, ns: m.joints(ns, THRUSTERS, effort=log.thrust_cmd[j]),
        WRENCH_ACHIEVED: lambda j, ns: m.wrench(ns, log.wrench_achieved[j]),
    }
    for i, ns in enumerate(plant_ns):
        yield ns, ODOM, m.odom(ns, log.position[i], log.quaternion[i], log.nu[i])
        yield ns, JOINT_STATES, m.joints(
            ns, TILTS + THRUSTERS, position=(*log.tilt_position[i], *ABSENT4),
            velocity=(*log.tilt_velocity[i], *ABSENT4), effort=(*ABSENT2, *log.thrust[i]))
        yield ns, CLOCK, m.clock(ns)
        while k < len(control_ns) and control_ns[k] <= ns:
            for topic in CONTROL_TOPICS:
                yield control_ns[k], topic, builders[topic](k, control_ns[k])
            k += 1
    for j in range(k, len(control_ns)):       # ticks after the last plant row
        for topic in CONTROL_TOPICS:
            yield control_ns[j], topic, builders[topic](j, control_ns[j])


def write_runlog_bag(log: RunLog, path: str | Path, *, namespace: str = '',
                     run_info: Mapping[str, Any] | None = None,
                     compression: str = 'none') -> Path:
    """Write ``log`` as the bag directory ``path`` (must not exist); return it.

    ``namespace`` prefixes the relative topics (``/clock`` stays global).
    """
    info = dict(run_info) if run_info is not None else {
        k: v for k, v in log.meta.items() if k != 'bag'}
    m = _Messages()
    serialize = m.store.serialize_cdr
    with BagWriter(path, compression=compression,
                   custom_data={RUN_INFO_KEY: json.dumps(info, sort_keys=True)}) as bag:
        topics = {rel: join_namespace(namespace, rel) for rel in (*PLANT_TOPICS,
                                                                   *CONTROL_TOPICS)}
        connections = {rel: bag.add_topic(name, STACK_TOPICS[rel])
                       for rel, name in topics.items()}
        for ns, rel, msg in _rows(log, m):
            bag.write(connections[rel], ns, serialize(msg, STACK_TOPICS[rel]))
    return Path(path)
