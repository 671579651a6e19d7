"""What a lockstep tick of the controller waits for, and where a respawned controller resumes
(a base of :class:`~tiltrov_ros.nodes.wrench_controller.WrenchController`).

In lockstep a tick waits for its setpoint and, when a node publishes them at the run's
handshake (alone: at the first tick), its setpoint velocity and the pid's
``wrench_achieved``, however long; a long wait is reported (``input_timeout``). The
run's last state (the plant's ``end_ns``) is answered by no tick. A respawned
controller's pid continues from the integral its predecessor had after the tick before
the first one it answers (nodes/handoff.py)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState

from tiltrov_ros.core.controllers import PIDController
from tiltrov_ros.core.names import (
    PID_INTEGRAL,
    PLANT,
    SETPOINT,
    SETPOINT_VELOCITY,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
)
from tiltrov_ros.core.timebase import format_ns, seconds

from .conversions import wrench_array
from .guard import guarded
from .handshake import END_KEY

if TYPE_CHECKING:
    from .wrench_controller import WrenchController


class ControllerWaits:
    """The lockstep tick's waits and the resumption (see the module docstring)."""

    def _decide_inputs(self: WrenchController) -> frozenset[str]:
        """lockstep: the inputs besides the setpoint that a tick waits for, decided once:
        at the run's handshake, those a node of the run publishes; alone, at the first tick,
        those with a publisher now. Said once in the log."""
        if self._waits_for is not None:
            return self._waits_for
        wanted = [t for t, used in ((SETPOINT_VELOCITY, self.use_velocity),
                                    (WRENCH_ACHIEVED, self.kind == 'pid')) if used]
        hs = self.handshake
        if hs.active:
            published = {t for state in hs.states.values() for t, _ in state.publishes}
            waits = frozenset(t for t in wanted if self.resolve_topic_name(t) in published)
        else:
            waits = frozenset(t for t in wanted
                              if self.count_publishers(self.resolve_topic_name(t)) > 0)
        self._waits_for = waits
        for topic in wanted:
            if topic in waits:
                self.get_logger().info(f'each tick waits for its {topic}' + (
                    ' (while the anti-windup is on)' if topic == WRENCH_ACHIEVED else ''))
            else:
                what = ('zero feed-forward' if topic == SETPOINT_VELOCITY
                        else 'no anti-windup')
                self.get_logger().warning(f'no node publishes {topic}: {what} for the '
                                          'whole run')
        return waits

    @property
    def run_end_ns(self: WrenchController) -> int | None:
        """The sim time the run ends at, as the plant of the run says (None: unknown)."""
        plant = self.handshake.state_of(PLANT)
        end = plant.extra.get(END_KEY) if plant is not None else None
        return int(end) if end is not None and end.isdigit() else None

    def on_handshake(self: WrenchController) -> None:
        """The run's handshake is this node's moment to decide what a tick waits for."""
        if self.lockstep and self._waits_for is None and self.handshake.ready:
            self._decide_inputs()

    @guarded
    def _watchdog(self: WrenchController) -> None:
        """lockstep: report a tick that waits longer than ``input_timeout`` (once per tick)."""
        tick = self._tick
        if tick is None or self._warned_tick == tick.ns:
            return
        waited = seconds(self.steady_ns() - tick.since)
        if waited < self.input_timeout:
            return
        self._warned_tick = tick.ns
        self.input_waits += 1
        missing = self.missing_inputs(tick.ns)
        self.get_logger().warning(f'waiting for the {" and ".join(missing) or "inputs"} '
                                  f'stamped {format_ns(tick.ns)} ({waited:.2f} s so far)')

    def missing_inputs(self: WrenchController, ns: int) -> list[str]:
        """The inputs tick ``ns`` still waits for."""
        waits = self._waits_for or frozenset()
        missing = [] if ns in self._setpoints else [SETPOINT]
        if SETPOINT_VELOCITY in waits and ns not in self._velocities:
            missing.append(SETPOINT_VELOCITY)
        if WRENCH_ACHIEVED in waits and self.waits_for_achieved(ns):
            missing.append(WRENCH_ACHIEVED)
        return missing

    def _resume(self: WrenchController, ns: int) -> None:
        """The first tick of a respawned controller: the pid continues from the state its
        predecessor had after the tick before ``ns`` (the handoff a standby kept)."""
        handoff, self.handoff = self.handoff, None
        if handoff is None or not isinstance(self.controller, PIDController):
            return
        got = handoff.before(PID_INTEGRAL, ns, JointState)
        if got is None:
            self.get_logger().warning(f'no pid_integral of a predecessor before '
                                      f'{format_ns(ns)}: the integral starts from zero')
            return
        stamp, msg = got
        last = handoff.before(WRENCH_CMD, stamp + 1, WrenchStamped)
        self.controller.resume(seconds(stamp), list(msg.position),
                               wrench_array(last[1]) if last and last[0] == stamp else None)
        self.resumed_from = stamp
        self.get_logger().info(f'resumed the pid from its predecessor\'s integral after '
                               f'{format_ns(stamp)}' + ('' if stamp == ns - self.period_ns
                                                        else f' (not the tick before '
                                                        f'{format_ns(ns)}: not bumpless)'))
