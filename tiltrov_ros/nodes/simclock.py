"""Sim time that survives any ``/clock`` sample: rclpy's time source with its input checked.

rclpy's ``TimeSource`` converts every ``/clock`` message inside its own
subscription callback, outside the node's guarded callbacks: a sample with a
negative ``sec`` raises there and stops the executor (every node in the
process with it). :class:`CheckedTimeSource` checks each sample first, as the
nodes check every input (``core/validation.py``):

* a malformed sample (``sec < 0`` or ``nanosec >= 1e9``) is rejected: counted
  on ``/diagnostics`` (``rejected./clock.bad_stamp``), logged (throttled), and
  the node's clock stays where it was; so are bytes that do not decode as a
  ``rosgraph_msgs/Clock`` (``rejected./clock.malformed``: the subscription is
  raw and the node decodes it, rclpy's typed one would drop them unseen);
* a sample earlier than the previous one is accepted: time starts over (a
  restarted simulator, a looped replay; rclpy and rclcpp do the same). It is
  counted (``clock_jumps_back``) and logged, and the nodes' own "stamp went
  back" logic handles what follows (the controller and the allocator start
  afresh when their inputs go back too).

:func:`install` replaces a node's time source by this one (same subscription,
same clocks); :class:`~tiltrov_ros.nodes.base.TiltrovNode` does it for every
node of the package. A node that reads ``/clock`` itself (``reads_clock``: the
reference publisher) hands each valid sample to :meth:`CheckedTimeSource.clock_callback`
from its own reader, and the time source subscribes to nothing: each sample is
taken once per node. Samples are decoded by a
:class:`~tiltrov_ros.nodes.serialized.MessageReader` (no message object per sample).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.time_source import TimeSource
from rosgraph_msgs.msg import Clock as ClockMsg

from tiltrov_ros.core.names import CLOCK
from tiltrov_ros.core.timebase import format_ns
from tiltrov_ros.core.validation import InvalidInput, checked_stamp_ns

from .serialized import MessageReader

if TYPE_CHECKING:
    from .base import TiltrovNode

#: s: a jump back of /clock is logged at most once per this period.
JUMP_LOG_PERIOD = 5.0


class CheckedTimeSource(TimeSource):
    """rclpy's TimeSource, with every /clock sample checked before it sets the time."""

    def __init__(self, node: TiltrovNode) -> None:
        self._owner = node
        self.last_ns: int | None = None
        self.jumps_back = 0
        self._reader = MessageReader(ClockMsg)
        super().__init__(node=node)

    def _subscribe_to_clock_topic(self) -> None:
        """rclpy's subscription (same topic and QoS: the latest sample, best effort), but
        raw: the node decodes each sample (:meth:`TiltrovNode.decode`), so bytes that
        do not decode are rejected and counted instead of dropped unseen. None for a
        node that reads /clock itself (``reads_clock``): its reader hands each valid
        sample to :meth:`clock_callback`, so each sample is taken once."""
        node = self._get_node()
        if self._clock_sub is None and node is not None and not self._owner.reads_clock:
            self._clock_sub = node.create_subscription(
                ClockMsg, CLOCK, self._on_clock_bytes,
                QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT), raw=True)

    def _on_clock_bytes(self, data: bytes) -> None:
        node = self._owner
        try:
            msg = self._reader.read(data)
        except Exception:   # rclpy's RMWError: not a Clock
            if not node.reads_clock:       # else the node's own /clock reader counts it
                node.reject_malformed(CLOCK, ClockMsg, data)
            return
        self.clock_callback(msg)

    def clock_callback(self, msg: Any) -> None:
        node = self._owner
        try:
            ns = checked_stamp_ns(msg.clock.sec, msg.clock.nanosec)
        except InvalidInput as bad:
            if not node.reads_clock:       # else the node's own /clock reader counts it
                node.reject_input(CLOCK, bad)
            return
        except Exception as exc:  # nothing a sample holds may stop the executor
            node.callback_errors += 1
            node.get_logger().error(f'/clock sample not usable: {exc!r}',
                                    throttle_duration_sec=JUMP_LOG_PERIOD)
            return
        if self.last_ns is not None and ns < self.last_ns:
            self.jumps_back += 1
            node.get_logger().warning(
                f'/clock went back from {format_ns(self.last_ns)} to {format_ns(ns)} '
                f'({self.jumps_back} time(s) so far): time starts over',
                throttle_duration_sec=JUMP_LOG_PERIOD)
        self.last_ns = ns
        super().clock_callback(msg)


def install(node: TiltrovNode) -> CheckedTimeSource:
    """Replace ``node``'s time source (built by rclpy's Node) by a :class:`CheckedTimeSource`:
    the old one's /clock subscription and parameter callback go, the node's clock is
    attached to the new one, which subscribes to /clock when ``use_sim_time`` is set."""
    old = node._time_source
    old.detach_node()
    node.remove_on_set_parameters_callback(old._on_parameter_event)
    new = CheckedTimeSource(node)
    new.attach_clock(node.get_clock())
    node._time_source = new
    return new
