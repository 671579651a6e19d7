"""Messages <-> float arrays: the only place fields are copied in and out.

The nodes convert messages to float arrays exactly (float64 fields,
quaternions reordered from ROS (x, y, z, w) to the core's (w, x, y, z)), call
the core, and convert back. No arithmetic happens on the way, so the ROS
stack gives the numbers of the headless runner bit for bit (ARCHITECTURE.md,
"Time and stamps"). :func:`message_is_finite` is the check of every outgoing
message (no NaN or infinity on a topic).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
import math
from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from numpy.typing import NDArray
from sensor_msgs.msg import JointState

from tiltrov_ros.core import validation
from tiltrov_ros.core.names import FRAME_BODY, FRAME_EARTH
from tiltrov_ros.core.timebase import ns_to_stamp, stamp_to_ns

from .serialized import SerializedTemplate

FloatArray = NDArray[np.float64]



def stamp_ns(stamp: Time) -> int:
    """Integer ns of a ``builtin_interfaces/Time``."""
    return stamp_to_ns(stamp.sec, stamp.nanosec)


def set_stamp(stamp: Time, ns: int) -> None:
    """Write integer ns into a ``builtin_interfaces/Time`` in place."""
    stamp.sec, stamp.nanosec = ns_to_stamp(ns)



def _finite(values: Iterable[float]) -> bool:
    return all(math.isfinite(v) for v in values)


def odometry_arrays(msg: Odometry) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(position (3), quaternion (w, x, y, z) (4), nu (6)) of an ``odom`` message."""
    pose, twist = msg.pose.pose, msg.twist.twist
    p, o = pose.position, pose.orientation
    lin, ang = twist.linear, twist.angular
    return (np.array([p.x, p.y, p.z]), np.array([o.w, o.x, o.y, o.z]),
            np.array([lin.x, lin.y, lin.z, ang.x, ang.y, ang.z]))


def fill_odometry(msg: Odometry, ns: int, position: Sequence[float],
                  quaternion: Sequence[float], nu: Sequence[float]) -> Odometry:
    """Write a plant state into ``msg`` (reused between steps) and return it."""
    set_stamp(msg.header.stamp, ns)
    pose, twist = msg.pose.pose, msg.twist.twist
    pose.position.x, pose.position.y, pose.position.z = position
    o = pose.orientation
    o.w, o.x, o.y, o.z = quaternion
    twist.linear.x, twist.linear.y, twist.linear.z = nu[0:3]
    twist.angular.x, twist.angular.y, twist.angular.z = nu[3:6]
    return msg


def new_odometry() -> Odometry:
    msg = Odometry()
    msg.header.frame_id = FRAME_EARTH
    msg.child_frame_id = FRAME_BODY
    return msg


def pose_arrays(msg: PoseStamped) -> tuple[FloatArray, FloatArray]:
    """(position (3), quaternion (w, x, y, z) (4)) of a ``setpoint``."""
    p, o = msg.pose.position, msg.pose.orientation
    return np.array([p.x, p.y, p.z]), np.array([o.w, o.x, o.y, o.z])


def fill_pose(msg: PoseStamped, ns: int, position: Sequence[float],
              quaternion: Sequence[float]) -> PoseStamped:
    set_stamp(msg.header.stamp, ns)
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.w, o.x, o.y, o.z = (float(v) for v in quaternion)
    return msg


def twist_array(msg: TwistStamped) -> FloatArray:
    """d(eta_d)/dt (6) of a ``setpoint_velocity``: linear then angular."""
    lin, ang = msg.twist.linear, msg.twist.angular
    return np.array([lin.x, lin.y, lin.z, ang.x, ang.y, ang.z])


def fill_twist(msg: TwistStamped, ns: int, velocity: Sequence[float]) -> TwistStamped:
    set_stamp(msg.header.stamp, ns)
    lin, ang = msg.twist.linear, msg.twist.angular
    lin.x, lin.y, lin.z, ang.x, ang.y, ang.z = (float(v) for v in velocity)
    return msg


def wrench_array(msg: WrenchStamped) -> FloatArray:
    """(X, Y, Z, K, M, N) of a ``WrenchStamped``."""
    f, t = msg.wrench.force, msg.wrench.torque
    return np.array([f.x, f.y, f.z, t.x, t.y, t.z])


def fill_wrench(msg: WrenchStamped, ns: int, wrench: Sequence[float]) -> WrenchStamped:
    set_stamp(msg.header.stamp, ns)
    f, t = msg.wrench.force, msg.wrench.torque
    f.x, f.y, f.z, t.x, t.y, t.z = (float(v) for v in wrench)
    return msg


def new_wrench() -> WrenchStamped:
    msg = WrenchStamped()
    msg.header.frame_id = FRAME_BODY
    return msg


def joint_state_values(msg: JointState, required: Sequence[str], field: str,
                       allowed: Sequence[str] | None = None) -> list[float]:
    """Values of ``field`` (position, velocity or effort) for ``required``, by name.

    Checked by :func:`tiltrov_ros.core.validation.joint_values`: raises
    :class:`~tiltrov_ros.core.validation.InvalidInput` for an unknown, missing or
    repeated joint, an array of the wrong length or a non-finite value.
    """
    return validation.joint_values(
        list(msg.name), {'position': msg.position, 'velocity': msg.velocity,
                         'effort': msg.effort}, required, field, allowed)


def fill_joint_state(msg: JointState, ns: int, *, position: Sequence[float] = (),
                     velocity: Sequence[float] = (), effort: Sequence[float] = ()) -> JointState:
    set_stamp(msg.header.stamp, ns)
    msg.position = [float(v) for v in position]
    msg.velocity = [float(v) for v in velocity]
    msg.effort = [float(v) for v in effort]
    return msg


def new_joint_state(names: Sequence[str]) -> JointState:
    msg = JointState()
    msg.name = list(names)
    return msg


# --------------------------------------------------------------------------- serialized

#: A message's numbers as a template holds them, or None for a message it does not hold.
Values = Callable[[Any], Sequence[float] | None]


def _header_stamp(msg: Any) -> list[Time]:
    return [msg.header.stamp]


def wrench_template() -> tuple[SerializedTemplate, Values]:
    """A ``WrenchStamped`` in ``base_link_frd`` (:func:`new_wrench`) as a serialized template,
    and the numbers of such a message (X Y Z K M N)."""

    def values(msg: WrenchStamped) -> list[float] | None:
        if msg.header.frame_id != FRAME_BODY:
            return None
        f, t = msg.wrench.force, msg.wrench.torque
        return [f.x, f.y, f.z, t.x, t.y, t.z]

    return SerializedTemplate(WrenchStamped, lambda v, ns: fill_wrench(new_wrench(), ns, v),
                              _header_stamp, 6), values


def joint_template(names: Sequence[str], field: str) -> tuple[SerializedTemplate, Values]:
    """A ``JointState`` of ``names`` with ``field`` (position, velocity or effort) only, no
    frame, as a serialized template, and the numbers of such a message (``field``)."""
    expected = list(names)
    others = [f for f in ('position', 'velocity', 'effort') if f != field]

    def values(msg: JointState) -> Sequence[float] | None:
        numbers = getattr(msg, field)
        if (msg.header.frame_id or msg.name != expected or len(numbers) != len(expected)
                or any(len(getattr(msg, f)) for f in others)):
            return None
        return numbers      # type: ignore[no-any-return]

    return SerializedTemplate(
        JointState, lambda v, ns: fill_joint_state(new_joint_state(names), ns, **{field: v}),
        _header_stamp, len(expected)), values


# --------------------------------------------------------------------------- outgoing values


def _all_finite(*groups: Iterable[float]) -> bool:
    return all(all(map(math.isfinite, group)) for group in groups)


def _odometry_finite(m: Odometry) -> bool:
    p, o = m.pose.pose.position, m.pose.pose.orientation
    lin, ang = m.twist.twist.linear, m.twist.twist.angular
    return (_all_finite((p.x, p.y, p.z, o.x, o.y, o.z, o.w, lin.x, lin.y, lin.z,
                         ang.x, ang.y, ang.z))
            and bool(np.isfinite(m.pose.covariance).all())
            and bool(np.isfinite(m.twist.covariance).all()))


def _joint_state_finite(m: JointState) -> bool:
    return _all_finite(m.position, m.velocity, m.effort)


def _wrench_finite(m: WrenchStamped) -> bool:
    f, t = m.wrench.force, m.wrench.torque
    return _all_finite((f.x, f.y, f.z, t.x, t.y, t.z))


def _pose_finite(m: PoseStamped) -> bool:
    p, o = m.pose.position, m.pose.orientation
    return _all_finite((p.x, p.y, p.z, o.x, o.y, o.z, o.w))


def _twist_finite(m: TwistStamped) -> bool:
    lin, ang = m.twist.linear, m.twist.angular
    return _all_finite((lin.x, lin.y, lin.z, ang.x, ang.y, ang.z))


#: Message type -> "every float field is finite" (types without floats are not listed).
FINITE_CHECKS: dict[type, Callable[[Any], bool]] = {
    Odometry: _odometry_finite, JointState: _joint_state_finite,
    WrenchStamped: _wrench_finite, PoseStamped: _pose_finite, TwistStamped: _twist_finite,
}


def message_is_finite(msg: Any) -> bool:
    """True when no float field of ``msg`` is NaN or infinite (types of the stack)."""
    check = FINITE_CHECKS.get(type(msg))
    return True if check is None else check(msg)
