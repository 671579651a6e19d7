"""The base of the stack's nodes: construction, parameters in command-line order,
diagnostics, guarded publishers and the recorder hold (input validation and the
callback guard: nodes/guard.py).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
import math
import time
from typing import Any, ClassVar

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.context import Context
from rclpy.duration import Duration
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
)
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile

from tiltrov_ros.core import jit, validation
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.names import (
    BACKEND_KEY,
    CLOCK,
    DIAGNOSTICS,
    FINAL_STATUS_KEY,
    KERNEL_WARMUP_KEY,
    RECORDER,
    join_namespace,
)
from tiltrov_ros.core.paramtable import Param, ParamTable
from tiltrov_ros.core.validation import InvalidInput

from .conversions import Values, message_is_finite, set_stamp, stamp_ns
from .guard import THROTTLE, InputGuard, guarded
from .handshake import RECORDED_KEY, Handshake
from .parameters import (
    Overrides,
    allowed_text,
    apply_command_line_order,
    as_parameters,
    declare,
    init_args,
    misdirected_sections,
    parameter_source,
)
from .qos import RELIABLE_QOS
from .responses import HeldResponses
from .serialized import SerializedTemplate
from .simclock import install as install_time_source

#: s (wall): period of the /diagnostics messages.
DIAGNOSTICS_PERIOD = 1.0
#: DiagnosticStatus levels as ints (the message field is a byte).
OK, WARN, ERROR = 0, 1, 2
#: s (wall): the longest a node started alone waits for its readers' acknowledgements as
#: it stops (a bound against a hang; a node of a run waits for the recorder instead).
DELIVERY_WAIT = 10.0

#: ``run_nodes``: the names of the run's nodes, given by the launchers (nodes/handshake.py).
RUN = ParamTable('run', [
    Param('run_nodes', 'strs', (), "names of the run's nodes (the launchers set them): the "
          'node joins the run\'s handshake and the plant starts once every one of them has '
          'matched the others, seen from both sides; empty: the node runs alone, on its own '
          'side of each match', read_only=True),
])


def steady_clock() -> Clock:
    """A monotonic wall clock for timeouts and diagnostics (independent of sim time)."""
    return Clock(clock_type=ClockType.STEADY_TIME)


class SafePublisher:
    """A publisher that never sends NaN or infinity (docs/reliability.md).

    A message with a non-finite float is not published: the node counts it
    (``unsafe_outputs`` on /diagnostics, ERROR level), logs it, and publishes
    what ``safe(msg)`` returns instead (the node's safe command), if anything.
    ``published`` counts the messages sent. ``topic`` is the name as given, or the
    resolved one when a remapping moved it (``/tf`` in a namespaced stack), so that
    ``published.<topic>`` on /diagnostics names the topic in the bag.
    """

    def __init__(self, node: TiltrovNode, msg_type: Any, topic: str, qos: QoSProfile,
                 safe: Callable[[Any], Any | None] | None = None) -> None:
        self.node = node
        self.publisher = node.create_publisher(msg_type, topic, qos)
        resolved = self.publisher.topic_name
        self.topic = (topic if join_namespace(node.get_namespace(), topic) == resolved
                      else resolved)
        self._safe = safe
        self.published = 0
        self._template: tuple[SerializedTemplate, Values] | None = None

    def serialize_as(self, template: SerializedTemplate, values: Values) -> None:
        """From now on publish a message whose numbers ``values(msg)`` reads (not None: the
        template holds that message) as ``template``'s bytes, without rclpy's conversion
        of its fields (nodes/serialized.py); any other message as before."""
        self._template = (template, values)

    def publish(self, msg: Any) -> bool:
        """Publish ``msg`` if it is finite, else its safe replacement; True if ``msg`` went."""
        if self._template is not None and not isinstance(msg, bytes):
            template, read = self._template
            values = read(msg)
            if values is not None and all(map(math.isfinite, values)):
                self.publisher.publish(template.serialize(stamp_ns(msg.header.stamp), values))
                self.published += 1
                return True
        if message_is_finite(msg):
            self.publisher.publish(msg)
            self.published += 1
            return True
        self.node.unsafe_output(self.topic)
        replacement = self._safe(msg) if self._safe is not None else None
        if replacement is not None and message_is_finite(replacement):
            self.publisher.publish(replacement)
            self.published += 1
        return False

    def publish_serialized(self, template: SerializedTemplate, ns: int,
                           values: Sequence[float] | np.ndarray) -> bool:
        """Publish the message of ``template`` holding ``values`` stamped ``ns`` as
        bytes rewritten in place (:class:`~tiltrov_ros.nodes.serialized.SerializedTemplate`:
        no message object, no conversion of its fields), as :meth:`publish` would
        publish it: a value not finite sends the message object through :meth:`publish`
        (withheld, counted, replaced by the safe answer)."""
        if isinstance(values, np.ndarray):
            values = values.tolist()
        if not all(map(math.isfinite, values)):
            return self.publish(template.message(values, ns))
        self.publisher.publish(template.serialize(ns, values))
        self.published += 1
        return True

    def get_subscription_count(self) -> int:
        return int(self.publisher.get_subscription_count())

    def wait_for_all_acked(self, timeout: Any) -> bool:
        return bool(self.publisher.wait_for_all_acked(timeout))


class TiltrovNode(InputGuard, Node):
    """Base of the stack nodes: construction options, diagnostics, error handling,
    input validation and guarded publishers.

    Parameters
    ----------
    node_name : str
        Default name of the node.
    namespace : str, optional
        Pushed on every relative topic name.
    context : rclpy Context, optional
        For in-process tests and the single-process launcher.
    cli_args : list of str, optional
        Node-local ROS arguments, e.g. ``['--ros-args', '--params-file', path]``.
    parameter_overrides : mapping or list of Parameter, optional
        Values that win over parameter files.
    """

    #: The stack's nodes run kernels, expect one /clock and report what they published
    #: (the recorder does none of that; every node publishes /diagnostics and joins the
    #: run's handshake).
    stack_node: ClassVar[bool] = True
    #: The node subscribes to /clock itself and rejects bad samples there (the time
    #: source then drops them without counting them a second time).
    reads_clock: ClassVar[bool] = False
    #: The compiled-kernel groups the node calls (core/jit.py): compiled or loaded in the
    #: constructor, blocking, before the node joins the graph, so that no tick waits for a
    #: compiler (and none runs the reference first and the kernels later).
    kernel_groups: ClassVar[tuple[str, ...]] = ()

    def __init__(self, node_name: str, *, namespace: str | None = None,
                 context: Context | None = None, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Overrides = None) -> None:
        overrides = as_parameters(parameter_overrides)
        #: s: this constructor's compiling or loading of its kernels (/diagnostics). Before
        #: the node exists: it appears in the graph once it can answer (a launch that saw
        #: it and was stopped at once found it busy loading, deaf to SIGINT for seconds).
        self.kernel_warmup = jit.warmup(self.kernel_groups) if self.stack_node else 0.0
        super().__init__(node_name, namespace=namespace, context=context,
                         cli_args=list(cli_args) if cli_args is not None else None,
                         parameter_overrides=overrides)
        #: The process-wide arguments, then the node's own: parameter files and -p
        #: values apply in this order (later ones win) and errors name the file.
        self._source_args = [*init_args(self.context), *(cli_args or ())]
        apply_command_line_order(self, self._source_args, keep=[p.name for p in overrides])
        for line in misdirected_sections(self._source_args, self.get_fully_qualified_name()):
            self.get_logger().warning(line)
        #: Its parameter services' responses reach a requester matched late (responses.py).
        self.responses = HeldResponses(self)
        self.callback_errors = 0
        self.final_sent = False
        self.steady = steady_clock()
        self._diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS,
                                                      RELIABLE_QOS)
        self._diagnostics_msg = DiagnosticArray()
        self.init_input_guard()
        #: topic -> outgoing messages withheld for a non-finite value.
        self.unsafe: Counter[str] = Counter()
        self._rejected_at_last_report = 0
        self._safe_publishers: list[SafePublisher] = []
        #: Topics that must have one source (the plant's); more are named on /diagnostics.
        self.single_source: list[str] = []
        self._sources_reported: dict[str, tuple[str, ...]] = {}
        #: rclpy's time source with each /clock sample checked (nodes/simclock.py).
        self.time_source = install_time_source(self)
        if self.stack_node and self.on_sim_time():
            self.expect_single_source(CLOCK)
        self.add_on_set_parameters_callback(self._refuse_fixed)
        #: The run's handshake (nodes/handshake.py); joined by :meth:`join_run`.
        self.handshake = Handshake(self, declare(self, RUN)['run_nodes'],
                                   on_change=self.on_handshake)

    def declare_parameter(self, name: str, value: Any = None,
                          descriptor: ParameterDescriptor | None = None,
                          ignore_override: bool = False) -> Parameter:
        """rclpy's, but a value of the wrong type or out of range (from a parameter
        file or an override) raises :class:`ParameterError` naming the parameter, the
        value, the allowed range and the file it came from."""
        try:
            return super().declare_parameter(name, value, descriptor, ignore_override)
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            given = getattr(self, '_parameter_overrides', {}).get(name)
            got = given.value if given is not None else value
            raise ParameterError(
                name, f'got {got!r}; allowed: {allowed_text(descriptor, value)}',
                source=parameter_source(name, self.get_fully_qualified_name(),
                                        self._source_args)) from exc

    # -- hooks for subclasses ---------------------------------------------------

    def diagnostic_status(self) -> tuple[int, str, dict[str, Any]]:
        """(level, message, key values) for /diagnostics; subclasses extend it."""
        return OK, 'ok', {}

    def on_callback_error(self, callback: str, exc: Exception) -> None:
        """Called when a callback raised; subclasses publish a safe command too."""
        self.get_logger().error(f'{callback} failed: {exc!r}', throttle_duration_sec=THROTTLE)

    def diagnostics_stamp_ns(self) -> int:
        """The stamp of this node's /diagnostics: the clock it runs on (sim time on
        /clock with ``use_sim_time``, else system time); the plant overrides it with
        its own sim time."""
        return int(self.get_clock().now().nanoseconds)

    def on_rejected(self, topic: str, bad: InvalidInput, stamp: int | None) -> None:
        """Called after a message of ``topic`` was rejected; ``stamp`` is its stamp (ns)
        when the stamp itself was valid, else None. Subclasses answer a rejected
        tick with their safe command here, stamped by :meth:`safe_stamp`, and change
        nothing else (no state, no cached answer)."""

    def safe_stamp(self, stamp: int, newest_valid: int | None, period: int) -> int:
        """The stamp of the safe answer to a rejected message stamped ``stamp``: never
        later than the node's own last good time, so that a rejected message cannot
        push a stamp ahead of the real ones (downstream nodes keep the latest command
        by stamp). That time is the node's clock (sim time); while it is unknown, the
        newest valid input's stamp ``newest_valid`` plus one control ``period``."""
        now = self.clock_ns()
        if now is None and newest_valid is not None:
            now = newest_valid + period
        return stamp if now is None else min(stamp, now)

    # -- output guard -----------------------------------------------------------

    def create_safe_publisher(self, msg_type: Any, topic: str, qos: QoSProfile,
                              safe: Callable[[Any], Any | None] | None = None
                              ) -> SafePublisher:
        """A :class:`SafePublisher`: never NaN or infinity on ``topic``."""
        pub = SafePublisher(self, msg_type, topic, qos, safe)
        self._safe_publishers.append(pub)
        return pub

    def unsafe_output(self, topic: str) -> None:
        """Count and log an outgoing message withheld for a non-finite value."""
        self.unsafe[topic] += 1
        self.get_logger().error(f'withheld a {topic} message with a non-finite value '
                                f'({self.unsafe[topic]} so far); publishing the safe command',
                                throttle_duration_sec=THROTTLE)

    def recorded_by_the_run(self) -> bool:
        """True once nothing this node published can still be lost for the run's bag: the
        run's recorder says it has written this node's final report and every message
        that report counts (its handshake state names this node's instance under
        ``recorded``), or it is gone, or the run has none (no run nodes: see
        :meth:`wait_for_delivery`)."""
        hs = self.handshake
        if not hs.active or RECORDER not in hs.run_nodes or self.get_name() == RECORDER:
            return True
        state = hs.state_of(RECORDER)
        if state is not None and f'{self.get_name()}={hs.instance}' in state.extra.get(
                RECORDED_KEY, '').split():
            return True
        return (RECORDER, self.get_namespace()) not in self.get_node_names_and_namespaces()

    def wait_for_delivery(self, timeout: float = DELIVERY_WAIT) -> bool:
        """A node without run nodes: wait (at most ``timeout`` wall seconds in all, against
        a hang) until every reliable reader has acknowledged every message this node
        published, so that a lagging reader (a recorder started by hand) loses none of
        the last ones when the writers go."""
        deadline = time.monotonic() + timeout
        acked = True
        publishers = [p.publisher for p in self._safe_publishers]
        publishers.append(self._diagnostics_pub)
        for pub in publishers:
            left = max(deadline - time.monotonic(), 0.0)
            acked = bool(pub.wait_for_all_acked(Duration(seconds=left))) and acked
        return acked

    def published_counts(self) -> dict[str, int]:
        """Messages published per topic by the guarded publishers."""
        return {pub.topic: pub.published for pub in self._safe_publishers}

    # -- helpers ----------------------------------------------------------------

    def join_run(self) -> None:
        """Publish /diagnostics every DIAGNOSTICS_PERIOD wall seconds and join the run's
        handshake (call last in ``__init__``: every endpoint of the node exists)."""
        self._diagnostics_timer = self.create_timer(DIAGNOSTICS_PERIOD, self.publish_diagnostics,
                                                    clock=self.steady)
        self.handshake.start()
        if self.handshake.active:
            self.get_logger().info(f'run of {", ".join(self.handshake.run_nodes)}: waiting '
                                   'until each of them has matched the others')
        else:
            self.get_logger().info('started alone (no run_nodes): waiting on its own side '
                                   'of each match only')

    def on_handshake(self) -> None:
        """Called when what this node knows of the run's handshake changed."""

    def steady_ns(self) -> int:
        return int(self.steady.now().nanoseconds)

    def expect_single_source(self, *topics: str) -> None:
        """``topics`` must have one publisher (the plant's odom, joint_states, /clock):
        a second one (another simulator, a replay) is named on /diagnostics (WARN)
        and logged once when it appears."""
        self.single_source.extend(self.resolve_topic_name(t) for t in topics)

    def extra_sources(self) -> dict[str, tuple[str, ...]]:
        """Topic -> its publishers (node names), for the single-source topics with more
        than one."""
        found: dict[str, tuple[str, ...]] = {}
        for topic in self.single_source:
            names = tuple(sorted({f'{i.node_namespace.rstrip("/")}/{i.node_name}'
                                  for i in self.get_publishers_info_by_topic(topic)}))
            if len(names) > 1:
                found[topic] = names
            if names != self._sources_reported.get(topic, names[:1]) and len(names) > 1:
                self.get_logger().warning(f'{len(names)} publishers of {topic}: '
                                          f'{", ".join(names)}; one is expected')
            self._sources_reported[topic] = names
        return found

    @guarded
    def publish_diagnostics(self, final: bool = False) -> None:
        """Publish this node's status; ``final``: the last one, sent as the node stops
        (``final: true``): a recording of the whole run that lacks it may have lost the
        node's last messages (bag/losses.py). Nothing follows the final one."""
        if self.final_sent:
            return
        if final:
            self.final_sent = True
            if getattr(self, '_diagnostics_timer', None) is not None:
                self._diagnostics_timer.cancel()
        level, message, values = self.diagnostic_status()
        for topic, names in self.extra_sources().items():
            level = max(level, WARN)
            message = f'{message}; {len(names)} publishers of {topic}: {", ".join(names)}'
            values = {**values, f'publishers.{topic}': list(names)}
        rejected = self.rejected_messages
        if rejected > self._rejected_at_last_report:
            level = max(level, WARN)
            message = (f'{message}; {rejected - self._rejected_at_last_report} input '
                       'message(s) rejected')
        self._rejected_at_last_report = rejected
        unsafe = sum(self.unsafe.values())
        if self.callback_errors or unsafe:
            level = max(level, ERROR)
        if self.callback_errors:
            message = f'{message}; {self.callback_errors} callback error(s)'
        if unsafe:
            message = f'{message}; {unsafe} non-finite output(s) withheld'
        if not self.handshake.ready:
            level = max(level, WARN)
            message = f'{message}; waiting for {self.handshake.waiting_for}'
        values = {**values, 'instance': self.handshake.instance,
                  'handshake': self.handshake.ready,
                  'waiting_for': values.get('waiting_for') or self.handshake.waiting_for,
                  'callback_errors': self.callback_errors,
                  'rejected_messages': rejected, BACKEND_KEY: jit.backend(),
                  KERNEL_WARMUP_KEY: self.kernel_warmup}
        if self.on_sim_time():
            values['clock_jumps_back'] = self.time_source.jumps_back
        values.update({f'rejected.{topic}.{reason}': n
                       for (topic, reason), n in sorted(self.rejections.items())})
        values.update({f'unsafe_outputs.{topic}': n for topic, n in sorted(self.unsafe.items())})
        values.update({f'published.{topic}': n for topic, n in self.published_counts().items()})
        if final:
            values[FINAL_STATUS_KEY] = 'true'
        status = DiagnosticStatus(
            level=bytes([level]), name=f'{self.get_fully_qualified_name()}',
            message=message, hardware_id='tiltrov',
            values=[KeyValue(key=str(k), value=_text(v)) for k, v in values.items()])
        msg = self._diagnostics_msg
        set_stamp(msg.header.stamp, self.diagnostics_stamp_ns())
        msg.status = [status]
        if self._diagnostics_pub is not None:
            self._diagnostics_pub.publish(msg)

    def check_overrides(self) -> None:
        """Warn about parameters given (file or -p) that this node does not have.

        rclpy ignores them silently; a typo in a YAML file would otherwise go
        unnoticed. Call after every parameter is declared.
        """
        given = getattr(self, '_parameter_overrides', {}) or {}
        unknown = sorted(name for name in given if not self.has_parameter(name))
        if unknown:
            self.get_logger().warning(f'ignoring unknown parameter(s): {", ".join(unknown)}')

    def _refuse_fixed(self, parameters: list[Parameter]) -> SetParametersResult:
        """A run-time change no node of the package applies, refused with the reason:
        ``use_sim_time`` (each node chose its time source, subscriptions and timers at
        start). Deleting a parameter (``ros2 param delete``) rclpy refuses itself:
        every parameter is declared with a value of a fixed type."""
        for p in parameters:
            if p.name == 'use_sim_time' and self.has_parameter('use_sim_time') and (
                    p.value != self.get_parameter('use_sim_time').value):
                return self.reject('use_sim_time is fixed at start (restart the node to '
                                   'change it)')
        return SetParametersResult(successful=True)

    def reject(self, reason: str) -> SetParametersResult:
        self.get_logger().warning(f'parameter change rejected: {reason}')
        return SetParametersResult(successful=False, reason=reason)

    def check_failed_thrusters(self, parameters: list[Parameter]) -> SetParametersResult:
        """The verdict on a change that may set ``failed_thrusters`` (plant, allocator)."""
        for p in parameters:
            if p.name == 'failed_thrusters':
                try:
                    validation.failed_thruster_indices(p.value)
                except ParameterError as exc:
                    return self.reject(str(exc))
        return SetParametersResult(successful=True)


def _text(value: Any) -> str:
    if isinstance(value, float):
        return f'{value:.6g}'
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_text(v) for v in value) + ']'
    return str(value)
