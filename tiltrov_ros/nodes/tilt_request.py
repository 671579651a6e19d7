"""How the allocator pairs ``tilt_request`` with ``wrench_cmd`` (the switching
baseline fixes the tilts itself: its request, same stamp as its wrench, makes the
allocator hold the tilts there and solve for the thrusts, ``allocate_fixed``).

Parameter ``tilt_request`` of the allocator:

* ``required``: every wrench waits for the tilt request with its stamp (they
  travel on two topics, so either may come first). In a lockstep run (the plant's
  mode, from the run's handshake) it waits however long: a wait longer than
  ``input_timeout`` is reported, nothing more. Otherwise (realtime, or alone), after
  ``input_timeout`` wall seconds the latest request received is used (counted on
  /diagnostics). The wait is measured from the oldest wrench not answered: a newer
  wrench replaces the waiting one (realtime) but does not restart the wait;
* ``ignored``: free allocation, the topic is not subscribed;
* ``auto`` (default): in a lockstep run, decided at the run's handshake and said in
  the log: ``required`` if a node of the run publishes ``tilt_request``, else
  ``ignored``. Otherwise free allocation until a tilt request carries the stamp
  of a wrench (the switching controller's do); from then on ``required``,
  until a wrench waits ``input_timeout`` in vain, which returns to free
  allocation. A request that matches no wrench (a stray publisher, another
  run's replay) changes nothing; /diagnostics counts the requests received
  and matched and names the topic's publishers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sensor_msgs.msg import JointState

from tiltrov_ros.core.names import LOCKSTEP, PLANT, TILT_REQUEST, TILTS
from tiltrov_ros.core.timebase import format_ns, seconds

from .base import OK, WARN
from .conversions import FloatArray, joint_state_values
from .guard import THROTTLE, guarded, input_callback
from .handshake import MODE_KEY

#: The ``tilt_request`` modes.
TILT_REQUEST_MODES = ('auto', 'required', 'ignored')
#: Most messages kept by stamp (tilt requests, measured tilts) waiting for their wrench.
BUFFER = 200


def keep_bounded(by_stamp: dict[int, Any], ns: int, value: Any) -> None:
    """``by_stamp[ns] = value``, dropping the oldest stamps beyond :data:`BUFFER`."""
    by_stamp[ns] = value
    if len(by_stamp) > BUFFER:
        for stamp in sorted(by_stamp)[:len(by_stamp) - BUFFER]:
            del by_stamp[stamp]


@dataclass
class _Waiting:
    ns: int
    wrench: FloatArray
    since: int      # steady ns


class TiltRequests:
    """The pairing, a base of the allocator node (which gives ``tilt_request_mode``,
    ``input_timeout``, ``_last_ns``, ``_allocate`` and the node's clocks and logger)."""

    def init_tilt_requests(self) -> None:
        self._requests: dict[int, tuple[float, float]] = {}
        self._latest_request: tuple[float, float] | None = None
        #: auto mode: tilt requests have been carrying the wrenches' stamps.
        self._paired = self.tilt_request_mode == 'required'
        self.requests_received = 0
        self.requests_matched = 0
        self._waiting: _Waiting | None = None
        #: wrenches that waited input_timeout in vain; replaced while waiting (realtime).
        self.stale_requests = 0
        self.dropped = 0
        self._reported_wait: int | None = None     # lockstep: the wait told of

    def in_lockstep_run(self) -> bool:
        """The node is in a run whose plant is in lockstep (its handshake state says)."""
        plant = self.handshake.state_of(PLANT)
        return plant is not None and plant.extra.get(MODE_KEY) == LOCKSTEP

    def decide_tilt_requests(self) -> None:
        """In a lockstep run, at the handshake: ``auto`` becomes ``required`` if a node of
        the run publishes ``tilt_request``, else ``ignored`` (said once)."""
        if self.tilt_request_mode != 'auto' or not self.in_lockstep_run():
            return
        topic = self.resolve_topic_name(TILT_REQUEST)
        senders = sorted(n for n, state in self.handshake.states.items()
                         if any(t == topic for t, _ in state.publishes))
        self.tilt_request_mode = 'required' if senders else 'ignored'
        self._paired = bool(senders)
        self.get_logger().info(
            f'tilt_request auto, lockstep run: {self.tilt_request_mode} for the whole run ('
            + (f'published by {", ".join(senders)})' if senders else 'no node of the run '
               'publishes it)'))

    def _needs_request(self) -> bool:
        return self.tilt_request_mode != 'ignored' and self._paired

    def _matched(self) -> None:
        """A tilt request carried a wrench's stamp."""
        self.requests_matched += 1
        if not self._paired:
            self._paired = True
            self.get_logger().info('tilt_request carries the wrench_cmd stamps: tilts fixed '
                                   'by the request from now on')

    def _wait(self, ns: int, wrench: FloatArray) -> None:
        """The wrench stamped ``ns`` waits for its tilt request."""
        since = self.steady_ns()
        if self._waiting is not None:
            self.dropped += 1     # a newer wrench came first (realtime)
            since = self._waiting.since     # the wait goes on: it does not restart
        self._waiting = _Waiting(ns, wrench, since)

    @input_callback(TILT_REQUEST)
    def _on_tilt_request(self, msg: JointState) -> None:
        ns = self.check_header(msg.header, None)
        values = joint_state_values(msg, TILTS, 'position')
        request = (values[0], values[1])
        self.requests_received += 1
        keep_bounded(self._requests, ns, request)
        self._latest_request = request
        if ns == self._last_ns:     # it came after its wrench was answered (free)
            self._matched()
        waiting = self._waiting
        if waiting is not None and waiting.ns == ns:
            self._matched()
            self._allocate(ns, waiting.wrench, request)

    @guarded
    def _watchdog(self) -> None:
        waiting = self._waiting
        if waiting is None:
            return
        waited = seconds(self.steady_ns() - waiting.since)
        if waited < self.input_timeout:
            return
        if self.in_lockstep_run():
            if self._reported_wait != waiting.ns:       # waits by stamp: told, not timed out
                self._reported_wait = waiting.ns
                self.get_logger().warning(f'waiting for the tilt_request stamped '
                                          f'{format_ns(waiting.ns)} ({waited:.2f} s so far)')
            return
        self.stale_requests += 1
        if self.tilt_request_mode == 'auto':
            self._paired = False
            self.get_logger().warning(
                f'no tilt_request stamped {format_ns(waiting.ns)} after {waited:.2f} s: '
                'free allocation until a request carries a wrench stamp again',
                throttle_duration_sec=THROTTLE)
            self._allocate(waiting.ns, waiting.wrench, None)
            return
        self.get_logger().warning(
            f'no tilt_request stamped {format_ns(waiting.ns)} after {waited:.2f} s: using '
            f'{"the latest" if self._latest_request else "none (free allocation)"}',
            throttle_duration_sec=THROTTLE)
        self._allocate(waiting.ns, waiting.wrench, self._latest_request)

    def _tilt_request_status(self) -> tuple[int, str, dict[str, Any]]:
        """What the tilt requests do: paired with the wrenches or not, who sends them,
        wrenches that waited in vain or were replaced while waiting."""
        if self.tilt_request_mode == 'ignored':
            return OK, '', {}
        infos = self.get_publishers_info_by_topic(self.resolve_topic_name(TILT_REQUEST))
        senders = sorted({f'{i.node_namespace.rstrip("/")}/{i.node_name}' for i in infos})
        level, text = OK, ''
        unmatched = self.requests_received - self.requests_matched
        if self.dropped or (self.stale_requests and self._paired):
            level = WARN
            text = (f'; wrenches waiting for tilt_request: {self.stale_requests} timed out, '
                    f'{self.dropped} replaced by newer ones')
        elif self.requests_received and not self._paired:
            level = WARN
            text = (f'; {unmatched} tilt_request(s) from {", ".join(senders) or "(gone)"} '
                    'carry no wrench_cmd stamp: ignored (free allocation)')
        return level, text, {
            'tilt_request_pairing': 'paired' if self._paired else 'free',
            'tilt_requests_received': self.requests_received,
            'tilt_requests_matched': self.requests_matched,
            'tilt_request_publishers': senders}
