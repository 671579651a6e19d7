"""Input freshness: the watchdog of one input topic against a timeout."""

from __future__ import annotations

from typing import TYPE_CHECKING

from tiltrov_ros.core.timebase import format_ns, seconds, to_ns

if TYPE_CHECKING:
    from .base import TiltrovNode


class InputWatchdog:
    """One input's freshness against a timeout (docs/reliability.md): the newest
    message's stamp and arrival, whether it is stale, how often it went stale; each
    transition logged once. The controller watches ``odom`` with it, the allocator
    ``wrench_cmd``.
    """

    def __init__(self, node: TiltrovNode, topic: str, timeout_name: str, safe_action: str,
                 resumes: str) -> None:
        self.node = node
        self.topic = topic
        self.timeout_name = timeout_name
        self.safe_action = safe_action      # what the node does while stale (for the log)
        self.resumes = resumes              # what resumes with fresh input (for the log)
        self.seen: tuple[int, int] | None = None     # (stamp, steady ns) of the newest
        self.stale = False
        self.events = 0

    def fresh(self, stamp: int, received: int | None = None) -> None:
        """A valid input stamped ``stamp`` arrived (at steady time ``received``, now if None)."""
        self.seen = (stamp, self.node.steady_ns() if received is None else received)
        if self.stale:
            self.stale = False
            self.node.get_logger().info(f'{self.topic} fresh again (stamped '
                                        f'{format_ns(stamp)}): {self.resumes}')

    def expired(self, timeout: float) -> tuple[int, int] | None:
        """(stamp, arrival) of the newest input when it is older than ``timeout`` s
        (0: off), else None; the first expiry of a stale spell is counted and logged."""
        seen = self.seen
        if seen is None or timeout <= 0:
            return None
        age = self.node.input_age_ns(*seen)
        if age <= to_ns(timeout):
            return None
        if not self.stale:
            self.stale = True
            self.events += 1
            self.node.get_logger().warning(
                f'{self.topic} is stale: the newest (stamped {format_ns(seen[0])}) is '
                f'{seconds(age):.3f} s old ({self.timeout_name} {timeout:g} s); '
                f'{self.safe_action}')
        return seen
