"""Service responses that wait for their requester's match.

rmw_fastrtps sends a service response only to a requester whose response reader the
server has matched, and waits at most 100 ms for that match; past it the response is
dropped (rclpy: a RuntimeWarning, "failed to send response (timeout)") and the
requester, ``ros2 param set`` or ``ros2 param get`` among them, waits for ever. The
requester sends as soon as it has matched the server from its own side; on a loaded
machine a node busy with a run takes longer than 100 ms to match the new reader from
its side.

:class:`HeldResponses` wraps every service of a stack node (its parameter services):
a response that did not go out is held and sent again every :data:`RETRY_PERIOD` s of
wall time until it goes out, i.e. until the match is made; :data:`GIVE_UP` only bounds
the effort for a requester that has gone meanwhile.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
import time
from typing import Any
import warnings

from rclpy.clock import Clock, ClockType
from rclpy.node import Node

#: rclpy's warning for a response rmw could not send (the requester not matched).
TIMEOUT_TEXT = 'failed to send response'
#: s (wall): how often held responses are sent again (each try waits up to 100 ms in rmw).
RETRY_PERIOD = 0.05
#: s (wall): a held response is dropped after this long (its requester is gone).
GIVE_UP = 60.0


@dataclass
class _Held:
    service: str
    send: Callable[[Any, Any], None]
    response: Any
    header: Any
    since: float


def _sent(send: Callable[[Any, Any], None], response: Any, header: Any) -> bool:
    """Send; False when rmw could not (rclpy's timeout warning, or its error)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        try:
            send(response, header)
        except RuntimeError as exc:          # rclpy's RCLError
            if TIMEOUT_TEXT not in str(exc):
                raise
            return False
    return not any(TIMEOUT_TEXT in str(w.message) for w in caught)


class HeldResponses:
    """Wraps the ``send_response`` of every service ``node`` has now (the executors call
    it by name, the EventsExecutor too) so that a response rmw could not send is held and
    sent again (see the module docstring)."""

    def __init__(self, node: Node) -> None:
        self.node = node
        self.held: list[_Held] = []
        self.resent = 0          # responses that went out on a later try
        self.dropped = 0         # responses given up (their requester gone)
        self._timer: Any = None
        for service in list(node.services):
            self._wrap(service)

    def _wrap(self, service: Any) -> None:
        send = service.send_response
        name = service.srv_name

        def send_response(response: Any, header: Any) -> None:
            if not _sent(send, response, header):
                self._hold(_Held(name, send, response, header, time.monotonic()))

        service.send_response = send_response

    def _hold(self, held: _Held) -> None:
        if not self.held:
            self.node.get_logger().info(
                f'{held.service}: the requester is not matched yet; its response is held '
                'until it is')
        self.held.append(held)
        if self._timer is None:
            self._timer = self.node.create_timer(
                RETRY_PERIOD, self.retry, clock=Clock(clock_type=ClockType.STEADY_TIME))
        elif self._timer.is_canceled():
            self._timer.reset()

    def retry(self) -> None:
        """Send the held responses again; keep those that still cannot go."""
        now, kept = time.monotonic(), []
        for held in self.held:
            if _sent(held.send, held.response, held.header):
                self.resent += 1
            elif now - held.since > GIVE_UP:
                self.dropped += 1
                self.node.get_logger().warning(
                    f'{held.service}: dropped a response held {GIVE_UP:g} s: its requester '
                    'never matched (gone?)')
            else:
                kept.append(held)
        self.held = kept
        if not kept and self._timer is not None:
            self._timer.cancel()
