"""Restart without a jolt: the state a node hands to its successor, and the standby that
keeps it.

A node that ``tiltrov launch --respawn`` (or the launch file's ``respawn:=``) starts
again resumes from the state in force when its predecessor died, so that a lockstep run
with kills equals the run without them to the last bit:

* the controller's pid publishes ``pid_integral`` (sensor_msgs/JointState over x..yaw:
  positions the integral after the tick, efforts Ki times it), stamped with the tick,
  before the tick's ``wrench_cmd``;
* the allocator publishes ``tilt_target`` (sensor_msgs/JointState, stamped with the
  wrench it answered, before its answer): the tilts the servos are heading for while a
  travel is under way (robust mode's ``transit``), no joints otherwise; its commanded
  tilts are ``tilt_cmd``.

Both are reliable and transient local. A successor asked for tick t resumes from the
state after tick t - period (the predecessor may have answered t already: its state after
t is not the one to resume t from). What a killed process has not sent is lost with it,
so the state is kept by a *standby*: the same executable started ahead (kernels loaded,
rclpy up) as a node of its own name (``<node>_standby``, two nodes of one name confuse
``ros2 param``), reading the handoff topics. It is a node of the run's handshake (the
launchers name it among ``run_nodes``): the run starts, and resumes after a takeover,
only once it has matched the handoff's writers from both sides, so a node killed at
once still leaves its state kept. The launcher sends it SIGUSR1 when it sees the node's
process exit; it then builds the real node with what it kept (:class:`Handoff`), which
joins the run's handshake under the node's name, and starts a new standby.
"""

from __future__ import annotations

from collections.abc import Sequence
import functools
from typing import TYPE_CHECKING, Any

from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState

from tiltrov_ros.core.names import (
    DOF_NAMES,
    HANDOFF_TOPICS,
    PID_INTEGRAL,
    TILT_CMD,
    TILT_TARGET,
    TILTS,
    WRENCH_CMD,
    standby_name,
)
from tiltrov_ros.core.timebase import cdr_stamp_ns

from .base import RUN
from .handshake import Handshake
from .parameters import declare
from .qos import HANDOFF_QOS, RELIABLE_QOS

if TYPE_CHECKING:
    from rclpy.node import Node

#: Answers kept by stamp per topic (a successor needs the one before the tick it answers).
KEPT = 10
#: What each respawnable node hands over: topic -> type, read raw and kept by stamp.
TOPICS: dict[str, dict[str, Any]] = {
    'wrench_controller': {PID_INTEGRAL: JointState, WRENCH_CMD: WrenchStamped},
    'thrust_allocator': {TILT_TARGET: JointState, TILT_CMD: JointState},
    'reference_publisher': {},
}


class Handoff:
    """What a standby kept of its predecessor: per topic, the last :data:`KEPT` messages
    by stamp (raw CDR, decoded when used)."""

    def __init__(self) -> None:
        self.kept: dict[str, dict[int, bytes]] = {}

    def keep(self, topic: str, data: bytes) -> None:
        try:
            stamp = cdr_stamp_ns(data)
        except ValueError:
            return
        by_stamp = self.kept.setdefault(topic, {})
        by_stamp[stamp] = bytes(data)
        for old in sorted(by_stamp)[:-KEPT]:
            del by_stamp[old]

    def before(self, topic: str, ns: int, msg_type: Any) -> tuple[int, Any] | None:
        """The newest message of ``topic`` stamped before ``ns`` (stamp, decoded), or None."""
        from rclpy.serialization import deserialize_message

        stamps = [s for s in self.kept.get(topic, {}) if s < ns]
        if not stamps:
            return None
        stamp = max(stamps)
        return stamp, deserialize_message(self.kept[topic][stamp], msg_type)

    def __bool__(self) -> bool:
        return any(self.kept.values())


class Standby:
    """The standby's node: reads the handoff topics of ``node`` and keeps them, and joins
    the run's handshake (``run_nodes``, as the node would) once it reads them."""

    def __init__(self, node_name: str, context: Any, namespace: str | None = None) -> None:
        import rclpy

        self.handoff = Handoff()
        self.node: Node = rclpy.create_node(standby_name(node_name), context=context,
                                            namespace=namespace)
        for topic, msg_type in TOPICS.get(node_name, {}).items():
            qos = HANDOFF_QOS if topic in HANDOFF_TOPICS else RELIABLE_QOS
            self.node.create_subscription(msg_type, topic,
                                          functools.partial(self.handoff.keep, topic),
                                          qos, raw=True)
        self.handshake = Handshake(self.node, declare(self.node, RUN)['run_nodes'])
        self.handshake.start()


def pid_integral_message(ns: int, integral: Sequence[float], ki: Sequence[float]) -> JointState:
    """``pid_integral`` stamped ``ns``: positions the integral, efforts Ki times it."""
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    msg.name = list(DOF_NAMES)
    msg.position = [float(v) for v in integral]
    msg.effort = [float(k) * float(v) for k, v in zip(ki, integral)]
    return msg


def tilt_target_message(ns: int, target: Sequence[float] | None) -> JointState:
    """``tilt_target`` stamped ``ns``: the travel's target tilts, or no joints."""
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)
    if target is not None:
        msg.name = list(TILTS)
        msg.position = [float(target[0]), float(target[1])]
    return msg
