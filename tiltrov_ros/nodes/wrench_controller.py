"""``wrench_controller``: the core controllers (pd (16), switching, pid) as a ROS node.

At each control tick, i.e. on an ``odom`` whose stamp t_i is a multiple of
``control_period``, it calls ``controller.update(seconds(t_i), position,
quaternion, nu, reference)`` with the floats the messages carry and publishes
``wrench_cmd`` (frame ``base_link_frd``) stamped t_i. The switching baseline
also publishes ``tilt_request`` (tilt_front, tilt_rear positions) with the same
stamp, before the wrench (ARCHITECTURE.md, "The switching baseline").

The reference is the ``setpoint`` (and ``setpoint_velocity``, the feed-forward
d(eta_d)/dt; zero when ``use_setpoint_velocity`` is false):

* ``mode: lockstep``: the ones stamped t_i. The tick waits for them, however long
  (no wall-clock time changes a number): a wait longer than ``input_timeout`` is
  reported (log, ``/diagnostics`` ``waiting_for``), nothing more. Whether
  ``setpoint_velocity`` (and the pid's anti-windup input ``wrench_achieved``) is waited
  for is decided once, at the run's handshake (alone: at the first tick): yes if a node
  publishes it then, else it is read as zero (not used) for the whole run, said once.
* ``mode: realtime``: the latest received; with none yet, a zero wrench.

A repeated odom stamp (the plant re-publishes a stalled tick) re-publishes the
answer already given, so the controller's state advances once per tick; a stamp
earlier than the last answered (a restarted plant, a looped replay) resets the
controller.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import sys
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from nav_msgs.msg import Odometry
import numpy as np
from sensor_msgs.msg import JointState

from tiltrov_ros.core.controllers import (
    ControlOutput,
    PIDController,
    Reference,
    make_controller,
)
from tiltrov_ros.core.frames import enu_to_ned
from tiltrov_ros.core.names import (
    CONTROLLER,
    FRAME_EARTH,
    LOCKSTEP,
    ODOM,
    PID_INTEGRAL,
    SETPOINT,
    SETPOINT_VELOCITY,
    TILT_REQUEST,
    TILTS,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
)
from tiltrov_ros.core.timebase import cdr_stamp_ns, format_ns, seconds, to_ns
from tiltrov_ros.core.validation import (
    InvalidInput,
    check_finite,
    check_frame,
    check_quaternion,
)

from .achieved_input import AchievedInput
from .base import OK, WARN, TiltrovNode
from .controller_params import ControllerParameters
from .controller_waits import ControllerWaits
from .conversions import (
    FloatArray,
    fill_joint_state,
    fill_wrench,
    joint_template,
    new_joint_state,
    new_wrench,
    odometry_arrays,
    pose_arrays,
    stamp_ns,
    twist_array,
    wrench_template,
)
from .executors import main_loop
from .guard import THROTTLE, guarded, input_callback
from .handoff import HANDOFF_QOS, Handoff, pid_integral_message
from .parameters import Overrides
from .qos import PUBLISHER_QOS, RELIABLE_QOS, reader_qos
from .watchdog import InputWatchdog

#: s (wall): how often the lockstep watchdog looks at a waiting tick.
WATCHDOG_PERIOD = 0.1
#: Buffered setpoints (by stamp); older ones are dropped.
BUFFER = 200
@dataclass
class _Tick:
    """An odom at a control tick, waiting for its setpoint."""

    ns: int
    position: FloatArray
    quaternion: FloatArray
    nu: FloatArray
    since: int          # steady ns when it arrived


class WrenchController(ControllerParameters, ControllerWaits, AchievedInput, TiltrovNode):
    """The wrench controller (see the module docstring). ``handoff``: what a standby
    kept of the predecessor of this node (nodes/handoff.py): the pid resumes from it."""

    kernel_groups = ('control',)

    def __init__(self, *, node_name: str = CONTROLLER, namespace: str | None = None,
                 context: Any = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None, handoff: Handoff | None = None
                 ) -> None:
        super().__init__(node_name, namespace=namespace, context=context, cli_args=cli_args,
                         parameter_overrides=parameter_overrides)
        self.handoff = handoff
        self.resumed_from: int | None = None      # the predecessor's tick resumed from
        self._declare_parameters()
        self.period_ns = to_ns(self.control_period)
        self.controller = make_controller(self.controller_config, self.robot)
        self.kind = self.controller_config.kind
        self.lockstep = self.mode == LOCKSTEP

        # Guarded: a non-finite wrench goes out as zero, a non-finite tilt request as
        # the last finite one.
        self._wrench_pub = self.create_safe_publisher(
            WrenchStamped, WRENCH_CMD, PUBLISHER_QOS,
            lambda msg: fill_wrench(new_wrench(), stamp_ns(msg.header.stamp), np.zeros(6)))
        self._tilt_pub = (self.create_safe_publisher(
            JointState, TILT_REQUEST, PUBLISHER_QOS,
            lambda msg: fill_joint_state(new_joint_state(TILTS), stamp_ns(msg.header.stamp),
                                         position=self._safe_tilts))
            if self.kind == 'switching' else None)
        # The pid's handoff to a successor (nodes/handoff.py), before each wrench.
        self._integral_pub = (self.create_safe_publisher(JointState, PID_INTEGRAL, HANDOFF_QOS)
                              if self.kind == 'pid' else None)
        # The answers go out as serialized templates (nodes/serialized.py).
        self._wrench_pub.serialize_as(*wrench_template())
        if self._tilt_pub is not None:
            self._tilt_pub.serialize_as(*joint_template(TILTS, 'position'))
        # Raw: only the odometry at control ticks (1 in control_period / step_size) is
        # deserialized (bytes that do not decode are rejected: malformed); the stamp of
        # the others is read from the CDR header.
        self.create_subscription(Odometry, ODOM, self._on_odom_raw, reader_qos(self.mode),
                                 raw=True)
        self.expect_single_source(ODOM)
        self.create_input_subscription(PoseStamped, SETPOINT, self._on_setpoint, RELIABLE_QOS)
        if self.use_velocity:
            self.create_input_subscription(TwistStamped, SETPOINT_VELOCITY, self._on_velocity,
                                           RELIABLE_QOS)

        self.init_achieved_input()
        #: lockstep: the inputs a tick waits for besides the setpoint, decided once at the
        #: handshake (alone: the first tick); None: not decided yet.
        self._waits_for: frozenset[str] | None = None
        self._setpoints: dict[int, tuple[FloatArray, FloatArray]] = {}
        self._velocities: dict[int, FloatArray] = {}
        self._latest_setpoint: tuple[int, FloatArray, FloatArray] | None = None
        self._latest_velocity: tuple[int, FloatArray] | None = None
        self._tick: _Tick | None = None
        self._last_ns = -1
        self._last_msgs: tuple[WrenchStamped, JointState | None] | None = None
        self._last_tilts: tuple[float, float] = (0.0, 0.0)
        self._safe_tilts: tuple[float, float] = (0.0, 0.0)    # the last finite request
        self._warned_tick = -1
        self.ticks = 0
        self.republished = 0
        self.no_setpoint = 0
        self.safe_answers = 0
        self.resets = 0
        self.input_waits = 0
        self.last_mode = ''
        self.odom_watchdog = InputWatchdog(
            self, ODOM, 'odom_timeout', 'publishing a zero wrench until fresh odometry returns',
            'control resumes')
        self.watchdog_outputs = 0

        if self.lockstep:
            self.create_timer(WATCHDOG_PERIOD, self._watchdog, clock=self.steady)
        else:
            # In lockstep the plant does not advance without the loop: sim time never
            # runs ahead of odom, and a wrench for a tick not reached would break the
            # run's determinism; the plant reports the stall.
            self.create_timer(self.control_period, self._odom_watchdog, clock=self.steady)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.join_run()
        self.get_logger().info(f'{self.kind} controller, {self.mode}, odometry in '
                               f'{"ENU/FLU" if self.enu else "NED/FRD"}, control period '
                               f'{self.control_period:g} s')

    # -- parameters ------------------------------------------------------------------

    # -- inputs ----------------------------------------------------------------------

    @guarded
    def _on_odom_raw(self, data: bytes) -> None:
        try:
            stamp = cdr_stamp_ns(data)
        except ValueError:        # too short to hold a stamp
            self.reject_malformed(ODOM, Odometry, data)
            return
        if stamp % self.period_ns == 0:
            msg = self.decode(Odometry, ODOM, data)
            if msg is not None:
                self.on_odom(msg)

    @input_callback(ODOM)
    def on_odom(self, msg: Odometry) -> None:
        """An odometry message (the raw callback passes those at control ticks)."""
        ns = self.check_header(msg.header, self.odom_frames[0])
        if ns % self.period_ns:
            return
        # Validated whole before it may act: a rejected message changes nothing.
        check_frame(msg.child_frame_id, self.odom_frames[1], 'child_frame_id')
        position, quaternion, nu = odometry_arrays(msg)
        check_finite(position, 'position')
        check_quaternion(quaternion)
        check_finite(nu, 'twist')
        if self.enu:            # the core's convention from here on
            position, quaternion, nu = enu_to_ned(position, quaternion, nu)
        if ns == self._last_ns and self._last_msgs is not None:
            self.republished += 1
            self._publish(*self._last_msgs)
            return
        if self.run_end_ns is not None and ns >= self.run_end_ns:
            return      # the run's last state: no tick answers it (nor the headless runner)
        if ns < self._last_ns:
            self._reset(f'odometry went back from {format_ns(self._last_ns)} to '
                        f'{format_ns(ns)}')
        now = self.steady_ns()
        self.odom_watchdog.fresh(ns, now)
        self._tick = _Tick(ns, position, quaternion, nu, now)
        self._try_compute()

    @input_callback(SETPOINT)
    def _on_setpoint(self, msg: PoseStamped) -> None:
        ns = self.check_header(msg.header, FRAME_EARTH)
        position, quaternion = pose_arrays(msg)
        check_finite(position, 'position')
        check_quaternion(quaternion)
        self._setpoints[ns] = (position, quaternion)
        self._latest_setpoint = (ns, position, quaternion)
        _trim(self._setpoints)
        self._try_compute()

    @input_callback(SETPOINT_VELOCITY)
    def _on_velocity(self, msg: TwistStamped) -> None:
        ns = self.check_header(msg.header, FRAME_EARTH)
        velocity = twist_array(msg)
        check_finite(velocity, 'twist')
        self._velocities[ns] = velocity
        self._latest_velocity = (ns, velocity)
        _trim(self._velocities)
        self._try_compute()

    # -- the tick --------------------------------------------------------------------

    def _try_compute(self) -> None:
        tick = self._tick
        if tick is None:
            return
        ns = tick.ns
        if self.lockstep:
            waits = self._decide_inputs()
            setpoint = self._setpoints.get(ns)
            if setpoint is None:
                return
            velocity = (self._velocities.get(ns) if SETPOINT_VELOCITY in waits
                        else np.zeros(6))
            if velocity is None:
                return
            if WRENCH_ACHIEVED in waits and self.waits_for_achieved(ns):
                return
        else:
            if self._latest_setpoint is None:
                self._tick = None
                self.no_setpoint += 1
                if self.handoff is not None:
                    # A respawned controller before its first setpoint: a zero wrench
                    # would be a command (zero thrust); silent, it leaves the
                    # predecessor's last one held (respawn_hold).
                    self.get_logger().warning(
                        'respawned: no setpoint received yet: publishing nothing, the '
                        "predecessor's last wrench holds meanwhile (respawn_hold)",
                        throttle_duration_sec=THROTTLE)
                    return
                self.get_logger().warning('no setpoint received yet: publishing a zero wrench',
                                          throttle_duration_sec=THROTTLE)
                self._publish_safe(ns)
                return
            sp_ns, position, quaternion = self._latest_setpoint
            setpoint = (position, quaternion)
            velocity = self._velocities.get(sp_ns) if self.use_velocity else None
            if velocity is None:
                velocity = (self._latest_velocity[1] if self.use_velocity
                            and self._latest_velocity is not None else np.zeros(6))
        self._tick = None
        if self.handoff is not None:
            self._resume(ns)
        reference = Reference(setpoint[0], setpoint[1], velocity)
        out = self.controller.update(seconds(ns), tick.position, tick.quaternion, tick.nu,
                                     reference, achieved=self.achieved_of_last())
        self._answer(ns, out)
        for buffer in (self._setpoints, self._velocities):
            for stamp in [s for s in buffer if s < ns]:
                del buffer[stamp]

    def _answer(self, ns: int, out: ControlOutput) -> None:
        wrench = fill_wrench(new_wrench(), ns, out.wrench)
        if self._integral_pub is not None and isinstance(self.controller, PIDController):
            self._integral_pub.publish(pid_integral_message(
                ns, self.controller.integral, self.controller.gains.ki))
        tilt_msg = None
        if self._tilt_pub is not None:
            tilts = out.tilt_request if out.tilt_request is not None else self._last_tilts
            self._last_tilts = (float(tilts[0]), float(tilts[1]))
            if all(np.isfinite(self._last_tilts)):
                self._safe_tilts = self._last_tilts
            tilt_msg = fill_joint_state(new_joint_state(TILTS), ns, position=self._last_tilts)
        self.ticks += 1
        self.last_mode = out.mode
        self._last_ns = ns
        self._last_msgs = (wrench, tilt_msg)
        self._publish(wrench, tilt_msg)

    def _publish(self, wrench: WrenchStamped, tilt_msg: JointState | None) -> None:
        if tilt_msg is not None and self._tilt_pub is not None:
            self._tilt_pub.publish(tilt_msg)
        self._wrench_pub.publish(wrench)

    def _publish_safe(self, ns: int) -> None:
        """A zero wrench (and the tilts last requested) stamped ``ns``."""
        self.safe_answers += 1
        self._answer(ns, ControlOutput(np.zeros(6), self._safe_tilts, 'safe'))

    def on_rejected(self, topic: str, bad: InvalidInput, stamp: int | None) -> None:
        """A rejected odometry tick with a valid stamp, later than the last answered and
        not waiting, is answered with a zero wrench (the state is unknown; the plant waits for that
        stamp in lockstep), stamped no later than the node's clock (:meth:`safe_stamp`)
        and not kept as the tick's answer: a valid odometry of the tick afterwards is
        answered as usual, and nothing else changes."""
        if (topic != ODOM or stamp is None or stamp % self.period_ns
                or stamp <= self._last_ns or (self._tick is not None and self._tick.ns == stamp)):
            return
        seen = self.odom_watchdog.seen
        self.safe_answers += 1
        ns = self.safe_stamp(stamp, seen[0] if seen else None, self.period_ns)
        if not self.lockstep and seen is not None:
            # Realtime: /clock runs ahead of the odometry still on its way; stamped no
            # later than the newest valid odom, the answer cannot overtake the next
            # real tick (the allocator would take that one for a stamp going back).
            ns = min(ns, seen[0])
        self._publish_zero(ns)

    def _publish_zero(self, ns: int) -> None:
        """A zero wrench (and the last finite tilt request) stamped ``ns``, not kept as
        the answer of a tick."""
        self._publish(fill_wrench(new_wrench(), ns, np.zeros(6)),
                      None if self._tilt_pub is None else fill_joint_state(
                          new_joint_state(TILTS), ns, position=self._safe_tilts))

    @guarded
    def _odom_watchdog(self) -> None:
        """realtime: a zero wrench while odom is stale (not cached: the next fresh
        tick is computed as usual)."""
        seen = self.odom_watchdog.expired(self.odom_timeout)
        if seen is None:
            return
        self.watchdog_outputs += 1
        self._publish_zero(self.estimated_now_ns(*seen, self.period_ns))

    def _reset(self, why: str) -> None:
        self.resets += 1
        self.get_logger().info(f'{why}: resetting the controller')
        self.controller.reset()
        self._setpoints.clear()
        self._velocities.clear()
        self._last_ns = -1
        self._last_msgs = None

    def on_callback_error(self, callback: str, exc: Exception) -> None:
        super().on_callback_error(callback, exc)
        tick, self._tick = self._tick, None
        if tick is not None and tick.ns != self._last_ns:
            self._publish_safe(tick.ns)

    # -- diagnostics -----------------------------------------------------------------

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        level, message = OK, f'{self.kind}: {self.ticks} ticks'
        tick = self._tick
        if self.odom_watchdog.stale:
            level = WARN
            message = (f'odom stale (older than odom_timeout {self.odom_timeout:g} s): '
                       'publishing a zero wrench')
        elif (tick is not None and self.lockstep
                and seconds(self.steady_ns() - tick.since) >= self.input_timeout):
            level = WARN
            message = (f'waiting for the {" and ".join(self.missing_inputs(tick.ns))} '
                       f'stamped {format_ns(tick.ns)}')
        elif self.no_setpoint:
            level = WARN
            message += f'; {self.no_setpoint} tick(s) without setpoint'
        waiting = (', '.join(self.missing_inputs(tick.ns))
                   if tick is not None and self.lockstep else '')
        return level, message, {
            'controller': self.kind, 'mode': self.mode, 'ticks': self.ticks,
            'last_tick': seconds(max(self._last_ns, 0)), 'control_mode': self.last_mode,
            'republished': self.republished, 'input_waits': self.input_waits,
            'waiting_for': waiting,
            'waits_for': sorted(self._waits_for) if self._waits_for is not None else '',
            'ticks_without_setpoint': self.no_setpoint, 'safe_answers': self.safe_answers,
            'resets': self.resets, 'odom_stale': self.odom_watchdog.stale,
            'odom_stale_events': self.odom_watchdog.events,
            'watchdog_zero_wrenches': self.watchdog_outputs,
            'resumed_from': seconds(self.resumed_from) if self.resumed_from is not None else '',
        }


def _trim(buffer: dict[int, Any]) -> None:
    if len(buffer) > BUFFER:
        for stamp in sorted(buffer)[:len(buffer) - BUFFER]:
            del buffer[stamp]


def main(args: list[str] | None = None) -> int:
    """``wrench_controller [--ros-args --params-file config/wrench_controller.yaml ...]``."""
    return main_loop(WrenchController, args, CONTROLLER)


if __name__ == '__main__':
    sys.exit(main())
