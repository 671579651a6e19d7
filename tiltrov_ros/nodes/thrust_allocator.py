"""``thrust_allocator``: :class:`tiltrov_ros.core.allocation.ThrustAllocator` as a ROS node.

For each ``wrench_cmd`` it publishes ``wrench_achieved`` (eq. (4) of its
answer), ``tilt_cmd`` and ``thrust_cmd``, all stamped with the wrench's stamp
(in that order: the plant advances on the last two). ``previous`` is the last
answer, so the tilts move least and at most ``max_tilt_step`` per call.

The switching baseline fixes the tilts itself: its ``tilt_request`` (same
stamp as its ``wrench_cmd``) makes the allocator hold the tilts there and
solve for the thrusts (``allocate_fixed``). Parameter ``tilt_request``:

* ``required``: every wrench waits for the tilt request with its stamp (they
  travel on two topics, so either may come first); after ``input_timeout``
  wall seconds the latest request received is used (counted on /diagnostics);
* ``ignored``: free allocation, the topic is not subscribed;
* ``auto`` (default): ``required`` once a tilt request has been received or
  a ``tilt_request`` publisher is in the graph, else free allocation.

The launcher sets ``required`` for the switching controller and ``ignored``
otherwise. A repeated wrench stamp re-publishes the cached answer without
allocating again (so re-publication is idempotent and ``previous`` does not
move); an earlier stamp (a restarted plant, a looped replay) forgets
``previous``.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
import math
import sys
from typing import Any

from geometry_msgs.msg import WrenchStamped
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from tiltrov_ros.core.allocation import (
    AllocationResult,
    AllocatorConfig,
    load_allocator_config,
)
from tiltrov_ros.core.errors import ParameterError

from .common import (
    OK,
    RELIABLE_QOS,
    THROTTLE,
    THRUST_CMD,
    THRUSTERS,
    TILT_CMD,
    TILT_REQUEST,
    TILTS,
    WARN,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
    FloatArray,
    Overrides,
    TiltrovNode,
    declare_robot,
    descriptor,
    fill_joint_state,
    fill_wrench,
    format_ns,
    guarded,
    joint_values,
    main_loop,
    new_joint_state,
    new_wrench,
    stamp_ns,
    wrench_array,
)

NODE_NAME = 'thrust_allocator'
TILT_REQUEST_MODES = ('auto', 'required', 'ignored')
#: s (wall): how often a wrench waiting for its tilt request is looked at.
WATCHDOG_PERIOD = 0.1
BUFFER = 200
ALLOCATOR_KEYS = ('mode', 'max_tilt_step', 'weights')


@dataclass
class _Waiting:
    ns: int
    wrench: FloatArray
    since: int      # steady ns


class ThrustAllocatorNode(TiltrovNode):
    """The thrust allocator (see the module docstring)."""

    def __init__(self, *, node_name: str = NODE_NAME, namespace: str | None = None,
                 context: Any = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None) -> None:
        super().__init__(node_name, namespace=namespace, context=context, cli_args=cli_args,
                         parameter_overrides=parameter_overrides)
        self._declare_parameters()
        self.allocator = self.allocator_config.build(self.robot, self.control_period)

        self._achieved_pub = self.create_publisher(WrenchStamped, WRENCH_ACHIEVED,
                                                   RELIABLE_QOS)
        self._tilt_pub = self.create_publisher(JointState, TILT_CMD, RELIABLE_QOS)
        self._thrust_pub = self.create_publisher(JointState, THRUST_CMD, RELIABLE_QOS)
        self.create_subscription(WrenchStamped, WRENCH_CMD, self._on_wrench, RELIABLE_QOS)
        if self.tilt_request_mode != 'ignored':
            self.create_subscription(JointState, TILT_REQUEST, self._on_tilt_request,
                                     RELIABLE_QOS)
            self.create_timer(WATCHDOG_PERIOD, self._watchdog, clock=self.steady)

        self.previous: AllocationResult | None = None
        self._last_ns = -1
        self._last_msgs: tuple[WrenchStamped, JointState, JointState] | None = None
        self._requests: dict[int, tuple[float, float]] = {}
        self._latest_request: tuple[float, float] | None = None
        self._waiting: _Waiting | None = None
        self.ticks = 0
        self.feasible = 0
        self.infeasible = 0
        self.saturated = 0
        self.methods: Counter[str] = Counter()
        self.max_error = 0.0
        self.republished = 0
        self.stale_requests = 0
        self.dropped = 0
        self.rejected_messages = 0
        self.resets = 0
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
        d = self.declare_parameter
        d('mode', shipped.mode, descriptor(
            "robust: exact when attainable, else least weighted wrench error; paper: "
            'Section 3 of the paper', constraints='robust or paper'))
        d('max_tilt_step', shipped.max_tilt_step, descriptor(
            'how far each tilt may move per control period, rad; <= 0: the servo reach '
            '(tilt_rate_limit x control_period)', floating=(-1e6, 1e6)))
        d('weights', [float(w) for w in shipped.weights], descriptor(
            'robust mode: weights of the wrench error (X Y Z K M N)',
            constraints='6 finite numbers > 0'))
        self.tilt_request_mode = d('tilt_request', 'auto', descriptor(
            'tilts fixed by the controller (switching baseline): required, ignored, or '
            'auto (required once a tilt_request publisher or message is seen)',
            read_only=True, constraints=' | '.join(TILT_REQUEST_MODES))).value
        self.input_timeout = d('input_timeout', 1.0, descriptor(
            'wall seconds a wrench waits for its tilt_request before the latest one is '
            'used', floating=(0.001, 3600.0))).value
        self.robot, self.control_period = declare_robot(self)
        self.check_overrides()
        if self.tilt_request_mode not in TILT_REQUEST_MODES:
            raise ParameterError('tilt_request', f'got {self.tilt_request_mode!r}; allowed: '
                                 f'{", ".join(TILT_REQUEST_MODES)}')
        self.allocator_config = AllocatorConfig.from_mapping(
            {key: self.get_parameter(key).value for key in ALLOCATOR_KEYS})

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        changes = {p.name: p.value for p in parameters if p.name in ALLOCATOR_KEYS}
        if not changes:
            return SetParametersResult(successful=True)
        values = {key: changes.get(key, self.get_parameter(key).value)
                  for key in ALLOCATOR_KEYS}
        try:
            AllocatorConfig.from_mapping(values)
        except ParameterError as exc:
            return self.reject(str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        if not any(p.name in ALLOCATOR_KEYS for p in parameters):
            return
        self.allocator_config = AllocatorConfig.from_mapping(
            {key: self.get_parameter(key).value for key in ALLOCATOR_KEYS})
        self.allocator = self.allocator_config.build(self.robot, self.control_period)
        self.get_logger().info(f'allocator changed: {self.allocator_config}')

    # -- inputs ----------------------------------------------------------------------

    def _needs_request(self) -> bool:
        if self.tilt_request_mode == 'auto':
            return (self._latest_request is not None
                    or self.count_publishers(TILT_REQUEST) > 0)
        return self.tilt_request_mode == 'required'

    @guarded
    def _on_wrench(self, msg: WrenchStamped) -> None:
        ns = stamp_ns(msg.header.stamp)
        if ns == self._last_ns and self._last_msgs is not None:
            self.republished += 1
            self._publish(*self._last_msgs)
            return
        if ns < self._last_ns:
            self._reset(f'wrench_cmd went back from {format_ns(self._last_ns)} to '
                        f'{format_ns(ns)}')
        wrench = wrench_array(msg)
        if not np.all(np.isfinite(wrench)):
            self.rejected_messages += 1
            self.get_logger().error(f'wrench_cmd stamped {format_ns(ns)} is not finite: its '
                                    'non-finite components are read as 0',
                                    throttle_duration_sec=THROTTLE)
        if self._needs_request():
            request = self._requests.get(ns)
            if request is None:
                if self._waiting is not None:
                    self.dropped += 1     # a newer wrench came first (realtime)
                self._waiting = _Waiting(ns, wrench, self.steady_ns())
                return
            self._allocate(ns, wrench, request)
        else:
            self._allocate(ns, wrench, None)

    @guarded
    def _on_tilt_request(self, msg: JointState) -> None:
        ns = stamp_ns(msg.header.stamp)
        values = joint_values(msg, TILTS, 'position')
        if values is None:
            self.rejected_messages += 1
            self.get_logger().error(f'ignoring a tilt_request stamped {format_ns(ns)}: needs '
                                    'finite positions for tilt_front and tilt_rear',
                                    throttle_duration_sec=THROTTLE)
            return
        request = (values[0], values[1])
        self._requests[ns] = request
        self._latest_request = request
        if len(self._requests) > BUFFER:
            for stamp in sorted(self._requests)[:len(self._requests) - BUFFER]:
                del self._requests[stamp]
        waiting = self._waiting
        if waiting is not None and waiting.ns == ns:
            self._allocate(ns, waiting.wrench, request)

    @guarded
    def _watchdog(self) -> None:
        waiting = self._waiting
        if waiting is None:
            return
        waited = (self.steady_ns() - waiting.since) / 1e9
        if waited < self.input_timeout:
            return
        self.stale_requests += 1
        self.get_logger().warning(
            f'no tilt_request stamped {format_ns(waiting.ns)} after {waited:.2f} s: using '
            f'{"the latest" if self._latest_request else "none (free allocation)"}',
            throttle_duration_sec=THROTTLE)
        self._allocate(waiting.ns, waiting.wrench, self._latest_request)

    # -- allocation ------------------------------------------------------------------

    def _allocate(self, ns: int, wrench: FloatArray, request: tuple[float, float] | None) -> None:
        self._waiting = None
        if request is None:
            result = self.allocator.allocate(wrench, previous=self.previous)
        else:
            result = self.allocator.allocate_fixed(wrench, request[0], request[1],
                                                   previous=self.previous)
        self.previous = result
        self.ticks += 1
        self.methods[result.method] += 1
        if result.feasible:
            self.feasible += 1
        else:
            self.infeasible += 1
        limit = self.robot.max_thrust * (1.0 - 1e-9)
        if np.any(np.abs(result.thrusts) >= limit):
            self.saturated += 1
        error = float(result.error)
        if math.isfinite(error):
            self.max_error = max(self.max_error, error)
        self._answer(ns, result.thrusts, (result.tilt_front, result.tilt_rear),
                     result.achieved)
        for stamp in [s for s in self._requests if s < ns]:
            del self._requests[stamp]

    def _answer(self, ns: int, thrusts: Sequence[float], tilts: Sequence[float],
                achieved: Sequence[float]) -> None:
        msgs = (fill_wrench(new_wrench(), ns, achieved),
                fill_joint_state(new_joint_state(TILTS), ns, position=tilts),
                fill_joint_state(new_joint_state(THRUSTERS), ns, effort=thrusts))
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
        self._requests.clear()
        self._waiting = None
        self._last_ns = -1
        self._last_msgs = None

    def on_callback_error(self, callback: str, exc: Exception) -> None:
        """Safe answer to the wrench being handled: no thrust, tilts held."""
        super().on_callback_error(callback, exc)
        waiting, self._waiting = self._waiting, None
        ns = waiting.ns if waiting is not None else None
        if ns is None or ns == self._last_ns:
            return
        prev = self.previous
        tilts = (prev.tilt_front, prev.tilt_rear) if prev is not None else (0.0, 0.0)
        self._answer(ns, (0.0,) * 4, tilts, (0.0,) * 6)

    # -- diagnostics -----------------------------------------------------------------

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        level = OK
        message = (f'{self.allocator_config.mode}: {self.feasible} feasible, '
                   f'{self.infeasible} infeasible, {self.saturated} saturated')
        if self.infeasible or self.stale_requests or self.rejected_messages:
            level = WARN
        last = self.previous
        return level, message, {
            'mode': self.allocator_config.mode, 'ticks': self.ticks,
            'feasible': self.feasible, 'infeasible': self.infeasible,
            'saturated': self.saturated, 'max_weighted_error': self.max_error,
            'methods': dict(self.methods), 'republished': self.republished,
            'stale_tilt_requests': self.stale_requests,
            'dropped_wrenches': self.dropped,
            'rejected_messages': self.rejected_messages, 'resets': self.resets,
            'last_feasible': last.feasible if last is not None else True,
            'tilt_request': self.tilt_request_mode,
        }


def main(args: list[str] | None = None) -> int:
    """``thrust_allocator [--ros-args --params-file config/thrust_allocator.yaml ...]``."""
    return main_loop(ThrustAllocatorNode, args, NODE_NAME)


if __name__ == '__main__':
    sys.exit(main())
