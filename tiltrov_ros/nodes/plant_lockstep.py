"""The plant's lockstep (a base of :class:`~tiltrov_ros.nodes.plant_simulator.PlantSimulator`):
when it starts, what each control tick waits for, the pacing by the recorder, stalls.

* **Start.** In a run (``run_nodes``), the initial state goes out once the run's handshake
  is complete (every node matched every other, seen from both sides: nodes/handshake.py)
  and ``startup_subscribers`` readers are matched on ``odom``; in realtime too, then time
  starts. Alone (no run nodes), as on its own side: ``startup_subscribers`` odom readers
  and, in lockstep, a publisher on each command topic.
* **A tick.** At a control tick t the plant steps on only with a ``thrust_cmd`` *and* a
  ``tilt_cmd`` stamped t (and, when it draws ``robot_markers``, the ``wrench_cmd`` and
  ``wrench_achieved`` stamped t from the nodes that publish them at the start), exactly
  as :func:`tiltrov_ros.core.runner.run` does. No wall-clock time changes that: a wait
  longer than ``stall_timeout`` is reported (log, ``/diagnostics`` ``stalls``), nothing more.
* **A restart.** When the run's handshake is complete again with a new instance of a node
  (a respawned controller or allocator), the state of the tick waited at is published
  again; alone, when a new reader or command publisher matched on the plant's side. Every
  node answers a repeated stamp idempotently.
* **Pacing.** With the bag recorder among the run nodes, the plant steps past tick t only
  once the recorder reports (``recorder_progress``) that it has written ``/clock`` and every
  tick topic up to t - ``recorder_window``: it never runs further ahead of the bag than
  that, whatever the machine's load, so no writer's or reader's history can overflow. A
  wait for the recorder is counted apart (``waiting_for_recorder``), not as a stall.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from rosgraph_msgs.msg import Clock as ClockMsg

from tiltrov_ros.core.names import (
    RECORDER,
    RECORDER_PROGRESS,
    THRUST_CMD,
    TILT_CMD,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
)
from tiltrov_ros.core.timebase import format_ns, seconds, stamp_to_ns

from .guard import THROTTLE, guarded
from .handshake import END_KEY, MODE_KEY, WINDOW_KEY
from .qos import PROGRESS_QOS

if TYPE_CHECKING:
    from .plant_simulator import PlantSimulator

#: s (wall): how often the watchdog looks at the start-up and stall state.
WATCHDOG_PERIOD = 0.05
#: Most ticks with commands held before their time (only the present one is legitimate;
#: the cap keeps a misbehaving publisher from growing the table).
MAX_PENDING = 100
#: Marks a command that was received for a tick but rejected (held: previous stays).
REJECTED: list[float] = []
#: Slots of a tick's entry: the commands, then the wrenches the markers draw.
SLOTS = (THRUST_CMD, TILT_CMD, WRENCH_CMD, WRENCH_ACHIEVED)


class Lockstep:
    """Start, ticks, restarts and pacing (see the module docstring)."""

    def init_lockstep(self: PlantSimulator) -> None:
        # tick ns -> [thrust, tilts, wrench bytes, achieved bytes] (None: not yet)
        self._pending: dict[int, list[Any]] = {}
        #: Slots a tick needs: the commands, plus the markers' wrenches once decided.
        self._needed = 2
        self._started = False
        self._started_at = 0                       # steady ns of the initial state
        self._waiting_since: int | None = None     # steady ns, while waiting at a tick
        self._stalled = False                      # the present wait is a stall
        self.stalls = 0
        self.longest_stall_s = 0.0                 # wall s, the longest wait at a tick
        self.last_stall_ns: int | None = None     # the tick of the latest stall
        self._stall_told = 0                       # steady ns of its last log line
        self.republished = 0
        #: handshake generation of the state last published (a newer one republishes)
        self._published_generation = 0
        #: alone: the plant's own matches when the present wait began
        self._wait_counts: tuple[int, ...] = ()
        # pacing
        run = self.handshake.run_nodes
        self.paced = self.lockstep and RECORDER in run and self.get_name() != RECORDER
        self._window_ns = self.config.recorder_window_ns
        self.recorder_progress = -1
        self._recorder_since: int | None = None    # steady ns, while waiting for it
        self.recorder_waits = 0
        self.recorder_wait_s = 0.0
        self.handshake.extra[MODE_KEY] = self.config.mode
        if self.config.duration_ns:
            self.handshake.extra[END_KEY] = str(self.config.duration_ns)
        self._progress_sub: Any = None
        if self.paced:
            self.handshake.extra[WINDOW_KEY] = f'{seconds(self._window_ns):g}'
            self._progress_sub = self.create_subscription(ClockMsg, RECORDER_PROGRESS,
                                                          self._on_progress, PROGRESS_QOS)
        self._watchdog_timer = self.create_timer(WATCHDOG_PERIOD, self._watchdog,
                                                 clock=self.steady)

    # -- start ---------------------------------------------------------------------

    def on_handshake(self: PlantSimulator) -> None:
        if not self._started:
            self._try_start()
        elif self._waiting_since is not None and (
                self.handshake.generation > self._published_generation
                and self.handshake.run_ready()):
            self.get_logger().info(
                f'every node of the run is ready again (new: '
                f'{self._new_instances()}); publishing the state at '
                f'{format_ns(self.plant.time_ns)} again')
            self._republish()

    def _new_instances(self: PlantSimulator) -> str:
        return ', '.join(sorted(self.handshake.instances())) or 'none'

    def _own_side_ready(self: PlantSimulator) -> bool:
        """Alone: the odom readers and (lockstep) both command publishers matched; in a
        run the handshake covers every node, and only ``startup_subscribers`` is left."""
        if self._odom_pub.get_subscription_count() < self.config.startup_subscribers:
            return False
        if self.handshake.active:
            return self.handshake.run_ready()
        return not self.lockstep or all(sub.get_publisher_count() > 0
                                        for sub in self._command_subs)

    def _try_start(self: PlantSimulator) -> None:
        if self._started or not self._own_side_ready():
            return
        self._started = True
        self._started_at = self.steady_ns()
        self._decide_marker_wrenches()
        self.get_logger().info(
            f'{"every node of the run is ready" if self.handshake.active else "peers matched"}'
            f': {"publishing the initial state" if self.lockstep else "time starts"}')
        if not self.lockstep:
            self._start_realtime()
            return
        self._publish_state()
        self._advance()

    def _decide_marker_wrenches(self: PlantSimulator) -> None:
        """Lockstep: a tick waits for the wrenches the markers draw if a node publishes
        them now (a run node; alone: any publisher), so the markers are the run's."""
        if not self.lockstep or self.markers is None:
            return
        names = [self.resolve_topic_name(t) for t in (WRENCH_CMD, WRENCH_ACHIEVED)]
        if self.handshake.active:
            published = {t for s in self.handshake.states.values() for t, _ in s.publishes}
        else:
            published = {n for n in names if self.count_publishers(n) > 0}
        if all(n in published for n in names):
            self._needed = len(SLOTS)
        self.markers.by_stamp = self._needed == len(SLOTS)
        if not self.markers.by_stamp:
            self.get_logger().info('robot_markers draw the latest wrench_cmd and '
                                   'wrench_achieved: no node publishes both at the start')

    # -- ticks -----------------------------------------------------------------------

    def hold(self: PlantSimulator, ns: int, slot: int, value: Any) -> None:
        """Keep ``value`` for tick ``ns`` in ``slot`` (``REJECTED``: answered, but the
        previous command holds) and advance if the present tick is complete."""
        entry = self._pending.setdefault(ns, [None] * len(SLOTS))
        entry[slot] = value
        if len(self._pending) > MAX_PENDING:     # commands for ticks far ahead: nonsense
            del self._pending[max(self._pending)]
        self._advance()

    def _advance(self: PlantSimulator) -> None:
        """Step until a control tick whose inputs are missing, the recorder's window, or
        the end."""
        if not self._started or not self.lockstep:
            return
        plant = self.plant
        period = self.config.control_period_ns
        while True:
            if self._reached_end():
                self._finish()
                return
            t = plant.time_ns
            if t % period == 0:
                entry = self._pending.get(t)
                if entry is None or any(v is None for v in entry[:self._needed]):
                    self._start_wait()
                    return
                if self.paced and self.recorder_progress < t - self._window_ns:
                    if self._recorder_since is None:
                        self._recorder_since = self.steady_ns()
                        self.recorder_waits += 1
                    return
                self._end_recorder_wait()
                for kind, values in enumerate(entry[:2]):
                    if values:      # None was excluded above; REJECTED is empty
                        self._command(kind, values)
                if self.markers is not None and self.markers.by_stamp:
                    self.markers.use(entry[2], entry[3])
                for stamp in [s for s in self._pending if s <= t]:
                    del self._pending[stamp]
                self._end_wait()
            self._step()

    def _start_wait(self: PlantSimulator) -> None:
        if self._waiting_since is None:
            self._waiting_since = self.steady_ns()
            if not self.handshake.active:
                self._wait_counts = self._own_counts()

    def _waited(self: PlantSimulator) -> float:
        """Wall s of the present wait at a tick (0 when not waiting)."""
        since = self._waiting_since
        return 0.0 if since is None else seconds(self.steady_ns() - since)

    def _end_wait(self: PlantSimulator) -> None:
        if self._stalled:
            self.longest_stall_s = max(self.longest_stall_s, self._waited())
        self._waiting_since = None
        self._stalled = False

    def _end_recorder_wait(self: PlantSimulator) -> None:
        if self._recorder_since is not None:
            self.recorder_wait_s += seconds(self.steady_ns() - self._recorder_since)
            self._recorder_since = None

    def _on_progress(self: PlantSimulator, msg: ClockMsg) -> None:
        self.recorder_progress = max(self.recorder_progress,
                                     stamp_to_ns(msg.clock.sec, msg.clock.nanosec))
        if self._recorder_since is not None:
            self._advance()

    def _own_counts(self: PlantSimulator) -> tuple[int, ...]:
        """Alone: readers of the state and publishers of the commands, as matched here."""
        return (*self._state_readers(), *(s.get_publisher_count() for s in self._command_subs))

    # -- watchdog: start-up alone, restarts alone, stalls ---------------------------

    def _unpace_without_recorder(self: PlantSimulator) -> None:
        """The recorder's progress writer is gone (it died: DDS saw its lease expire):
        the run goes on unpaced, and says so."""
        self.paced = False
        self.get_logger().error(f'{RECORDER} is gone: the run goes on unpaced, unrecorded')
        self._end_recorder_wait()
        self._advance()

    @guarded
    def _watchdog(self: PlantSimulator) -> None:
        if not self._started:
            self._try_start()
            return
        if not self.lockstep:
            return
        if self.paced and self._progress_sub.get_publisher_count() == 0:
            self._unpace_without_recorder()
        since = self._waiting_since
        if since is None or self.finished.done():
            return
        if not self.handshake.active and any(
                n > n0 for n, n0 in zip(self._own_counts(), self._wait_counts)):
            self.get_logger().info('a new peer matched: publishing the state at '
                                   f'{format_ns(self.plant.time_ns)} again')
            self._republish()
            return
        waited = seconds(self.steady_ns() - since)
        if waited < self.config.stall_timeout:
            return
        t = self.plant.time_ns
        if not self._stalled:
            self.stalls += 1
            self._stalled = True
        entry = self._pending.get(t, [None] * len(SLOTS))
        missing = [name for name, got in zip(SLOTS[:self._needed], entry) if got is None]
        text = (f'stall at {format_ns(t)}: no {" and ".join(missing)} stamped with it after '
                f'{waited:.2f} s (waiting on: {self.handshake.run_waiting_for() or "answers"})')
        # The first stall at a tick is always told; then once every THROTTLE s.
        now = self.steady_ns()
        if self.last_stall_ns != t or seconds(now - self._stall_told) >= THROTTLE:
            self.last_stall_ns = t
            self._stall_told = now
            self.get_logger().warning(text)

    def _republish(self: PlantSimulator) -> None:
        self.republished += 1
        self._end_wait()
        self._waiting_since = self.steady_ns()
        if not self.handshake.active:
            self._wait_counts = self._own_counts()
        self._publish_state()

    def lockstep_status(self: PlantSimulator) -> dict[str, Any]:
        """The lockstep's keys of /diagnostics."""
        waiting = self._recorder_since is not None
        values: dict[str, Any] = {
            'stalls': self.stalls,
            'longest_stall_s': max(self.longest_stall_s,
                                   self._waited() if self._stalled else 0.0),
            'last_stall': seconds(self.last_stall_ns) if self.last_stall_ns is not None else '',
            'republished_states': self.republished,
            'waiting_for_recorder': waiting, 'recorder_waits': self.recorder_waits,
            'recorder_wait_s': self.recorder_wait_s + (
                seconds(self.steady_ns() - self._recorder_since) if waiting else 0.0)}
        if self.paced:
            values['recorder_window'] = seconds(self._window_ns)
            values['recorder_progress'] = (seconds(self.recorder_progress)
                                           if self.recorder_progress >= 0 else '')
        if not self._started:
            values['waiting_for'] = (self.handshake.run_waiting_for()
                                     or 'odom readers (startup_subscribers)')
        elif waiting:
            values['waiting_for'] = f'{RECORDER} (paced)'
        elif self._waiting_since is not None:
            values['waiting_for'] = 'the commands of the tick'
        return values
