"""What the allocator does besides allocating (a base of
:class:`~tiltrov_ros.nodes.thrust_allocator.ThrustAllocatorNode`): failed thrusters, the safe
answer (zero thrust, tilts held) to a rejected wrench or a stale one, and where a respawned
allocator resumes (its predecessor's last answer and servo travel, nodes/handoff.py)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
import math
from typing import TYPE_CHECKING

from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState

from tiltrov_ros.core.allocation import from_tilts
from tiltrov_ros.core.names import (
    FAILSAFE_FRAME,
    THRUSTERS,
    TILT_CMD,
    TILT_TARGET,
    TILTS,
    WRENCH_CMD,
)
from tiltrov_ros.core.scenarios import failed_at
from tiltrov_ros.core.timebase import format_ns, seconds, to_ns
from tiltrov_ros.core.validation import InvalidInput

from .conversions import (
    fill_joint_state,
    fill_wrench,
    joint_state_values,
    new_joint_state,
    new_wrench,
)
from .guard import guarded

if TYPE_CHECKING:
    from .thrust_allocator import ThrustAllocatorNode


def thruster_names(indices: Sequence[int]) -> str:
    return ', '.join(THRUSTERS[i] for i in indices) or 'none'


class AllocatorSafety:
    """Failed thrusters, safe answers, the resumption (see the module docstring)."""

    def _wanted_failed(self: ThrustAllocatorNode, ns: int | None) -> tuple[int, ...]:
        """``failed_thrusters`` plus the scenario's faults detected by stamp ``ns``."""
        scheduled = (failed_at(self.scenario_faults, seconds(ns), detected=True)
                     if ns is not None and self.scenario_faults else ())
        return tuple(sorted(set(self.failed_param) | set(scheduled)))

    def _use_failed(self: ThrustAllocatorNode, failed: tuple[int, ...], why: str) -> None:
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

    def _resume(self: ThrustAllocatorNode, ns: int) -> None:
        """The first wrench of a respawned allocator: start from its predecessor's last
        answer before ``ns`` (its commanded tilts, and the travel under way then)."""
        handoff, self.handoff = self.handoff, None
        if handoff is None:
            return
        got = handoff.before(TILT_CMD, ns, JointState)
        if got is None:
            self.get_logger().warning(f'no tilt_cmd of a predecessor before {format_ns(ns)}: '
                                      'allocating afresh')
            return
        stamp, cmd = got
        target = handoff.before(TILT_TARGET, stamp + 1, JointState)
        travel = (tuple(target[1].position) if target is not None and target[0] == stamp
                  and list(target[1].name) == list(TILTS) else None)
        self.previous = replace(from_tilts(None, joint_state_values(cmd, TILTS, 'position')),
                                method='transit' if travel else 'previous',
                                target=travel)      # type: ignore[arg-type]
        self.resumed_from = stamp
        self.get_logger().info(
            f'resumed from its predecessor\'s answer at {format_ns(stamp)}'
            + (f', travelling to {travel}' if travel else '')
            + ('' if stamp == ns - to_ns(self.control_period)
               else f' (not the tick before {format_ns(ns)}: not bumpless)'))

    def held_tilts(self: ThrustAllocatorNode) -> tuple[float, float]:
        """The tilts of the last allocation (in range), else 0: what a safe answer holds."""
        prev = self.previous
        if prev is None or not (math.isfinite(prev.tilt_front)
                                and math.isfinite(prev.tilt_rear)):
            return (0.0, 0.0)
        lo, hi = self.robot.tilt_min, self.robot.tilt_max
        return (min(max(prev.tilt_front, lo), hi), min(max(prev.tilt_rear, lo), hi))

    def _safe_msgs(self: ThrustAllocatorNode,
                   ns: int) -> tuple[WrenchStamped, JointState, JointState]:
        """The safe answer stamped ``ns``: zero thrust (so zero wrench), tilts held."""
        return (fill_wrench(new_wrench(), ns, (0.0,) * 6),
                fill_joint_state(new_joint_state(TILTS), ns, position=self.held_tilts()),
                fill_joint_state(new_joint_state(THRUSTERS), ns, effort=(0.0,) * 4))

    def _answer_safe(self: ThrustAllocatorNode, ns: int) -> None:
        self.safe_answers += 1
        self._waiting = None
        self._last_ns = ns
        self._last_msgs = self._safe_msgs(ns)
        self._publish(*self._last_msgs)

    @guarded
    def _wrench_watchdog(self: ThrustAllocatorNode) -> None:
        """Zero thrust, tilts held, while wrench_cmd is stale (not cached)."""
        timeout = self.wrench_timeout
        if timeout > 0 and self.respawn_hold > 0:
            timeout = max(timeout, self.respawn_hold)     # a respawned controller may come
        seen = self.wrench_watchdog.expired(timeout)
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

    def on_rejected(self: ThrustAllocatorNode, topic: str, bad: InvalidInput,
                    stamp: int | None) -> None:
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
