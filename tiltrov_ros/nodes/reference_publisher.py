"""``reference_publisher``: plays a scenario's reference on ``setpoint`` and ``setpoint_velocity``.

At every control tick t_k (a multiple of ``control_period``) it publishes
``setpoint_velocity`` (the feed-forward d(eta_d)/dt: linear = d(x, y, z)/dt,
angular = d(roll, pitch, yaw)/dt) and then ``setpoint`` (eta_d as a pose),
both in frame ``odom_ned`` and stamped exactly t_k, from
``ReferenceProfile.at(seconds(t_k))``: the floats the headless runner gives the
controller.

* On sim time (``use_sim_time``), ticks come from ``/clock``, read by the node
  itself (reliable, deep queue): for each clock message it publishes every
  tick crossed since the last one (at most ``max_catch_up``, the latest ones),
  so nothing depends on how often the clock ticks. A clock equal to the last
  tick published (the plant re-publishes a stalled tick) publishes that tick
  again; a clock that goes back starts over.
* On wall time, a timer at ``control_period`` publishes the reference at the
  time elapsed since the node started, stamped with the node's clock.

With ``duration`` > 0 only ticks t_k < duration are published: the runner's
last control tick is the last step before the end.
"""

from __future__ import annotations

from collections.abc import Sequence
import sys
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped
from rosgraph_msgs.msg import Clock as ClockMsg

from tiltrov_ros.core.names import (
    CLOCK,
    FRAME_EARTH,
    REFERENCE,
    SETPOINT,
    SETPOINT_VELOCITY,
)
from tiltrov_ros.core.paramtable import Param, ParamTable
from tiltrov_ros.core.scenarios import ReferenceProfile, load_scenario
from tiltrov_ros.core.timebase import format_ns, seconds, to_ns
from tiltrov_ros.core.validation import checked_stamp_ns

from .base import OK, WARN, TiltrovNode
from .conversions import fill_pose, fill_twist, stamp_ns
from .executors import main_loop
from .guard import THROTTLE, guarded, input_callback
from .parameters import Overrides, check, declare, declare_robot
from .qos import CLOCK_READER_QOS, PUBLISHER_QOS
from .serialized import SerializedTemplate

#: The reference publisher's own parameters (besides the robot and wait_for_recorder).
REFERENCE_PARAMS = ParamTable('reference_publisher', [
    Param('scenario', 'str', '', 'scenario name (config/scenarios/<name>.yaml) or path whose '
          'reference is played; empty: hold the origin (eta_d = 0)', read_only=True),
    Param('duration', 'float', 0.0, 'publish ticks before this sim time only; 0: no end', 's',
          low=0.0, high=1e9, read_only=True),
    Param('max_catch_up', 'int', 100, 'most ticks published for one /clock message (the '
          'latest ones)', low=1, high=1_000_000),
])
#: eta_d = 0 for ever: the reference without a scenario.
HOLD_ORIGIN = ReferenceProfile(((),) * 6)


def _setpoint_message(values: Any, ns: int) -> PoseStamped:
    """``setpoint`` of (position (3), quaternion (w, x, y, z)) stamped ``ns``."""
    msg = PoseStamped()
    msg.header.frame_id = FRAME_EARTH
    return fill_pose(msg, ns, values[:3], values[3:7])


def _velocity_message(values: Any, ns: int) -> TwistStamped:
    """``setpoint_velocity`` of d(eta_d)/dt (6) stamped ``ns``."""
    msg = TwistStamped()
    msg.header.frame_id = FRAME_EARTH
    return fill_twist(msg, ns, values)


class ReferencePublisher(TiltrovNode):
    """Publishes the reference at every control tick (see the module docstring)."""

    reads_clock = True      # its own /clock reader counts bad samples, sets the node's clock

    def __init__(self, *, node_name: str = REFERENCE, namespace: str | None = None,
                 context: Any = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None) -> None:
        super().__init__(node_name, namespace=namespace, context=context, cli_args=cli_args,
                         parameter_overrides=parameter_overrides)
        own = declare(self, REFERENCE_PARAMS)
        _, period = declare_robot(self)
        self.check_overrides()
        own = check(REFERENCE_PARAMS, own)
        self.scenario = own['scenario']
        self.max_catch_up = own['max_catch_up']
        self.period_ns = to_ns(period)
        self.duration_ns = to_ns(own['duration'])
        self.profile = (load_scenario(self.scenario).reference if self.scenario
                        else HOLD_ORIGIN)
        self.sim_time = bool(self.get_parameter('use_sim_time').value)

        # Guarded: a non-finite reference goes out as the last finite setpoint, held
        # (zero feed-forward).
        self._last_good: tuple[tuple[float, ...], tuple[float, ...]] = (
            (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0))
        self._velocity_pub = self.create_safe_publisher(
            TwistStamped, SETPOINT_VELOCITY, PUBLISHER_QOS,
            lambda msg: fill_twist(TwistStamped(header=msg.header), stamp_ns(msg.header.stamp),
                                   (0.0,) * 6))
        self._setpoint_pub = self.create_safe_publisher(
            PoseStamped, SETPOINT, PUBLISHER_QOS,
            lambda msg: fill_pose(PoseStamped(header=msg.header), stamp_ns(msg.header.stamp),
                                  *self._last_good))
        # Both go out as serialized templates rewritten in place (nodes/serialized.py).
        self._pose_bytes = SerializedTemplate(PoseStamped, _setpoint_message,
                                              lambda msg: [msg.header.stamp], 7)
        self._twist_bytes = SerializedTemplate(TwistStamped, _velocity_message,
                                               lambda msg: [msg.header.stamp], 6)
        self._last_tick: int | None = None
        self.published = 0
        self.skipped = 0
        self.restarts = 0
        if self.sim_time:
            self.create_input_subscription(ClockMsg, CLOCK, self._on_clock, CLOCK_READER_QOS)
        else:
            self._start_ns = self.get_clock().now().nanoseconds
            self.create_timer(seconds(self.period_ns), self._on_timer)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.join_run()
        self.get_logger().info(
            f'reference of {self.scenario or "(hold the origin)"} every '
            f'{seconds(self.period_ns):g} s on {"/clock" if self.sim_time else "wall time"}'
            f'{f" until {format_ns(self.duration_ns)}" if self.duration_ns else ""}')

    def _apply_parameters(self, parameters: list[Any]) -> None:
        for p in parameters:
            if p.name == 'max_catch_up':
                self.max_catch_up = int(p.value)

    def publish_tick(self, stamp: int, t: float) -> None:
        """Publish the reference at scenario time ``t`` (s) stamped ``stamp`` (ns)."""
        ref = self.profile.at(t)
        self._velocity_pub.publish_serialized(self._twist_bytes, stamp, ref.velocity)
        if self._setpoint_pub.publish_serialized(self._pose_bytes, stamp,
                                                 (*ref.position, *ref.quaternion)):
            self._last_good = (tuple(ref.position), tuple(ref.quaternion))
        self.published += 1

    @input_callback(CLOCK)
    def _on_clock(self, msg: ClockMsg) -> None:
        ns = checked_stamp_ns(msg.clock.sec, msg.clock.nanosec)
        self.time_source.clock_callback(msg)    # the node's clock: it has no reader of its own
        last = self._last_tick
        if last is not None and ns < last:
            self.restarts += 1
            self.get_logger().info(f'/clock went back from {format_ns(last)} to '
                                   f'{format_ns(ns)}: starting over')
            last = None
        period = self.period_ns
        if last is None:
            first = ns - ns % period
        elif ns == last:
            first = last            # a repeated tick (stalled plant): publish it again
        else:
            first = last + period
        end = ns + 1 if not self.duration_ns else min(ns + 1, self.duration_ns)
        ticks = range(first, end, period)
        if len(ticks) > self.max_catch_up:
            self.skipped += len(ticks) - self.max_catch_up
            self.get_logger().warning(f'/clock jumped by {len(ticks)} ticks: publishing the '
                                      f'latest {self.max_catch_up}',
                                      throttle_duration_sec=THROTTLE)
            ticks = ticks[-self.max_catch_up:]
        for tick in ticks:
            self.publish_tick(tick, seconds(tick))
            self._last_tick = tick
        if last is None and not ticks:
            self._last_tick = None

    @guarded
    def _on_timer(self) -> None:
        now = self.get_clock().now().nanoseconds
        elapsed = now - self._start_ns
        if self.duration_ns and elapsed >= self.duration_ns:
            return
        self.publish_tick(now, seconds(elapsed))

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        level = WARN if self.skipped else OK
        last = self._last_tick
        return level, (f'{self.published} setpoints published'
                       + (f', last at {format_ns(last)}' if last is not None else '')), {
            'scenario': self.scenario, 'time_source': '/clock' if self.sim_time else 'wall',
            'published': self.published, 'skipped_ticks': self.skipped,
            'restarts': self.restarts,
        }


def main(args: list[str] | None = None) -> int:
    """``reference_publisher [--ros-args --params-file config/reference_publisher.yaml ...]``."""
    return main_loop(ReferencePublisher, args, REFERENCE)


if __name__ == '__main__':
    sys.exit(main())
