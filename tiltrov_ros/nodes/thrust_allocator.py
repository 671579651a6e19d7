"""``thrust_allocator``: :class:`tiltrov_ros.core.allocation.ThrustAllocator` as a ROS node.

For each ``wrench_cmd`` it publishes ``wrench_achieved`` (eq. (4) of its
answer), ``tilt_cmd`` and ``thrust_cmd``, all stamped with the wrench's stamp
(in that order: the plant advances on the last two). ``previous`` is the last
answer, so the tilts move least and at most ``max_tilt_step`` per call.

The switching baseline fixes the tilts itself through ``tilt_request``
(parameter ``tilt_request``: ``auto``, ``required``, ``ignored``; how requests
pair with wrenches: nodes/tilt_request.py).

``/diagnostics`` says "steady demand out of the servo range's reach" (WARN) when the
core's :class:`~tiltrov_ros.core.steady.HoldMonitor` finds so (all four thrusters):
reach only, not a verdict on holding (metrics.json's ``hold``, after the run).

The launcher sets ``required`` for the switching controller and ``ignored``
otherwise. A repeated wrench stamp re-publishes the cached answer without
allocating again (so re-publication is idempotent and ``previous`` does not
move); an earlier stamp (a restarted plant, a looped replay) forgets
``previous``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
import math
import sys
from typing import Any

from geometry_msgs.msg import WrenchStamped
import numpy as np
from sensor_msgs.msg import JointState

from tiltrov_ros.core.allocation import (
    AllocationResult,
    from_tilts,
)
from tiltrov_ros.core.names import (
    ALLOCATOR,
    FRAME_BODY,
    JOINT_STATES,
    THRUST_CMD,
    THRUSTERS,
    TILT_CMD,
    TILT_REQUEST,
    TILT_TARGET,
    TILTS,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
    WRENCH_DOFS,
)
from tiltrov_ros.core.timebase import format_ns, seconds
from tiltrov_ros.core.validation import (
    MAX_WRENCH,
    check_finite,
    clip_wrench,
    limit_command,
)

from .allocator_params import AllocatorParameters
from .allocator_safety import AllocatorSafety, thruster_names
from .base import OK, WARN, TiltrovNode
from .conversions import (
    FloatArray,
    fill_joint_state,
    fill_wrench,
    joint_state_values,
    joint_template,
    new_joint_state,
    new_wrench,
    stamp_ns,
    wrench_array,
    wrench_template,
)
from .executors import main_loop
from .guard import THROTTLE, input_callback
from .handoff import HANDOFF_QOS, Handoff, tilt_target_message
from .parameters import Overrides
from .qos import ANSWERED_READER_QOS, PUBLISHER_QOS, RELIABLE_QOS
from .tilt_request import TiltRequests, keep_bounded
from .watchdog import InputWatchdog

#: s (wall): how often a wrench waiting for its tilt request is looked at.
WATCHDOG_PERIOD = 0.1


class ThrustAllocatorNode(AllocatorParameters, AllocatorSafety, TiltRequests, TiltrovNode):
    """The thrust allocator (see the module docstring)."""

    kernel_groups = ('allocation',)

    def __init__(self, *, node_name: str = ALLOCATOR, namespace: str | None = None,
                 context: Any = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None, handoff: Handoff | None = None
                 ) -> None:
        super().__init__(node_name, namespace=namespace, context=context, cli_args=cli_args,
                         parameter_overrides=parameter_overrides)
        #: What a standby kept of this node's predecessor (nodes/handoff.py).
        self.handoff = handoff
        self.resumed_from: int | None = None
        self._declare_parameters()
        self.failed: tuple[int, ...] = ()       # failed thrusters the allocator knows
        self.allocator = self.allocator_config.build(self.robot, self.control_period)
        self._new_hold_monitor()
        self._use_failed(self._wanted_failed(None), 'at start-up')

        # Guarded: a non-finite message is replaced by the same part of the safe answer.
        self._achieved_pub = self.create_safe_publisher(
            WrenchStamped, WRENCH_ACHIEVED, PUBLISHER_QOS,
            lambda msg: self._safe_msgs(stamp_ns(msg.header.stamp))[0])
        self._tilt_pub = self.create_safe_publisher(
            JointState, TILT_CMD, PUBLISHER_QOS,
            lambda msg: self._safe_msgs(stamp_ns(msg.header.stamp))[1])
        self._thrust_pub = self.create_safe_publisher(
            JointState, THRUST_CMD, PUBLISHER_QOS,
            lambda msg: self._safe_msgs(stamp_ns(msg.header.stamp))[2])
        # The servo travel under way, for a successor (nodes/handoff.py), before each answer.
        self._target_pub = self.create_safe_publisher(JointState, TILT_TARGET, HANDOFF_QOS)
        # The answers go out as serialized templates (nodes/serialized.py).
        self._achieved_pub.serialize_as(*wrench_template())
        self._tilt_pub.serialize_as(*joint_template(TILTS, 'position'))
        self._thrust_pub.serialize_as(*joint_template(THRUSTERS, 'effort'))
        self.create_input_subscription(WrenchStamped, WRENCH_CMD, self._on_wrench,
                                       ANSWERED_READER_QOS)
        if self.tilt_request_mode != 'ignored':
            self.create_input_subscription(JointState, TILT_REQUEST, self._on_tilt_request,
                                           ANSWERED_READER_QOS)
            self.create_timer(WATCHDOG_PERIOD, self._watchdog, clock=self.steady)
        #: tilt_source measured: joint_states tilts by stamp; the last received; wrenches
        #: that started from an earlier measurement than their own stamp, or from none.
        self._measured: dict[int, tuple[float, float]] = {}
        self._latest_measured: tuple[int, tuple[float, float]] | None = None
        self.measured_late = 0
        if self.measured_tilts:
            self.create_input_subscription(JointState, JOINT_STATES, self._on_joint_states,
                                           RELIABLE_QOS)

        self.previous: AllocationResult | None = None
        self._last_ns = -1
        self._last_msgs: tuple[WrenchStamped, JointState, JointState] | None = None
        self.init_tilt_requests()
        self.ticks = 0
        self.feasible = 0
        self.infeasible = 0
        self.saturated = 0
        self.methods: Counter[str] = Counter()
        self.max_error = 0.0
        self.republished = 0
        self.out_of_limits = 0
        self.safe_answers = 0
        self.clipped = 0
        self._handling: int | None = None     # stamp of the wrench being handled
        self.resets = 0
        self.wrench_watchdog = InputWatchdog(
            self, WRENCH_CMD, 'wrench_timeout',
            'commanding zero thrust until a fresh one comes', 'allocation resumes')
        self.watchdog_outputs = 0
        #: Ticks short of the wrench beyond ``wrench_tolerance``, in all and per
        #: component; the last such shortfall; ticks short at the last /diagnostics.
        self.short = 0
        self.unachieved: Counter[str] = Counter()
        self.last_shortfall = np.zeros(6)
        self._short_reported = 0
        self.create_timer(self.control_period, self._wrench_watchdog, clock=self.steady)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.join_run()
        self.get_logger().info(
            f'{self.allocator_config.mode} allocation, max tilt step '
            f'{self.allocator_config.tilt_step(self.robot, self.control_period):.4g} rad, '
            f'tilt_request {self.tilt_request_mode}')

    # -- parameters ------------------------------------------------------------------

    def on_handshake(self) -> None:
        if self.handshake.ready:
            self.decide_tilt_requests()

    # -- failed thrusters ------------------------------------------------------------

    # -- inputs ----------------------------------------------------------------------

    @input_callback(WRENCH_CMD)
    def _on_wrench(self, msg: WrenchStamped) -> None:
        ns = self.check_header(msg.header, FRAME_BODY)
        wrench = wrench_array(msg)
        check_finite(wrench, 'wrench')      # before it may act: rejected changes nothing
        if ns == self._last_ns and self._last_msgs is not None:
            self.republished += 1
            self.wrench_watchdog.fresh(ns)
            self._publish(*self._last_msgs)
            return
        if ns < self._last_ns:
            self._reset(f'wrench_cmd went back from {format_ns(self._last_ns)} to '
                        f'{format_ns(ns)}')
        self.wrench_watchdog.fresh(ns)
        self._handling = ns
        clipped, changed = clip_wrench(wrench)
        if changed:
            self.clipped += 1
            self.get_logger().warning(
                f'wrench_cmd stamped {format_ns(ns)} has components beyond +-{MAX_WRENCH:g}: '
                'clipped to it', throttle_duration_sec=THROTTLE)
            wrench = np.array(clipped)
        request = self._requests.get(ns) if self.tilt_request_mode != 'ignored' else None
        if request is not None:
            self._matched()
            self._allocate(ns, wrench, request)
        elif self._needs_request():
            self._wait(ns, wrench)
        else:
            self._allocate(ns, wrench, None)

    @input_callback(JOINT_STATES)
    def _on_joint_states(self, msg: JointState) -> None:
        """tilt_source measured: keep the servo positions by stamp (other joints of the
        message, e.g. the thrusters, are allowed and ignored)."""
        ns = self.check_header(msg.header, None)
        front, rear = joint_state_values(msg, TILTS, 'position', allowed=list(msg.name))
        keep_bounded(self._measured, ns, (front, rear))
        self._latest_measured = (ns, (front, rear))

    def _start(self, ns: int) -> AllocationResult | None:
        """What the allocation of the wrench stamped ``ns`` starts from: the last answer,
        or with tilt_source measured its tilts replaced by the measured ones."""
        if not self.measured_tilts:
            return self.previous
        tilts = self._measured.get(ns)
        if tilts is None:
            self.measured_late += 1
            latest = self._latest_measured
            if latest is None or latest[0] > ns:
                return self.previous
            tilts = latest[1]
        return from_tilts(self.previous, tilts)

    # -- allocation ------------------------------------------------------------------

    def _allocate(self, ns: int, wrench: FloatArray, request: tuple[float, float] | None) -> None:
        self._waiting = None
        if self.handoff is not None:
            self._resume(ns)
        if self.scenario_faults:
            self._use_failed(self._wanted_failed(ns), f'at {format_ns(ns)} (scenario)')
        start = self._start(ns)
        if request is None:
            result = self.allocator.allocate(wrench, previous=start)
        else:
            result = self.allocator.allocate_fixed(wrench, request[0], request[1],
                                                   previous=start)
        self.previous = result
        if request is None and not self.failed:     # the monitor knows four thrusters
            self.hold_monitor.update(wrench, result.achieved)
        self.ticks += 1
        self.methods[result.method] += 1
        if result.feasible:
            self.feasible += 1
        else:
            self.infeasible += 1        # not exact: the core's test, for the counts
            self._report_shortfall(ns, wrench, np.asarray(result.achieved, dtype=float))
        limit = self.robot.max_thrust * (1.0 - 1e-9)
        if np.any(np.abs(result.thrusts) >= limit):
            self.saturated += 1
        error = float(result.error)
        if math.isfinite(error):
            self.max_error = max(self.max_error, error)
        self._target_pub.publish(tilt_target_message(
            ns, result.target if result.method == 'transit' else None))
        self._answer(ns, result.thrusts, (result.tilt_front, result.tilt_rear),
                     result.achieved)
        self._handling = None
        for stamp in [s for s in self._requests if s < ns]:
            del self._requests[stamp]

    def _answer(self, ns: int, thrusts: Sequence[float], tilts: Sequence[float],
                achieved: Sequence[float]) -> None:
        """Publish an answer stamped ``ns``; one beyond the thrust limit or tilt range
        (or not finite) is replaced by the safe answer, whatever the core returned."""
        r = self.robot
        limited = limit_command(thrusts, tilts, r.max_thrust, r.tilt_min, r.tilt_max)
        if limited is not None:
            msgs = (fill_wrench(new_wrench(), ns, achieved),
                    fill_joint_state(new_joint_state(TILTS), ns, position=limited[1]),
                    fill_joint_state(new_joint_state(THRUSTERS), ns, effort=limited[0]))
        else:
            self.out_of_limits += 1
            self.get_logger().error(
                f'allocation stamped {format_ns(ns)} is beyond the limits (thrusts '
                f'{list(thrusts)}, tilts {list(tilts)}): publishing zero thrust',
                throttle_duration_sec=THROTTLE)
            msgs = self._safe_msgs(ns)
        self._last_ns = ns
        self._last_msgs = msgs
        self._publish(*msgs)

    def _publish(self, achieved: WrenchStamped, tilt: JointState, thrust: JointState) -> None:
        self._achieved_pub.publish(achieved)
        self._tilt_pub.publish(tilt)
        self._thrust_pub.publish(thrust)

    def _reset(self, why: str) -> None:
        self.resets += 1
        self.get_logger().info(f'{why}: forgetting the previous allocation')
        self.previous = None
        self.hold_monitor.reset()
        self._requests.clear()
        self._measured.clear()
        self._waiting = None
        self._last_ns = -1
        self._last_msgs = None

    def on_callback_error(self, callback: str, exc: Exception) -> None:
        """Safe answer to the wrench being handled: no thrust, tilts held."""
        super().on_callback_error(callback, exc)
        waiting, self._waiting = self._waiting, None
        ns = waiting.ns if waiting is not None else self._handling
        self._handling = None
        if ns is None or ns == self._last_ns:
            return
        self._answer_safe(ns)

    def _report_shortfall(self, ns: int, wrench: FloatArray, achieved: FloatArray) -> None:
        """Count and log (throttled) the components of ``wrench`` short by more than
        their tolerance (``wrench_tolerance``); a smaller shortfall is not reported."""
        shortfall = wrench - achieved
        missed = [dof for dof, v, tol in zip(WRENCH_DOFS, shortfall, self.tolerances)
                  if abs(v) > tol]
        if not missed:
            return
        self.short += 1
        self.unachieved.update(missed)
        self.last_shortfall = shortfall
        self.get_logger().warning(
            f'cannot achieve wrench_cmd stamped {format_ns(ns)} with thrusters '
            f'{thruster_names([i for i in range(4) if i not in self.failed])}: short by '
            + ', '.join(f'{dof} {v:+.3g}' for dof, v in zip(WRENCH_DOFS, shortfall)
                        if dof in missed), throttle_duration_sec=THROTTLE)

    # -- watchdog --------------------------------------------------------------------

    # -- diagnostics -----------------------------------------------------------------

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        level = OK
        message = (f'{self.allocator_config.mode}: {self.feasible} feasible, '
                   f'{self.infeasible} infeasible ({self.short} short beyond tolerance), '
                   f'{self.saturated} saturated')
        if self.short > self._short_reported or self.stale_requests:
            level = WARN            # short of the wrench since the last report
        self._short_reported = self.short
        if self.failed:
            message += f'; failed: {thruster_names(self.failed)}'
            if self.unachieved:
                message += ('; not achieved (ticks): ' + ', '.join(
                    f'{dof} {self.unachieved[dof]}' for dof in WRENCH_DOFS
                    if self.unachieved[dof]))
        if self.wrench_watchdog.stale:
            level = WARN
            message = (f'wrench_cmd stale (older than wrench_timeout '
                       f'{self.wrench_timeout:g} s): zero thrust; ' + message)
        request_level, request_text, request_values = self._tilt_request_status()
        level = max(level, request_level)
        message += request_text
        hold, steady = self.hold_monitor.report()
        if hold:
            level, message = WARN, f'{hold}; {message}'

        last = self.previous
        return level, message, {**request_values, **steady,
            'mode': self.allocator_config.mode, 'ticks': self.ticks,
            'feasible': self.feasible, 'infeasible': self.infeasible, 'short': self.short,
            'tolerances': [float(v) for v in self.tolerances],
            'saturated': self.saturated, 'max_weighted_error': self.max_error,
            'methods': dict(self.methods), 'republished': self.republished,
            'stale_tilt_requests': self.stale_requests,
            'dropped_wrenches': self.dropped, 'safe_answers': self.safe_answers,
            'out_of_limits': self.out_of_limits, 'resets': self.resets,
            'clipped_wrenches': self.clipped,
            'last_feasible': last.feasible if last is not None else True,
            'tilt_request': self.tilt_request_mode,
            'tilt_source': 'measured' if self.measured_tilts else 'commanded',
            'measured_tilts_late': self.measured_late,
            'failed_thrusters': [i + 1 for i in self.failed],
            'unachieved_ticks': {dof: self.unachieved[dof] for dof in WRENCH_DOFS},
            'last_shortfall': [float(v) for v in self.last_shortfall],
            'wrench_stale': self.wrench_watchdog.stale,
            'wrench_stale_events': self.wrench_watchdog.events,
            'watchdog_zero_thrusts': self.watchdog_outputs,
            'resumed_from': seconds(self.resumed_from) if self.resumed_from is not None else '',
        }


def main(args: list[str] | None = None) -> int:
    """``thrust_allocator [--ros-args --params-file config/thrust_allocator.yaml ...]``."""
    return main_loop(ThrustAllocatorNode, args, ALLOCATOR)


if __name__ == '__main__':
    sys.exit(main())
