"""The bag recorder's part in a run (a base of :class:`.bag_recorder.BagRecorder`): the
pacing of a recorded lockstep run and the run nodes' final reports.

* **Pacing.** When the plant's handshake state names a window (``recorder_window``), the
  recorder tracks, per paced topic (``/clock`` and each tick topic a node of the run
  publishes), the newest stamp it has taken, and publishes on ``recorder_progress`` the
  least of them whenever it moved by half the window (every tick for a window of 0): the
  plant steps at most that window ahead (nodes/plant_lockstep.py).
* **Final reports.** A node of the run that stops publishes its final ``/diagnostics``
  (its message counts) and waits until the recorder names its instance under
  ``recorded`` in its handshake state: once the report is taken and every message it
  counts is taken too (written, or counted as a write error). The recorder itself stops,
  at SIGINT, once every stack node of the run is so recorded or gone from the graph.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock as ClockMsg

from tiltrov_ros.bag.losses import resolve
from tiltrov_ros.core.names import (
    CLOCK,
    DIAGNOSTICS,
    FINAL_STATUS_KEY,
    PLANT,
    RECORDER_PROGRESS,
    STACK_NODES,
    TICK_TOPICS,
)
from tiltrov_ros.core.timebase import cdr_stamp_ns, format_ns, seconds, to_ns

from .base import OK, WARN
from .handshake import RECORDED_KEY, WINDOW_KEY
from .qos import PROGRESS_QOS

if TYPE_CHECKING:
    from .bag_recorder import BagRecorder


class RecorderRun:
    """Pacing and final reports (see the module docstring)."""

    def init_run(self: BagRecorder) -> None:
        # The run: final reports to confirm (nodes/base.recorded_by_the_run) and, in a
        # paced lockstep run, the progress the plant waits for.
        self._diagnostics_name = self.resolve_topic_name(DIAGNOSTICS)
        #: node -> (instance, resolved topic -> messages published) of a final report
        #: recorded but not yet confirmed (some of those messages still to be written)
        self._finals: dict[str, tuple[str, dict[str, int]]] = {}
        self._recorded: dict[str, str] = {}     # node -> instance confirmed
        self._paced: frozenset[str] = frozenset()
        self._window: float | None = None       # s of sim time; None: not paced
        self._latest: dict[str, int] = {}       # paced topic -> newest stamp written
        self.progress = -1                       # ns: every paced topic written up to it
        self._progress_sent: int | None = None
        self._progress_msg = ClockMsg()
        self._progress_pub = (self.create_publisher(ClockMsg, RECORDER_PROGRESS, PROGRESS_QOS)
                              if self.handshake.active else None)
        self.stopping = False

    def on_handshake(self: BagRecorder) -> None:
        """The plant's state says whether the run is paced (its window); the paced topics
        are ``/clock`` and the tick topics some node of the run publishes."""
        plant = self.handshake.state_of(PLANT)
        window = plant.extra.get(WINDOW_KEY) if plant is not None else None
        if window is None:
            return
        published = {t for state in self.handshake.states.values() for t, _ in state.publishes}
        paced = frozenset({self.resolve_topic_name(CLOCK)} | {
            name for name in map(self.resolve_topic_name, TICK_TOPICS) if name in published})
        if (float(window), paced) != (self._window, self._paced):
            self._window, self._paced = float(window), paced
            self._latest = {t: v for t, v in self._latest.items() if t in paced}
            self.get_logger().info(
                f'paced lockstep run: the plant steps at most {self._window:g} s of sim time '
                f'ahead of what is written of {", ".join(sorted(paced))}')
            self._update_progress()

    def _note_paced(self: BagRecorder, name: str, data: bytes) -> None:
        try:
            stamp = cdr_stamp_ns(data)
        except ValueError:
            return
        if stamp > self._latest.get(name, -1):
            self._latest[name] = stamp
            self._update_progress()

    def _update_progress(self: BagRecorder) -> None:
        """``recorder_progress``: the sim time up to which every paced topic is written,
        sent whenever it moved by half the window (every tick for a window of 0)."""
        if self._window is None or self._progress_pub is None:
            return
        progress = min((self._latest.get(t, -1) for t in self._paced), default=-1)
        if progress <= self.progress:
            return
        self.progress = progress
        sent = self._progress_sent
        if sent is not None and progress < sent + to_ns(self._window) // 2:
            return
        self._progress_sent = progress
        msg = self._progress_msg
        msg.clock.sec, msg.clock.nanosec = divmod(progress, 1_000_000_000)
        self._progress_pub.publish(msg)

    def _note_diagnostics(self: BagRecorder, data: bytes) -> None:
        """Keep the final reports of the run's nodes (confirmed once the bag has every
        message they count)."""
        try:
            msg = deserialize_message(data, DiagnosticArray)
        except Exception:
            return
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            name = status.name.rsplit('/', 1)[-1]
            if values.get(FINAL_STATUS_KEY) != 'true' or name not in self.handshake.run_nodes:
                continue
            published = {resolve(status.name, key.removeprefix('published.')): int(value)
                         for key, value in values.items()
                         if key.startswith('published.') and value.isdigit()}
            self._finals[name] = (values.get('instance', ''), published)

    def _confirm_finals(self: BagRecorder) -> None:
        """Confirm each final report whose counted messages are all accounted for: taken
        (what is queued on every topic is taken first; a message taken and not written is
        a write error) or reported lost by DDS (it will never come: a node that waited
        for it would wait for ever). Both are in the bag's report and the exit code."""
        for topic in list(self._topics.values()):
            self._drain(topic, limit=self._queue_limit)
        accounted = {t.name: t.received + t.lost for t in self._topics.values() if t.record}
        done = [name for name, (_, published) in self._finals.items()
                if all(accounted.get(topic, 0) >= n for topic, n in published.items())]
        if not done:
            return
        for name in done:
            self._recorded[name] = self._finals.pop(name)[0]
        self.handshake.extra[RECORDED_KEY] = ' '.join(
            f'{name}={instance}' for name, instance in sorted(self._recorded.items()))
        self.handshake.evaluate()

    def unrecorded_nodes(self: BagRecorder) -> list[str]:
        """The run's stack nodes whose last instance is still in the graph without its
        final report confirmed (the recorder stops once there are none; a node that
        joined the run from outside the package sends no final report)."""
        hs = self.handshake
        alive = {n for n, ns in self.get_node_names_and_namespaces()
                 if ns == self.get_namespace()}
        return [n for n in hs.run_nodes if n in STACK_NODES and n in alive
                and (hs.state_of(n) is None
                     or self._recorded.get(n) != hs.state_of(n).instance)]  # type: ignore[union-attr]

    def diagnostic_status(self: BagRecorder) -> tuple[int, str, dict[str, Any]]:
        stats = self.stats()
        level = WARN if stats.lost or stats.errors else OK
        message = f'{stats.total} messages written into {self.output}'
        values: dict[str, Any] = {
            'written': stats.total, 'lost_in_dds': sum(stats.lost.values()),
            'write_errors': stats.errors, 'stopping': self.stopping,
            'recorded_final_reports': ' '.join(sorted(self._recorded))}
        if self._window is not None:
            values['progress'] = seconds(self.progress) if self.progress >= 0 else ''
            values['pacing_window'] = self._window
            message += (f'; paced, written up to {format_ns(self.progress)}'
                        if self.progress >= 0 else '; paced')
        if self.stopping:
            waiting = self.unrecorded_nodes()
            values['waiting_for'] = ', '.join(f'the final report of {n}' for n in waiting)
            message += f'; stopping{f", waiting for {len(waiting)} node(s)" if waiting else ""}'
        return level, message, values
