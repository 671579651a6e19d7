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
from dataclasses import asdict
import math
import sys
from typing import Any

from geometry_msgs.msg import WrenchStamped
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from tiltrov_ros.core.allocation import (
    ALLOCATION,
    SHORTFALL_FRACTION,
    AllocationResult,
    AllocatorConfig,
    from_tilts,
    load_allocator_config,
    shortfall_tolerances,
)
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.names import (
    ALLOCATOR,
    FAILSAFE_FRAME,
    FRAME_BODY,
    JOINT_STATES,
    THRUST_CMD,
    THRUSTERS,
    TILT_CMD,
    TILT_REQUEST,
    TILTS,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
    WRENCH_DOFS,
)
from tiltrov_ros.core.paramtable import Param, ParamTable
from tiltrov_ros.core.scenarios import ThrusterFault, failed_at, load_scenario
from tiltrov_ros.core.steady import HoldMonitor
from tiltrov_ros.core.timebase import format_ns, seconds, to_ns
from tiltrov_ros.core.validation import (
    MAX_WRENCH,
    InvalidInput,
    check_finite,
    clip_wrench,
    failed_thruster_indices,
    limit_command,
)

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
from .guard import THROTTLE, guarded, input_callback
from .parameters import Overrides, check, declare, declare_failed_thrusters, declare_robot
from .qos import PUBLISHER_QOS, RELIABLE_QOS
from .tilt_request import TILT_REQUEST_MODES, TiltRequests, keep_bounded
from .watchdog import InputWatchdog

#: Where an allocation starts from: the last commanded tilts, or the measured ones.
TILT_SOURCES = ('commanded', 'measured')
#: s (wall): how often a wrench waiting for its tilt request is looked at.
WATCHDOG_PERIOD = 0.1

#: The node's own parameters (besides the allocator's, failed_thrusters, the stamp
#: bounds and the robot).
ALLOCATOR_PARAMS = ParamTable('thrust_allocator', [
    Param('tilt_request', 'str', 'auto', 'tilts fixed by the controller (switching baseline): '
          'required, ignored, or auto (paired once a request carries a wrench_cmd stamp, free '
          'again after a wrench waited input_timeout in vain)', choices=TILT_REQUEST_MODES,
          read_only=True),
    Param('input_timeout', 'float', 1.0, 'wall seconds a wrench waits for its tilt_request '
          'before the latest one is used', 's', low=0.001, high=3600.0),
    Param('wrench_timeout', 'float', 0.5, 'zero thrust (tilts held) is published every '
          'control period while the newest valid wrench_cmd is older than this; on sim time '
          'measured on /clock, else wall time since the message arrived; 0: off', 's',
          low=0.0, high=3600.0),
    Param('tilt_source', 'str', 'commanded', 'tilts each allocation starts from (and moves '
          'at most max_tilt_step away from): commanded, the last answer; measured, the '
          'servos\' positions in joint_states (the one stamped with the wrench, else the '
          'latest before it)', choices=TILT_SOURCES, read_only=True),
    Param('wrench_tolerance', 'float', SHORTFALL_FRACTION, 'a wrench component missing by '
          'more than this fraction of max_thrust (forces; moments: times min(length, width) / '
          '2) counts as not achieved: logged, counted per component, WARN on /diagnostics',
          '-', low=0.0, high=1.0),
    Param('scenario', 'str', '', 'scenario name or path whose faults (thruster failures) the '
          'allocator is told of at their time + detected_after, by the wrench stamps; empty: '
          'none', read_only=True),
])


def thruster_names(indices: Sequence[int]) -> str:
    return ', '.join(THRUSTERS[i] for i in indices) or 'none'


class ThrustAllocatorNode(TiltRequests, TiltrovNode):
    """The thrust allocator (see the module docstring)."""

    kernel_groups = ('allocation',)

    def __init__(self, *, node_name: str = ALLOCATOR, namespace: str | None = None,
                 context: Any = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None) -> None:
        super().__init__(node_name, namespace=namespace, context=context, cli_args=cli_args,
                         parameter_overrides=parameter_overrides)
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
        # The answers go out as serialized templates (nodes/serialized.py).
        self._achieved_pub.serialize_as(*wrench_template())
        self._tilt_pub.serialize_as(*joint_template(TILTS, 'position'))
        self._thrust_pub.serialize_as(*joint_template(THRUSTERS, 'effort'))
        self.create_input_subscription(WrenchStamped, WRENCH_CMD, self._on_wrench, RELIABLE_QOS)
        if self.tilt_request_mode != 'ignored':
            self.create_input_subscription(JointState, TILT_REQUEST, self._on_tilt_request,
                                           RELIABLE_QOS)
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
        self.start_diagnostics()
        self.get_logger().info(
            f'{self.allocator_config.mode} allocation, max tilt step '
            f'{self.allocator_config.tilt_step(self.robot, self.control_period):.4g} rad, '
            f'tilt_request {self.tilt_request_mode}')

    # -- parameters ------------------------------------------------------------------

    def _declare_parameters(self) -> None:
        shipped = load_allocator_config()
        declare(self, ALLOCATION, defaults=asdict(shipped))
        own = declare(self, ALLOCATOR_PARAMS, only=('tilt_request', 'input_timeout',
                                                  'wrench_timeout', 'wrench_tolerance',
                                                  'tilt_source'))
        self.failed_param = declare_failed_thrusters(self)
        own.update(declare(self, ALLOCATOR_PARAMS, only=('scenario',)))
        self.scenario_faults: tuple[ThrusterFault, ...] = (
            load_scenario(own['scenario']).faults if own['scenario'] else ())
        self.declare_stamp_bounds()
        self.robot, self.control_period = declare_robot(self)
        self.check_overrides()
        own = check(ALLOCATOR_PARAMS, own)
        self.tilt_request_mode = own['tilt_request']
        self.input_timeout = own['input_timeout']
        self.wrench_timeout = own['wrench_timeout']
        self.wrench_tolerance = own['wrench_tolerance']
        self.tolerances = shortfall_tolerances(self.robot, self.wrench_tolerance)
        self.measured_tilts = own['tilt_source'] == 'measured'
        self.allocator_config = AllocatorConfig.from_mapping(
            {key: self.get_parameter(key).value for key in ALLOCATION.names})

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        verdict = self.check_failed_thrusters(parameters)
        if not verdict.successful:
            return verdict
        changes = {p.name: p.value for p in parameters if p.name in ALLOCATION.names}
        if not changes:
            return SetParametersResult(successful=True)
        values = {key: changes.get(key, self.get_parameter(key).value)
                  for key in ALLOCATION.names}
        try:
            AllocatorConfig.from_mapping(values)
        except ParameterError as exc:
            return self.reject(str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        for p in parameters:
            if p.name == 'wrench_timeout':
                self.wrench_timeout = float(p.value)
            elif p.name == 'wrench_tolerance':
                self.wrench_tolerance = float(p.value)
                self.tolerances = shortfall_tolerances(self.robot, self.wrench_tolerance)
                self._new_hold_monitor()
            elif p.name == 'input_timeout':
                self.input_timeout = float(p.value)
            elif p.name == 'failed_thrusters':
                self.failed_param = failed_thruster_indices(p.value)
                self._use_failed(self._wanted_failed(self._last_ns if self._last_ns >= 0
                                                     else None), 'failed_thrusters set')
        if not any(p.name in ALLOCATION.names for p in parameters):
            return
        self.allocator_config = AllocatorConfig.from_mapping(
            {key: self.get_parameter(key).value for key in ALLOCATION.names})
        self.allocator = self.allocator_config.build(self.robot, self.control_period,
                                                     self.failed)
        self._new_hold_monitor()
        self.get_logger().info(f'allocator changed: {self.allocator_config}')

    def _new_hold_monitor(self) -> None:
        self.hold_monitor = HoldMonitor(self.robot, self.control_period,
                                        self.allocator_config.weights, self.wrench_tolerance)

    # -- failed thrusters ------------------------------------------------------------

    def _wanted_failed(self, ns: int | None) -> tuple[int, ...]:
        """``failed_thrusters`` plus the scenario's faults detected by stamp ``ns``."""
        scheduled = (failed_at(self.scenario_faults, seconds(ns), detected=True)
                     if ns is not None and self.scenario_faults else ())
        return tuple(sorted(set(self.failed_param) | set(scheduled)))

    def _use_failed(self, failed: tuple[int, ...], why: str) -> None:
        """Allocate with the thrusters not in ``failed`` (the core's robust allocator
        with ``failed_thrusters``: least weighted error, depth and attitude first)."""
        if failed == self.failed:
            return
        self.failed = failed
        self.allocator = self.allocator_config.build(self.robot, self.control_period, failed)
        self.hold_monitor.reset()
        working = [i for i in range(4) if i not in failed]
        self.get_logger().warning(
            f'{why}: failed thruster(s): {thruster_names(failed)}; allocating with '
            f'{thruster_names(working)} (weights {[float(w) for w in self.allocator.weights]}: '
            'depth and attitude first)')

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

    def held_tilts(self) -> tuple[float, float]:
        """The tilts of the last allocation (in range), else 0: what a safe answer holds."""
        prev = self.previous
        if prev is None or not (math.isfinite(prev.tilt_front)
                                and math.isfinite(prev.tilt_rear)):
            return (0.0, 0.0)
        lo, hi = self.robot.tilt_min, self.robot.tilt_max
        return (min(max(prev.tilt_front, lo), hi), min(max(prev.tilt_rear, lo), hi))

    def _safe_msgs(self, ns: int) -> tuple[WrenchStamped, JointState, JointState]:
        """The safe answer stamped ``ns``: zero thrust (so zero wrench), tilts held."""
        return (fill_wrench(new_wrench(), ns, (0.0,) * 6),
                fill_joint_state(new_joint_state(TILTS), ns, position=self.held_tilts()),
                fill_joint_state(new_joint_state(THRUSTERS), ns, effort=(0.0,) * 4))

    def _answer_safe(self, ns: int) -> None:
        self.safe_answers += 1
        self._waiting = None
        self._last_ns = ns
        self._last_msgs = self._safe_msgs(ns)
        self._publish(*self._last_msgs)

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

    @guarded
    def _wrench_watchdog(self) -> None:
        """Zero thrust, tilts held, while wrench_cmd is stale (not cached)."""
        seen = self.wrench_watchdog.expired(self.wrench_timeout)
        if seen is None:
            return
        self.watchdog_outputs += 1
        _, tilt, thrust = self._safe_msgs(
            self.estimated_now_ns(*seen, to_ns(self.control_period)))
        # It answers no wrench_cmd: marked (its stamp, off the tick grid, may still meet
        # the controller's own safety wrench), and no wrench_achieved goes with it.
        tilt.header.frame_id = thrust.header.frame_id = FAILSAFE_FRAME
        self._tilt_pub.publish(tilt)
        self._thrust_pub.publish(thrust)

    def on_rejected(self, topic: str, bad: InvalidInput, stamp: int | None) -> None:
        """A rejected wrench with a valid stamp, later than the last answered and not
        waiting, gets the safe answer (the plant waits for that stamp in lockstep),
        stamped no later than the node's clock (:meth:`safe_stamp`) and not kept as the
        answer of that stamp; nothing else changes. A bad stamp gets none."""
        waiting = self._waiting
        if (topic != WRENCH_CMD or stamp is None or stamp <= self._last_ns
                or (waiting is not None and waiting.ns == stamp)):
            return
        seen = self.wrench_watchdog.seen
        self.safe_answers += 1
        self._publish(*self._safe_msgs(self.safe_stamp(
            stamp, seen[0] if seen else None, to_ns(self.control_period))))

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
        }


def main(args: list[str] | None = None) -> int:
    """``thrust_allocator [--ros-args --params-file config/thrust_allocator.yaml ...]``."""
    return main_loop(ThrustAllocatorNode, args, ALLOCATOR)


if __name__ == '__main__':
    sys.exit(main())
