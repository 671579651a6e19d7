"""What stands between a node and its inputs: callbacks that never raise, and input
validation with rejection counts and bounded logs.

:func:`guarded` and :func:`input_callback` wrap callbacks; :class:`InputGuard` (a base
of :class:`~tiltrov_ros.nodes.base.TiltrovNode`, which sets up its state) checks input
stamps against the node's clock (:data:`STAMP_BOUNDS`) and frames, decodes raw
subscriptions (bytes that do not decode are rejected as ``malformed``), counts and logs
every rejection (core/validation.py says why a message is rejected). Subscriptions
are raw and decoded by a :class:`~tiltrov_ros.nodes.serialized.MessageReader` per topic
and type: the message a callback gets is refilled in place for the next one.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
import functools
from typing import TYPE_CHECKING, Any, TypeVar

from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription

from tiltrov_ros.core import validation
from tiltrov_ros.core.paramtable import Param, ParamTable
from tiltrov_ros.core.timebase import NS_PER_S
from tiltrov_ros.core.validation import MALFORMED, InvalidInput, StampBounds

from .parameters import declare
from .serialized import MessageReader

if TYPE_CHECKING:
    from .base import TiltrovNode

#: s: repeated warnings from callbacks are throttled to one per this period.
THROTTLE = 5.0

#: Characters of a rejection's detail in a log line (the strings of a message inside it
#: are already cut by core/validation.shown): a log line stays bounded.
MAX_DETAIL = 300

#: ``stamp_max_future``, ``stamp_max_age``: input stamps against the node's clock.
STAMP_BOUNDS = ParamTable('input stamps', [
    Param('stamp_max_future', 'float', 0.5, "input stamps more than this ahead of the node's "
          'clock are rejected (sim time: /clock, the plant its own; not checked on system '
          'time); 0: not checked', 's', low=0.0, high=1e6),
    Param('stamp_max_age', 'float', 5.0, "input stamps more than this behind the node's clock "
          'are rejected; 0: not checked', 's', low=0.0, high=1e9),
])


F = TypeVar('F', bound=Callable[..., Any])


def _callback_failed(node: TiltrovNode, name: str, exc: Exception) -> None:
    node.callback_errors += 1
    try:
        node.on_callback_error(name, exc)
    except Exception as inner:  # even the error handler must not escape
        node.get_logger().error(f'error handler failed: {inner!r}',
                                throttle_duration_sec=THROTTLE)


def guarded(method: F) -> F:
    """Wrap a callback so an exception is logged and counted, never raised.

    An exception escaping a callback would stop the executor (and, in the
    single-process launcher, every node with it). The node's
    :meth:`TiltrovNode.on_callback_error` decides what safe thing to do.
    """

    @functools.wraps(method)
    def wrapper(self: TiltrovNode, *args: Any, **kwargs: Any) -> Any:
        try:
            return method(self, *args, **kwargs)
        except Exception as exc:  # the executor must survive anything a callback does
            _callback_failed(self, method.__name__, exc)
            return None

    return wrapper  # type: ignore[return-value]


def input_callback(topic: str) -> Callable[[F], F]:
    """Decorate the subscription callback of ``topic``: validation plus :func:`guarded`.

    An :class:`~tiltrov_ros.core.validation.InvalidInput` raised inside is a
    rejection of the message (:meth:`TiltrovNode.reject_input`: counted per
    topic and reason, logged, and :meth:`TiltrovNode.on_rejected` may publish a
    safe answer); any other exception is a callback error, as in :func:`guarded`.
    """

    def decorate(method: F) -> F:
        @functools.wraps(method)
        def wrapper(self: TiltrovNode, msg: Any) -> Any:
            self._input_stamp = None
            try:
                return method(self, msg)
            except InvalidInput as bad:
                try:
                    self.reject_input(topic, bad, self._input_stamp)
                except Exception as exc:
                    _callback_failed(self, method.__name__, exc)
            except Exception as exc:  # the executor must survive anything a callback does
                _callback_failed(self, method.__name__, exc)
            return None

        return wrapper  # type: ignore[return-value]

    return decorate


class InputGuard:
    """Input validation of a :class:`~tiltrov_ros.nodes.base.TiltrovNode` (its
    constructor calls :meth:`init_input_guard`; the node gives the clocks, the logger
    and the :meth:`on_rejected` hook)."""

    def init_input_guard(self) -> None:
        #: (topic, reason) -> messages rejected (see core/validation.py).
        self.rejections: Counter[tuple[str, str]] = Counter()
        self.stamp_bounds = StampBounds()
        self._input_stamp: int | None = None
        self._reject_log: dict[tuple[str, str], tuple[int, int]] = {}
        self._readers: dict[tuple[str, type], MessageReader] = {}

    # -- input validation -------------------------------------------------------

    def declare_stamp_bounds(self) -> None:
        """Declare :data:`STAMP_BOUNDS` (s, run-time changeable)."""
        bounds = declare(self, STAMP_BOUNDS)
        self.stamp_bounds = StampBounds.from_seconds(bounds['stamp_max_future'],
                                                     bounds['stamp_max_age'])
        self.add_post_set_parameters_callback(self._apply_stamp_bounds)

    def _apply_stamp_bounds(self, parameters: list[Parameter]) -> None:
        if any(p.name in ('stamp_max_future', 'stamp_max_age') for p in parameters):
            self.stamp_bounds = StampBounds.from_seconds(
                self.get_parameter('stamp_max_future').value,
                self.get_parameter('stamp_max_age').value)

    # -- watchdogs ---------------------------------------------------------------

    def input_age_ns(self, stamp: int, received: int) -> int:
        """How old an input stamped ``stamp`` that arrived at steady time ``received`` is:
        on sim time, by ``/clock`` (0 before the first one: sim time is not running);
        on system time, the wall time since it arrived."""
        if self.on_sim_time():
            now = self.clock_ns()
            return 0 if now is None else now - stamp
        return self.steady_ns() - received

    def on_sim_time(self) -> bool:
        return bool(getattr(self.get_clock(), 'ros_time_is_active', False))

    def estimated_now_ns(self, stamp: int, received: int, period: int) -> int:
        """The stamp for a watchdog's output: sim time now on /clock, else ``stamp``
        plus the wall time since it arrived; after ``stamp``, and never a multiple of
        ``period`` (a control tick), so that no answer to a real tick, which downstream
        nodes cache by stamp, is ever confused with it."""
        now = self.clock_ns()
        if now is None:
            now = stamp + self.steady_ns() - received
        now = max(now, stamp + 1)
        return now + 1 if now % period == 0 else now

    def clock_ns(self) -> int | None:
        """The clock input stamps are checked against, ns: sim time when the node
        runs on ``/clock`` (``use_sim_time``, as ``tiltrov launch`` starts it).

        None (stamps not checked against a clock) on system time, and on sim time
        before the first ``/clock`` message (ROS time 0 means "not initialised"):
        the stack stamps with sim time, which the wall clock says nothing about.
        """
        clock = self.get_clock()
        if not getattr(clock, 'ros_time_is_active', False):
            return None
        ns = int(clock.now().nanoseconds)
        return ns if ns > 0 else None

    def check_header(self, header: Any, frame: str | None) -> int:
        """The header's stamp (ns), checked against :meth:`clock_ns` and
        :attr:`stamp_bounds`, then its ``frame_id`` against ``frame`` (None: any).

        Raises InvalidInput. Once the stamp is known to be valid, a later
        rejection of the same message passes it to :meth:`on_rejected`.
        """
        ns = validation.check_stamp(header.stamp.sec, header.stamp.nanosec, self.clock_ns(),
                                    self.stamp_bounds)
        self._input_stamp = ns
        if frame is not None:
            validation.check_frame(header.frame_id, frame)
        return ns

    def create_input_subscription(self, msg_type: Any, topic: str,
                                  callback: Callable[[Any], Any], qos: QoSProfile
                                  ) -> Subscription:
        """A subscription of ``topic`` that decodes what it receives itself (a raw
        subscription and :meth:`decode`): bytes that do not decode as ``msg_type``
        are rejected as ``malformed`` (rclpy's typed subscriptions drop them without
        a trace); a message that decodes goes to ``callback``, an
        :func:`input_callback`."""

        def on_bytes(data: bytes) -> None:
            msg = self.decode(msg_type, topic, data)
            if msg is not None:
                callback(msg)

        return self.create_subscription(msg_type, topic, on_bytes, qos, raw=True)

    def decode(self, msg_type: Any, topic: str, data: bytes) -> Any | None:
        """``data`` (serialized CDR) as a ``msg_type`` message, or None when it does not
        decode (truncated, garbage): then rejected as ``malformed`` (counted, logged).
        The message is this topic's reader's object, refilled by the next message
        (:class:`~tiltrov_ros.nodes.serialized.MessageReader`): keep numbers, not it."""
        reader = self._readers.get((topic, msg_type))
        if reader is None:
            reader = self._readers[(topic, msg_type)] = MessageReader(msg_type)
        try:
            return reader.read(data)
        except Exception:   # rclpy raises RMWError (Fast CDR: not enough bytes, ...)
            self.reject_malformed(topic, msg_type, data)
            return None

    def reject_malformed(self, topic: str, msg_type: Any, data: bytes) -> None:
        """Reject ``data`` received on ``topic``: not a serialized ``msg_type``."""
        try:
            name = f'{msg_type.__module__.split(".")[0]}/msg/{msg_type.__name__}'
            self.reject_input(topic, InvalidInput(
                MALFORMED, f'{len(data)} bytes that do not decode as {name}'))
        except Exception as exc:  # the executor must survive anything a sample holds
            _callback_failed(self, 'reject_malformed', exc)

    def reject_input(self, topic: str, bad: InvalidInput, stamp: int | None = None) -> None:
        """Count a rejected message of ``topic``, log it (at most once per THROTTLE
        seconds per topic and reason, with the number left unlogged), and call
        :meth:`on_rejected`."""
        key = (topic, bad.reason)
        self.rejections[key] += 1
        now = self.steady_ns()
        last, quiet = self._reject_log.get(key, (None, 0))
        if last is None or now - last >= THROTTLE * NS_PER_S:
            more = f' ({quiet} more since the last report)' if quiet else ''
            detail = bad.detail if len(bad.detail) <= MAX_DETAIL else (
                f'{bad.detail[:MAX_DETAIL]}... (cut)')
            self.get_logger().warning(f'rejected a {topic} message ({bad.reason}): '
                                      f'{detail}{more}')
            self._reject_log[key] = (now, 0)
        else:
            self._reject_log[key] = (last, quiet + 1)
        self.on_rejected(topic, bad, stamp)

    @property
    def rejected_messages(self) -> int:
        """Messages rejected so far, every topic and reason."""
        return sum(self.rejections.values())
