"""``bag_recorder``: records the stack's topics into a rosbag2 bag with MCAP storage.

The serialized CDR bytes each subscription receives are written untouched
(raw subscriptions, no deserialization), with the publishers' QoS in the
metadata and the message definitions as ``ros2msg`` schemas, so ``ros2 bag``,
rosbags, the mcap library and Foxglove open the bag. See docs/bags.md.

Design points:

* Throughput: each callback, after the message the executor took, takes the
  messages already queued on the same subscription (up to ``_DRAIN_LIMIT``),
  which keeps the executor's per-message overhead off the hot path.
* The stack's topics (:data:`~tiltrov_ros.core.names.STACK_TOPICS`) and the
  transform tree's (``/tf``, and ``/tf_static`` transient local, as rosbag2
  records it: a static transform published before the recorder started is
  recorded too; when tf2_msgs is importable) and ``robot_description`` (transient
  local) are subscribed at start-up, before
  their publishers exist, so the first message of a run is recorded; other
  topics are found by polling the graph every ``discovery_period`` seconds.
* Log time follows the node's clock. Without ``use_sim_time`` it is the time
  the middleware received the message (system time). With ``use_sim_time`` it
  is the value of the latest ``/clock`` message the recorder itself has taken,
  and before writing any other message the recorder takes every ``/clock``
  message already delivered. So every ``/clock`` message is logged at its own
  value, log times never run backwards while sim time does not, and a message
  published after the ``/clock`` that advanced time to t is logged at t or
  later (same or faster delivery assumed; DDS does not order across topics).
* ``flush_period`` bounds what a killed recorder loses: the pending MCAP chunk
  is written out at least that often (and whenever it reaches 1 MiB).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime
import functools
import json
import signal
import sys
import threading
import time
from typing import Any

from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.context import Context
from rclpy.event_handler import QoSMessageLostInfo, SubscriptionEventCallbacks
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
import rclpy.logging
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.subscription import Subscription
from rosbags.interfaces import Connection

from tiltrov_ros import __version__
from tiltrov_ros.bag.bagfile import RUN_INFO_KEY, parse_run_info
from tiltrov_ros.bag.losses import RECORDER_KEY
from tiltrov_ros.bag.msgdefs import message_class, message_definition
from tiltrov_ros.bag.qos import matches, subscription_qos, to_bag_qos
from tiltrov_ros.bag.topics import is_hidden, normalize_type
from tiltrov_ros.bag.writer import BagWriter
from tiltrov_ros.core.errors import BagError, TiltrovError
from tiltrov_ros.core.names import (
    CLOCK,
    HANDOFF_TOPICS,
    HANDSHAKE_TOPICS,
    LATCHED_TOPICS,
    RECORDER,
    STACK_TOPICS,
    TF_TOPICS,
)
from tiltrov_ros.core.timebase import cdr_stamp
from tiltrov_ros.core.validation import InvalidInput, checked_stamp_ns

from .base import TiltrovNode
from .executors import FINISH_POLL, STOP_POLL, init
from .parameters import Overrides
from .recorder_config import declare_parameters
from .recorder_run import RecorderRun

VERSION_KEY = 'tiltrov.version'
_DRAIN_LIMIT = 1000       # messages taken per callback, for fairness between topics
_THROTTLE = 5.0           # s, for repeated warnings from callbacks


@dataclass
class RecorderStats:
    """Per-topic counters of a recorder."""

    received: dict[str, int]    # messages taken from DDS
    written: dict[str, int]     # messages written to the bag
    flushed: dict[str, int]     # messages in complete chunks on disk
    lost: dict[str, int]        # samples DDS reported lost (message_lost events)
    errors: int                 # messages that could not be written

    @property
    def total(self) -> int:
        return sum(self.written.values())


@dataclass(eq=False)
class _Topic:
    """One subscribed topic."""

    name: str
    msgtype: str
    qos: QoSProfile
    record: bool
    sub: Subscription | None = None
    connection: Connection | None = None
    offered: list[Any] = field(default_factory=list)   # publishers' TopicEndpointInfo
    received: int = 0
    lost: int = 0
    warned: set[str] = field(default_factory=set)


class BagRecorder(RecorderRun, TiltrovNode):
    """Records topics into a rosbag2/MCAP bag (see the module docstring).

    Constructed as every node of the package (:class:`~tiltrov_ros.nodes.base.TiltrovNode`:
    ``node_name``, ``namespace``, ``context``, ``cli_args``, ``parameter_overrides``,
    e.g. ``{'output': 'runs/x', 'run_info': '{...}'}``, which win over parameter
    files). It publishes no /diagnostics and never waits for itself.

    Raises:
        ParameterError: invalid parameters.
        BagError: the output directory exists or cannot be created.

    """

    stack_node = False

    def __init__(self, *, node_name: str = RECORDER, namespace: str | None = None,
                 context: Context | None = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None) -> None:
        super().__init__(node_name, namespace=namespace, context=context, cli_args=cli_args,
                         parameter_overrides=parameter_overrides)
        self.config = declare_parameters(self)
        output = self.config.output or datetime.now().strftime('rosbag2_%Y_%m_%d-%H_%M_%S')
        self._bag = BagWriter(output, compression=self.config.compression, custom_data={
            RUN_INFO_KEY: self.config.run_info, VERSION_KEY: __version__})
        self.output = self._bag.path
        self._use_sim_time = bool(self.get_parameter('use_sim_time').value)
        self._clock_ns = 0
        self._bad_clock = 0         # /clock samples that were not a time
        self._clock_topic: _Topic | None = None
        self._topics: dict[str, _Topic] = {}
        self._skipped: set[str] = set()
        self._errors = 0
        self._first_error = ''
        self._closed = False
        # bound for draining a whole queue (a queue never holds more than its depth)
        self._queue_limit = self.config.queue_depth or 1_000_000
        self._selected = {self.resolve_topic_name(t) for t in self.config.topics}
        self._excluded = {self.resolve_topic_name(t) for t in self.config.exclude_topics}
        # Console only (not on /rosout): per-chunk debug lines would feed back into
        # the bag, and the summary is logged after a signal shut the context down.
        self._stats_logger = rclpy.logging.get_logger(f'{self.get_logger().name}.stats')
        self.add_on_set_parameters_callback(self._on_set_parameters)

        for relative, msgtype in STACK_TOPICS.items():
            name = self.resolve_topic_name(relative)
            if self._in_scope(name):
                # Load the definitions now: a first message must not stall the
                # recorder while publishers with shallow queues keep sending.
                message_definition(msgtype)
                # The restart handoff is transient local: read so from the start (adapting
                # the reader to its writer mid-run would lose what came meanwhile).
                self._subscribe(name, msgtype, [], latched=relative in HANDOFF_TOPICS)
        # The tree, and what is written once (transient local), read so from the start: a
        # latched topic found by polling may come after a short run has ended, and the
        # handshake then has the recorder wait for its writer's match like any other.
        for relative, msgtype in {**TF_TOPICS, **LATCHED_TOPICS}.items():
            name = self.resolve_topic_name(relative)
            if self._in_scope(name) and _importable(msgtype):
                message_definition(msgtype)
                self._subscribe(name, msgtype, [], latched=relative in LATCHED_TOPICS)
        if self._use_sim_time and self._clock_topic is None:
            self._subscribe(CLOCK, STACK_TOPICS[CLOCK], [], record=False)

        self.init_run()

        wall = Clock(clock_type=ClockType.STEADY_TIME)
        self._discover()
        self.create_timer(self.config.discovery_period, self._discover, clock=wall)
        if self.config.flush_period > 0:
            self.create_timer(self.config.flush_period, self._flush, clock=wall)
        self.join_run()
        self.get_logger().info(
            f'recording {"every topic" if not self._selected else sorted(self._selected)} '
            f'into {self.output} (log time: {"/clock" if self._use_sim_time else "system"})')

    # -- which topics ----------------------------------------------------------

    def _in_scope(self, name: str) -> bool:
        if any(name == self.resolve_topic_name(t) for t in HANDSHAKE_TOPICS):
            return False        # the run's handshake and progress are never recorded
        if self._selected:
            return name in self._selected
        if name in self._excluded:
            return False
        return self.config.include_hidden or not is_hidden(name)

    def _subscribe(self, name: str, msgtype: str, publishers: Sequence[Any], *,
                   record: bool = True, latched: bool = False) -> None:
        """Create (or re-create) the raw subscription of ``name`` for ``publishers``
        (the graph's endpoint infos, possibly none yet); ``latched``: transient local
        before any publisher is known."""
        try:
            msg_class = message_class(msgtype)
        except BagError as exc:
            if name not in self._skipped:
                self._skipped.add(name)
                self.get_logger().warning(f'not recording {name}: {exc}')
            return
        qos = subscription_qos([p.qos_profile for p in publishers], self.config.queue_depth)
        if name == CLOCK and not record:
            qos.reliability = ReliabilityPolicy.BEST_EFFORT  # time only: match any /clock
        if latched and not publishers:
            qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
        topic = self._topics.get(name)
        if topic is None:
            topic = _Topic(name, msgtype, qos, record)
            self._topics[name] = topic
        else:
            self._drain(topic, limit=self._queue_limit)
            if topic.sub is not None:
                self.destroy_subscription(topic.sub)
            topic.qos = qos
        topic.offered = list(publishers) or topic.offered
        events = SubscriptionEventCallbacks(
            message_lost=functools.partial(self._on_lost, topic))
        topic.sub = self.create_subscription(
            msg_class, name, functools.partial(self._on_message, topic), qos,
            raw=True, event_callbacks=events)
        if name == CLOCK and self._use_sim_time:
            self._clock_topic = topic

    def _discover(self) -> None:
        """Subscribe to new topics; re-subscribe where the publishers' QoS needs it."""
        try:
            for name, types in self.get_topic_names_and_types():
                if not self._in_scope(name) or name in self._skipped:
                    continue
                infos = self.get_publishers_info_by_topic(name)
                if not infos:
                    continue
                topic = self._topics.get(name)
                if topic is None:
                    if len(types) != 1:
                        self._skipped.add(name)
                        self.get_logger().warning(f'not recording {name}: several types {types}')
                        continue
                    self._subscribe(name, normalize_type(types[0]), infos)
                    continue
                topic.offered = infos
                if normalize_type(types[0]) != topic.msgtype or len(types) != 1:
                    self._warn_once(topic, 'type', f'{name} is published as {types}; '
                                    f'recording only {topic.msgtype}')
                elif not matches(topic.qos, [info.qos_profile for info in infos]):
                    self.get_logger().info(f'{name}: adapting the subscription QoS to its '
                                           'publishers')
                    self._subscribe(name, topic.msgtype, infos)
        except Exception as exc:  # never kill the executor
            if not self.context.ok():
                # A signal shut the context down while a discovery tick ran: nothing
                # is lost (close() still drains every subscription).
                self.get_logger().debug(f'graph discovery during shutdown: {exc}')
                return
            # Mid-run: a topic may go unrecorded, so the bag must say so.
            self._write_error(f'graph discovery failed: {exc}')

    # -- messages ----------------------------------------------------------------

    def _on_message(self, topic: _Topic, data: bytes, info: Mapping[str, Any]) -> None:
        """Raw subscription callback: record this message and those queued behind it."""
        self._record_safely(topic, data, info)
        self._drain(topic, limit=_DRAIN_LIMIT)
        if self._finals:
            self._confirm_finals()

    def _record_safely(self, topic: _Topic, data: bytes, info: Mapping[str, Any]) -> None:
        """Record one message; one that cannot be written is counted (a write error),
        never raised: the next ones are still taken."""
        try:
            self._record(topic, data, info)
        except Exception as exc:
            self._write_error(f'cannot record a message of {topic.name}: {exc}')

    def _write_error(self, text: str) -> None:
        """Count and log (throttled) a message or chunk that could not be written."""
        self._errors += 1
        self._first_error = self._first_error or text
        self.get_logger().error(f'{text} ({self._errors} error(s) so far)',
                                throttle_duration_sec=_THROTTLE)

    def _drain(self, topic: _Topic, limit: int) -> None:
        """Take and record messages already queued on ``topic``'s subscription."""
        sub = topic.sub
        if sub is None:
            return
        handle = sub.handle
        taken = 0
        with handle:
            while taken < limit:
                got = handle.take_message(sub.msg_type, True)
                if got is None:
                    return
                taken += 1
                self._record_safely(topic, got[0], got[1])

    def _record(self, topic: _Topic, data: bytes, info: Mapping[str, Any]) -> None:
        if self._closed:
            return
        topic.received += 1
        if topic is self._clock_topic:
            self._take_clock(data)
            log_time = self._clock_ns
        elif self._clock_topic is not None:
            self._drain(self._clock_topic, limit=_DRAIN_LIMIT)  # /clock before later data
            log_time = self._clock_ns
        else:
            log_time = int(info.get('received_timestamp', 0)) or time.time_ns()
        if not topic.record:
            return
        try:
            if topic.connection is None:
                topic.connection = self._add_connection(topic)
            if self._bag.write(topic.connection, log_time, data):
                self._log_flushed()
        finally:
            # Taken is taken: a message that could not be written is counted and
            # reported (exit code 1), and never holds a paced run.
            if topic.name in self._paced:
                self._note_paced(topic.name, data)
            elif topic.name == self._diagnostics_name and self.handshake.active:
                self._note_diagnostics(data)

    def _take_clock(self, data: bytes) -> None:
        """Log time from a /clock sample: a malformed one (no stamp, ``sec < 0``,
        ``nanosec >= 1e9``) is recorded as it came but leaves the log time at the
        last good sample (counted, logged); a sample earlier than the last moves
        the log time back with it (time starts over: nodes/simclock.py)."""
        try:
            self._clock_ns = checked_stamp_ns(*cdr_stamp(data))
        except (InvalidInput, ValueError) as exc:
            self._bad_clock += 1
            self.get_logger().warning(
                f'/clock sample not a time ({exc}; {self._bad_clock} so far): logged at the '
                'last good one', throttle_duration_sec=_THROTTLE)

    def _add_connection(self, topic: _Topic) -> Connection:
        """The topic's bag connection, with its publishers' QoS (from the graph now,
        or as last discovered when the graph is gone, e.g. after a signal)."""
        try:
            infos = self.get_publishers_info_by_topic(topic.name) or topic.offered
        except Exception:
            infos = topic.offered
        type_hash = next((str(i.topic_type_hash) for i in infos
                          if str(getattr(i, 'topic_type_hash', '')).startswith('RIHS01_')), '')
        return self._bag.add_topic(topic.name, topic.msgtype,
                                   qos=[to_bag_qos(i.qos_profile) for i in infos],
                                   rihs01=type_hash or None)

    def _on_lost(self, topic: _Topic, info: QoSMessageLostInfo) -> None:
        topic.lost = int(info.total_count)
        self.get_logger().warning(f'{topic.name}: DDS lost {info.total_count_change} '
                                  f'message(s) ({info.total_count} in total)',
                                  throttle_duration_sec=_THROTTLE)
        if self._finals:
            self._confirm_finals()

    def _flush(self) -> None:
        try:
            if not self._closed and self._bag.flush():
                self._log_flushed()
        except Exception as exc:
            self._write_error(f'cannot flush {self.output}: {exc}')

    def _log_flushed(self) -> None:
        flushed = self._bag.flushed_counts
        self._stats_logger.debug(
            f'flushed {sum(flushed.values())} {json.dumps(flushed, sort_keys=True)}')

    def _warn_once(self, topic: _Topic, key: str, text: str) -> None:
        if key not in topic.warned:
            topic.warned.add(key)
            self.get_logger().warning(text)

    def _on_set_parameters(self, parameters: Iterable[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name == 'run_info':
                try:
                    parse_run_info(str(parameter.value))
                except BagError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
                if not self._closed:
                    self._bag.set_custom_data(RUN_INFO_KEY, str(parameter.value))
        return SetParametersResult(successful=True)

    # -- results and shutdown ----------------------------------------------------

    def stats(self) -> RecorderStats:
        """Per-topic counters of the recorded topics that carried messages."""
        recorded = [t for t in self._topics.values() if t.record]
        return RecorderStats(
            received={t.name: t.received for t in recorded if t.received},
            written=self._bag.counts,
            flushed=self._bag.flushed_counts,
            lost={t.name: t.lost for t in recorded if t.lost},
            errors=self._errors)

    @property
    def subscribed_topics(self) -> dict[str, str]:
        """Recorded topic name -> type, as subscribed so far."""
        return {t.name: t.msgtype for t in self._topics.values() if t.record}

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> RecorderStats:
        """Record what is still queued, close the bag and log the counts. Idempotent."""
        if self._closed:
            return self.stats()
        for topic in list(self._topics.values()):
            try:
                self._drain(topic, limit=self._queue_limit)
            except Exception as exc:  # e.g. the context is already shut down
                self.get_logger().debug(f'final drain of {topic.name}: {exc}')
        self._closed = True
        for topic in self._topics.values():
            sub, topic.sub = topic.sub, None
            if sub is not None:
                try:
                    self.destroy_subscription(sub)
                except Exception as exc:
                    self.get_logger().debug(f'destroying the {topic.name} subscription: {exc}')
        try:
            self._bag.set_custom_data(RECORDER_KEY, json.dumps(self._account(), sort_keys=True))
        except Exception as exc:  # a full disk: the bag says nothing, the exit code does
            self._write_error(f'cannot write the metadata of {self.output}: {exc}')
        try:
            self._bag.close()
        except Exception as exc:
            self._write_error(f'cannot close {self.output}: {exc}')
        stats = self.stats()
        lines = [f'recorded {stats.total} messages on {len(stats.written)} topics '
                 f'into {self.output}']
        lines += [f'  {name}: {count}' for name, count in sorted(stats.written.items())]
        self._stats_logger.info('\n'.join(lines))
        if stats.lost or stats.errors:
            self._stats_logger.warning(f'lost in DDS: {stats.lost}; write errors: '
                                       f'{stats.errors}')
        return stats

    def _account(self) -> dict[str, Any]:
        """What the recorder itself knows it lost (``tiltrov.recorder`` in the bag)."""
        stats = self.stats()
        return {'write_errors': stats.errors, 'first_error': self._first_error,
                'lost_in_dds': stats.lost, 'bad_clock_samples': self._bad_clock}

    @property
    def first_error(self) -> str:
        """The first write error, as logged ('' if none)."""
        return self._first_error

    @property
    def lost_data(self) -> bool:
        """True when a message could not be written or DDS reported samples lost."""
        stats = self.stats()
        return bool(stats.errors or stats.lost)

    def destroy_node(self) -> None:
        try:
            self.close()
        except TiltrovError as exc:
            self.get_logger().error(str(exc))
        finally:
            super().destroy_node()


def _importable(msgtype: str) -> bool:
    """``msgtype``'s Python class can be imported (tf2_msgs in a venv without it: no)."""
    try:
        message_class(msgtype)
    except BagError:
        return False
    return True


def main(args: list[str] | None = None) -> int:
    """``bag_recorder [--ros-args -p output:=DIR ...]``.

    SIGINT ends the recording: at once for a recorder without run nodes; in a run, once
    every run node's final report (and every message it counts) is written or the node
    is gone (:meth:`BagRecorder.unrecorded_nodes`). A second SIGINT, or SIGTERM, ends it
    at once. Either way the queues are drained and the bag closed.
    """
    stop = threading.Event()
    hurry = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        if stop.is_set() or signum == signal.SIGTERM:
            hurry.set()
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, on_signal)
    if not init(args, RECORDER, signal_handlers=False):
        return 1
    context = rclpy.get_default_context()
    executor = SingleThreadedExecutor(context=context)
    node: BagRecorder | None = None
    try:
        node = BagRecorder()
        executor.add_node(node)
        while context.ok() and not stop.is_set():
            executor.spin_once(timeout_sec=STOP_POLL)
        node.stopping = True
        if node.handshake.active:
            waiting = node.unrecorded_nodes()
            if waiting and not hurry.is_set():
                node.get_logger().info(f'stopping once the final reports of '
                                       f'{", ".join(waiting)} are written')
            while context.ok() and not hurry.is_set() and node.unrecorded_nodes():
                executor.spin_once(timeout_sec=FINISH_POLL)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (TiltrovError, ParameterException) as exc:
        print(f'bag_recorder: {exc}', file=sys.stderr)
        return 1
    except Exception:
        if rclpy.ok():
            raise
        # else: the context shut down while the node was starting
    finally:
        executor.shutdown(timeout_sec=1.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if node is not None and node.lost_data:
        stats = node.stats()
        print(f'bag_recorder: data lost in {node.output}: {stats.errors} message(s) not '
              f'written{f" ({node.first_error})" if stats.errors else ""}; DDS lost: '
              f'{stats.lost or "none"}', file=sys.stderr, flush=True)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
