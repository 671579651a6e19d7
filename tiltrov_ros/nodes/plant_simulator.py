"""``plant_simulator``: the robot (:class:`tiltrov_ros.core.plant.Plant`) as a ROS node.

Subscribes ``thrust_cmd`` (thruster_1..4, effort N) and ``tilt_cmd``
(tilt_front, tilt_rear, position rad) and hands them to the actuator models
(``Plant.command``); publishes at every plant step, stamped with the sim time
t_i in integer ns (the first message is the initial state at t = 0):
``/clock``, then ``joint_states``, then ``odom``, then ``/tf`` (nodes/transforms.py),
and every ``markers_period`` ``robot_markers`` (nodes/markers.py). The clock first: a node on
sim time has its clock at t_i when the state stamped t_i arrives (its stamp
checks and a recorder's log times are then exact, docs/bags.md), the
reference publisher answers the clock while the state is on its way, and the
allocator has the measured tilts at t_i before the wrench that answers the
``odom`` at t_i.

Modes (parameter ``mode``):

* ``lockstep``: as fast as possible and deterministic: at each control tick the
  plant waits for the commands stamped with it (nodes/plant_lockstep.py: the start on
  the run's handshake, the ticks, restarts, the recorder's pacing, stalls).
* ``realtime``: a wall-clock timer steps the plant ``real_time_factor`` times
  faster than real time; the latest command (by stamp) is in force. Time
  starts as lockstep's initial state goes out (the handshake, ``startup_subscribers``).

In both modes a command stamped more than one plant step after the plant's
time is rejected (``future_stamp``): it answers no state yet published, and,
latest by stamp, it would shut out the real answers until its time.

With ``duration`` > 0 the plant stops at that sim time (after publishing the
state at ``duration``) and :attr:`PlantSimulator.finished` completes; with
``exit_at_end`` the process then exits with code 0 once every reader has
acknowledged the last messages (the launcher ends the run on it).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
import sys
from typing import Any

from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from rclpy.task import Future
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState

from tiltrov_ros.core.names import (
    CLOCK,
    JOINT_STATES,
    LOCKSTEP,
    ODOM,
    PLANT,
    THRUST_CMD,
    THRUSTERS,
    TILT_CMD,
    TILTS,
)
from tiltrov_ros.core.scenarios import failed_at
from tiltrov_ros.core.timebase import format_ns, seconds, to_ns
from tiltrov_ros.core.validation import (
    InvalidInput,
    check_answerable,
    checked_stamp_ns,
    failed_thruster_indices,
)

from .base import OK, WARN, TiltrovNode
from .conversions import (
    fill_joint_state,
    fill_odometry,
    joint_state_values,
    new_joint_state,
    new_odometry,
    set_stamp,
)
from .executors import main_loop
from .guard import THROTTLE, guarded, input_callback
from .markers import RobotMarkers
from .parameters import Overrides
from .plant_config import declare_parameters
from .plant_lockstep import REJECTED, Lockstep
from .qos import RELIABLE_QOS, STATE_QOS
from .serialized import SerializedTemplate
from .transforms import robot_transforms

#: joint_states value of a field a joint does not have (thruster position and
#: velocity, servo effort): 0.0, since no topic carries NaN (docs/reliability.md).
NO_VALUE = 0.0
#: Most plant steps one realtime timer callback catches up before it re-bases.
MAX_CATCH_UP = 100
#: The numbers of joint_states (position, velocity, effort of TILTS + THRUSTERS) and of
#: odom (position, quaternion, nu) in the templates' order.
_JOINT_VALUES = 3 * len(TILTS + THRUSTERS)
_ODOM_VALUES = 13
_NO_THRUSTER_VALUES = (NO_VALUE,) * len(THRUSTERS)


def _clock_message(values: Any, ns: int) -> ClockMsg:
    msg = ClockMsg()
    set_stamp(msg.clock, ns)
    return msg


def _joint_message(values: Any, ns: int) -> JointState:
    """joint_states of :data:`_JOINT_VALUES` values stamped ``ns``."""
    n = len(TILTS + THRUSTERS)
    return fill_joint_state(new_joint_state(TILTS + THRUSTERS), ns, position=values[:n],
                            velocity=values[n:2 * n], effort=values[2 * n:])


def _odom_message(values: Any, ns: int) -> Odometry:
    """odom of :data:`_ODOM_VALUES` values stamped ``ns``."""
    return fill_odometry(new_odometry(), ns, values[0:3], values[3:7], values[7:13])


class PlantSimulator(Lockstep, TiltrovNode):
    """The simulated robot (see the module docstring)."""

    kernel_groups = ('plant', 'visual')     # the step; robot_markers' scene

    def __init__(self, *, node_name: str = PLANT, namespace: str | None = None,
                 context: Any = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None) -> None:
        super().__init__(node_name, namespace=namespace, context=context, cli_args=cli_args,
                         parameter_overrides=parameter_overrides)
        self.config = declare_parameters(self)
        self.plant = self.config.build_plant()
        self.lockstep = self.config.mode == LOCKSTEP
        #: Completes (result: final sim time, ns) when ``duration`` is reached.
        self.finished: Future = Future()

        # Guarded: a non-finite state (a diverged integration) is withheld and counted.
        self._odom_pub = self.create_safe_publisher(Odometry, ODOM, STATE_QOS)
        self._joint_pub = self.create_safe_publisher(JointState, JOINT_STATES, STATE_QOS)
        self._clock_pub = self.create_safe_publisher(ClockMsg, CLOCK, STATE_QOS)
        self.expect_single_source(ODOM, JOINT_STATES, CLOCK)
        c = self.config
        self.markers = (RobotMarkers(self, c.robot.length, c.robot.width, c.markers_period_ns,
                                     c.marker_scales) if c.markers_period_ns else None)
        self.transforms = robot_transforms(self, c.robot, self.plant.time_ns, tf=c.tf,
                                           thrusters=c.tf_thrusters)
        # The state goes out as bytes rewritten in place (nodes/serialized.py).
        self._clock_bytes = SerializedTemplate(ClockMsg, _clock_message,
                                               lambda msg: [msg.clock], 0)
        self._joint_bytes = SerializedTemplate(JointState, _joint_message,
                                               lambda msg: [msg.header.stamp], _JOINT_VALUES)
        self._odom_bytes = SerializedTemplate(Odometry, _odom_message,
                                              lambda msg: [msg.header.stamp], _ODOM_VALUES)
        self._command_subs = (
            self.create_input_subscription(JointState, THRUST_CMD, self._on_thrust_cmd,
                                           RELIABLE_QOS),
            self.create_input_subscription(JointState, TILT_CMD, self._on_tilt_cmd,
                                           RELIABLE_QOS))
        self.init_lockstep()
        if self.markers is not None:
            self.markers.on_wrench = self._on_marker_wrench
        self._last_applied = [-1, -1]              # realtime: stamps of the held commands
        self._last_thrust_at: int | None = None    # realtime: sim ns of the last thrust_cmd
        self.commands_stale = False
        self.stale_events = 0
        self._update_failed()
        self.overruns = 0
        self._diag_mark = (self.steady_ns(), self.plant.time_ns)
        self._rtf_achieved = 0.0

        self._step_timer = None
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.join_run()
        c = self.config
        self.get_logger().info(
            f'{c.mode}{"" if self.lockstep else f" x{c.real_time_factor:g}"}, scenario '
            f'{c.scenario or "(none)"}, step {seconds(c.step_ns):g} s, control period '
            f'{seconds(c.control_period_ns):g} s, duration '
            f'{format_ns(c.duration_ns) if c.duration_ns else "unlimited"}')

    # -- state out -----------------------------------------------------------------

    def _publish_state(self) -> None:
        """``/clock``, ``joint_states``, then ``odom`` (see the module docstring)."""
        s = self.plant.sample()
        ns = s.t_ns
        self._published_generation = self.handshake.generation
        self._clock_pub.publish_serialized(self._clock_bytes, ns, ())
        self._joint_pub.publish_serialized(
            self._joint_bytes, ns, (*s.tilts, *_NO_THRUSTER_VALUES, *s.tilt_velocities,
                                    *_NO_THRUSTER_VALUES, NO_VALUE, NO_VALUE, *s.thrusts))
        self._odom_pub.publish_serialized(self._odom_bytes, ns,
                                          (*s.position, *s.quaternion, *s.nu))
        if self.transforms is not None:
            self.transforms.publish(s)
        if self.markers is not None and self.markers.due(ns):
            self.markers.publish(s, self.plant.thrusters.command_held,
                                 self.plant.servos.command_held)

    def _reached_end(self) -> bool:
        end = self.config.duration_ns
        return bool(end) and self.plant.time_ns >= end

    def _finish(self) -> None:
        if not self.finished.done():
            self._end_wait()
            t = self.plant.time_ns
            wall = seconds(self.steady_ns() - self._started_at)
            self.get_logger().info(
                f'reached the end of the run at {format_ns(t)}: {wall:.3f} s wall since '
                f'the initial state, real-time factor {seconds(t) / max(wall, 1e-9):.2f}')
            self.finished.set_result(t)

    # -- commands in ---------------------------------------------------------------

    def clock_ns(self) -> int | None:
        """The plant's clock is its own sim time (stamp bounds are relative to it)."""
        return self.plant.time_ns

    def diagnostics_stamp_ns(self) -> int:
        """The plant runs on its own sim time: its /diagnostics are stamped with it."""
        return self.plant.time_ns

    @input_callback(THRUST_CMD)
    def _on_thrust_cmd(self, msg: JointState) -> None:
        self._on_command(0, msg, THRUSTERS, 'effort')

    @input_callback(TILT_CMD)
    def _on_tilt_cmd(self, msg: JointState) -> None:
        self._on_command(1, msg, TILTS, 'position')

    def _on_command(self, kind: int, msg: JointState, names: tuple[str, ...],
                    field: str) -> None:
        stamp = msg.header.stamp
        if self.lockstep and (checked_stamp_ns(stamp.sec, stamp.nanosec) < self.plant.time_ns
                              or self.finished.done()):
            return   # a re-published answer to a tick already passed
        ns = self.check_header(msg.header, None)
        check_answerable(ns, self.plant.time_ns, self.config.step_ns)
        values = joint_state_values(msg, names, field)
        if not self.lockstep:
            if ns >= self._last_applied[kind]:
                self._last_applied[kind] = ns
                self._command(kind, values)
                if kind == 0:
                    self._last_thrust_at = self.plant.time_ns
                    if self.commands_stale:
                        self.commands_stale = False
                        self.get_logger().info(f'thrust_cmd again (stamped {format_ns(ns)}): '
                                               'commands resume')
            return
        self.hold(ns, kind, values)

    def _on_marker_wrench(self, ns: int, slot: int, data: bytes) -> None:
        """lockstep: a wrench the markers draw, kept for its tick (an old one is dropped)."""
        if ns >= self.plant.time_ns and not self.finished.done():
            self.hold(ns, slot, data)

    def on_rejected(self, topic: str, bad: InvalidInput, stamp: int | None) -> None:
        """A rejected command leaves the previous one in force. In lockstep one stamped
        with the tick the plant waits at answers that tick, unless a valid one already
        did (the run goes on); one stamped ahead answers nothing, so that it cannot
        stand in for a valid command not yet arrived; a bad stamp answers none."""
        if (not self.lockstep or stamp is None or self.finished.done()
                or stamp != self.plant.time_ns):
            return
        kind = 0 if topic == THRUST_CMD else 1
        entry = self._pending.get(stamp)
        if entry is None or entry[kind] is None:
            self.hold(stamp, kind, REJECTED)

    def _command(self, kind: int, values: list[float]) -> None:
        if kind == 0:
            self.plant.command(thrusts=values)
        else:
            self.plant.command(tilts=values)

    # -- stepping --------------------------------------------------------------------

    def _step(self) -> None:
        """One plant step (the scenario's faults applied first), then the state out."""
        if self.config.faults:
            self._update_failed()
        self.plant.step()
        self._publish_state()

    def _update_failed(self) -> None:
        """Failed thrusters: the parameter's plus the scenario's failed by now."""
        failed = tuple(sorted(set(self.config.failed_thrusters) | set(
            failed_at(self.config.faults, seconds(self.plant.time_ns)))))
        if failed != self.plant.failed_thrusters:
            self.plant.set_failed_thrusters(failed)
            self.get_logger().warning(
                f'at {format_ns(self.plant.time_ns)}: failed thruster(s): '
                f'{", ".join(THRUSTERS[i] for i in failed) or "none"}')

    def _check_commands(self) -> None:
        """realtime: zero thrust (tilts held) once thrust_cmd is command_timeout old (with a
        respawn configured, ``respawn_hold`` old: the last command holds while a respawned
        allocator takes over)."""
        timeout = self.config.command_timeout
        if timeout > 0 and self.config.respawn_hold > 0:
            timeout = max(timeout, self.config.respawn_hold)
        last = self._last_thrust_at
        if (last is None or timeout <= 0 or self.commands_stale
                or self.plant.time_ns - last <= to_ns(timeout)):
            return
        self.commands_stale = True
        self.stale_events += 1
        self.plant.command(thrusts=(0.0,) * 4)
        self.get_logger().warning(
            f'no thrust_cmd for {seconds(self.plant.time_ns - last):.3f} s of sim time '
            f'(timeout {timeout:g} s): thrusters commanded to zero until commands '
            'return')

    def _state_readers(self) -> tuple[int, ...]:
        """Readers matched on each writer of the state (odom, joint_states, /clock, /tf)."""
        pubs = (self._odom_pub, self._joint_pub, self._clock_pub)
        tf = () if self.transforms is None else (self.transforms.publisher,)
        return tuple(pub.get_subscription_count() for pub in pubs + tf)

    # -- realtime --------------------------------------------------------------------

    def _start_realtime(self) -> None:
        self._publish_state()
        self._rebase()
        self._make_step_timer()

    def _rebase(self) -> None:
        self._rt_origin = (self.steady_ns(), self.plant.time_ns)

    def _make_step_timer(self) -> None:
        if self._step_timer is not None:
            self.destroy_timer(self._step_timer)
        period = max(seconds(self.config.step_ns) / self.config.real_time_factor, 0.001)
        self._step_timer = self.create_timer(period, self._realtime_step, clock=self.steady)

    @guarded
    def _realtime_step(self) -> None:
        if self.finished.done():
            return
        wall0, sim0 = self._rt_origin
        due = sim0 + int((self.steady_ns() - wall0) * self.config.real_time_factor)
        steps = 0
        while self.plant.time_ns + self.config.step_ns <= due:
            if self._reached_end():
                break
            if steps == MAX_CATCH_UP:
                self.overruns += 1
                self.get_logger().warning(
                    f'cannot keep up with real_time_factor {self.config.real_time_factor:g}; '
                    'sim time falls behind', throttle_duration_sec=THROTTLE)
                self._rebase()
                break
            self._check_commands()
            self._step()
            steps += 1
        if self._reached_end():
            self._finish()

    # -- parameters ------------------------------------------------------------------

    def _validate_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        return self.check_failed_thrusters(parameters)

    def _apply_parameters(self, parameters: list[Parameter]) -> None:
        """Run-time changes (ranges, types and read-only are checked by rclpy)."""
        for p in parameters:
            if p.name == 'failed_thrusters':
                self.config = replace(self.config,
                                      failed_thrusters=failed_thruster_indices(p.value))
                self._update_failed()
            elif p.name == 'command_timeout':
                self.config = replace(self.config, command_timeout=float(p.value))
            if p.name == 'real_time_factor':
                self.config = replace(self.config, real_time_factor=float(p.value))
                if not self.lockstep:
                    self._rebase()
                    self._make_step_timer()
            elif p.name == 'stall_timeout':
                self.config = replace(self.config, stall_timeout=float(p.value))

    # -- diagnostics and shutdown ----------------------------------------------------

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        now, t = self.steady_ns(), self.plant.time_ns
        wall0, sim0 = self._diag_mark
        if now > wall0:
            self._rtf_achieved = (t - sim0) / (now - wall0)
        self._diag_mark = (now, t)
        level, message = OK, f'{self.config.mode} at {format_ns(t)}'
        lockstep = self.lockstep_status()
        if not self._started:
            message = f'{self.config.mode}: waiting for {lockstep["waiting_for"]}'
        elif self.finished.done():
            message = f'finished at {format_ns(t)}'
        elif self._stalled:
            level = WARN
            message = f'stalled at {format_ns(t)}: waiting for thrust_cmd/tilt_cmd'
        elif lockstep['waiting_for_recorder']:
            message = f'waiting at {format_ns(t)} for the bag recorder (paced)'
        elif self.commands_stale:
            level = WARN
            message = (f'no thrust_cmd for more than command_timeout '
                       f'{self.config.command_timeout:g} s: thrusters at zero')
        if self.stalls and level == OK:
            message += f' ({self.stalls} stall(s) so far)'
        plant = self.plant
        return level, message, {
            'mode': self.config.mode, 'sim_time': seconds(t),
            'real_time_factor_achieved': self._rtf_achieved, **lockstep,
            'overruns': self.overruns,
            'rejected_thrust_commands': plant.thrusters.rejected,
            'rejected_tilt_commands': plant.servos.rejected,
            'finished': self.finished.done(),
            'commands_stale': self.commands_stale, 'command_stale_events': self.stale_events,
            'failed_thrusters': [i + 1 for i in plant.failed_thrusters],
        }


def main(args: list[str] | None = None) -> int:
    """``plant_simulator [--ros-args --params-file config/plant_simulator.yaml ...]``."""

    def until(node: Any) -> Future | None:
        return node.finished if node.config.exit_at_end else None

    return main_loop(PlantSimulator, args, PLANT, until=until)


if __name__ == '__main__':
    sys.exit(main())
