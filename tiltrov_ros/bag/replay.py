"""Publishing a recorded bag into a live graph: :class:`Player` (``tiltrov replay``).

Each message is published as the recorded CDR bytes (raw publishers, nothing
deserialized), at its log time relative to the first message divided by
``rate``, on a fixed wall-clock schedule (no drift). ``by_stamp`` uses the
header stamps instead (the stamp is read from the CDR bytes): a lockstep run
outpaces the recorder, whose log times then bunch up, and replayed by log time
such a bag would arrive in bursts a subscriber's queue cannot hold. ``/clock``
is only published with ``clock``: the bag's own ``/clock`` messages, or, for a
bag recorded without one, a clock generated from the log times at
``clock_hz``, so nodes with ``use_sim_time`` follow the bag. Publishers offer
the recorded reliability and durability (see :mod:`.qos`).
"""
from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
import time
from typing import Any

from tiltrov_ros.core.errors import BagError
from tiltrov_ros.core.names import CLOCK, join_namespace
from tiltrov_ros.core.timebase import ns_to_stamp, seconds, to_ns

from .bagfile import BagInfo, RawMessage, bag_info, iter_raw

_MAX_SLEEP = 0.05  # s: sleep in slices this long so a shutdown is noticed quickly


def parse_remaps(items: Sequence[str]) -> dict[str, str]:
    """``['odom:=/replayed/odom']`` -> ``{'/odom': '/replayed/odom'}``."""
    remaps = {}
    for item in items:
        old, sep, new = item.partition(':=')
        if not sep or not old or not new:
            raise BagError(f'remap {item!r} is not OLD:=NEW')
        remaps[join_namespace('', old)] = join_namespace('', new)
    return remaps


@dataclass
class ReplayOptions:
    """What to replay and how (the command line's options)."""

    rate: float = 1.0
    topics: Sequence[str] = ()            # empty: every recorded topic but /clock
    remap: Mapping[str, str] = field(default_factory=dict)
    clock: bool = False
    clock_hz: float = 100.0
    loop: bool = False
    by_stamp: bool = False                # schedule by header stamps, not log times
    wait_for_subscribers: float = 1.0     # s, at most, before the first message
    queue_depth: int = 1000

    def __post_init__(self) -> None:
        if not self.rate > 0:
            raise BagError(f'rate must be positive, not {self.rate}')
        if not self.clock_hz > 0:
            raise BagError(f'clock rate must be positive, not {self.clock_hz}')


class Player:
    """Publishes one bag through ``node`` (see the module docstring).

    ``run()`` blocks until the bag has been played (or forever with ``loop``)
    or ``should_stop()`` returns True; it returns the messages published per
    topic (published names, after remapping).
    """

    def __init__(self, bag: str, node: Any, options: ReplayOptions | None = None) -> None:
        from .msgdefs import message_class
        from .qos import replay_qos

        self.options = options or ReplayOptions()
        self.bag = bag
        self.node = node
        self.info: BagInfo = bag_info(bag)
        wanted = {join_namespace('', t) for t in self.options.topics}
        unknown = wanted - set(self.info.topics)
        if unknown:
            raise BagError(f'not in {bag}: {", ".join(sorted(unknown))}')
        self.topics = [name for name in self.info.topics
                       if (name in wanted if wanted else name != CLOCK)]
        self.generate_clock = self.options.clock and CLOCK not in self.info.topics
        if self.options.clock and not self.generate_clock and CLOCK not in self.topics:
            self.topics.append(CLOCK)
        self.publishers: dict[str, Any] = {}
        for name in self.topics:
            topic = self.info.topics[name]
            self.publishers[name] = node.create_publisher(
                message_class(topic.msgtype), self.options.remap.get(name, name),
                replay_qos(topic.qos, self.options.queue_depth))
        self._clock_pub = None
        if self.generate_clock:
            from rosgraph_msgs.msg import Clock

            self._clock_pub = node.create_publisher(
                Clock, CLOCK, replay_qos((), self.options.queue_depth))
        self.counts: dict[str, int] = {}

    def _ok(self, should_stop: Callable[[], bool]) -> bool:
        return self.node.context.ok() and not should_stop()

    def _sleep_until(self, due: float, should_stop: Callable[[], bool]) -> bool:
        while True:
            left = due - time.monotonic()
            if not self._ok(should_stop):
                return False
            if left <= 0:
                return True
            time.sleep(min(left, _MAX_SLEEP))

    def _wait_for_subscribers(self, should_stop: Callable[[], bool]) -> None:
        """Wait (at most ``wait_for_subscribers`` s) until every topic has a reader and
        every reader the player sees has matched it, on the player's side: a reader whose
        own side lags behind may still miss the first messages (only it can see that)."""
        from .qos import unmatched

        publishers = [*self.publishers.values(),
                      *([self._clock_pub] if self._clock_pub is not None else [])]
        if self.options.wait_for_subscribers <= 0:
            return
        deadline = time.monotonic() + self.options.wait_for_subscribers
        while (time.monotonic() < deadline and self._ok(should_stop)
               and not all(p.get_subscription_count() > 0
                           and not unmatched(self.node, p, publisher=True)[1]
                           for p in publishers)):
            time.sleep(0.01)

    def _timed(self) -> Iterator[tuple[int, str, bytes]]:
        """(time, topic, payload) of the recorded messages, in the order to publish them.

        Log times, or with ``by_stamp`` the header stamps (``/clock``: its value;
        a message without a leading stamp keeps its log time), sorted stably:
        this holds the replayed messages in memory.
        """
        messages: Iterator[RawMessage] = iter_raw(self.bag, set(self.topics))
        if not self.options.by_stamp:
            for m in messages:
                yield m.log_time, m.topic, m.data
            return
        from .cdr import leading_stamp_ns

        timed = []
        for m in messages:
            stamp = leading_stamp_ns(m.data, m.msgtype)
            timed.append((m.log_time if stamp is None else stamp, m.topic, m.data))
        timed.sort(key=lambda item: item[0])
        yield from timed

    def _schedule(self) -> Iterator[tuple[int, str, bytes | int]]:
        """(time, topic, payload) in order; generated clock ticks carry their time."""
        if not self.generate_clock:
            yield from self._timed()
            return
        period = to_ns(1.0 / self.options.clock_hz)
        tick: int | None = None if self.options.by_stamp else self.info.start_ns
        for time_ns, topic, data in self._timed():
            if tick is None:
                tick = time_ns
            while tick <= time_ns:
                yield tick, CLOCK, tick
                tick += period
            yield time_ns, topic, data

    def run(self, should_stop: Callable[[], bool] = lambda: False) -> dict[str, int]:
        self._wait_for_subscribers(should_stop)
        try:
            self._play(should_stop)
        finally:
            self.wait_for_delivery()
        return self.counts

    def _play(self, should_stop: Callable[[], bool]) -> None:
        rate = self.options.rate
        while self._ok(should_stop):
            start_wall = time.monotonic()
            first: int | None = None
            for log_time, topic, payload in self._schedule():
                if first is None:
                    first = log_time
                if not self._sleep_until(start_wall + seconds(log_time - first) / rate,
                                         should_stop):
                    return
                self._publish(topic, payload)
            if not self.options.loop or first is None:
                return

    def wait_for_delivery(self, timeout: float = 5.0) -> bool:
        """Wait until reliable subscribers acknowledged everything published (the
        last messages would be lost if the process exited right away)."""
        from rclpy.duration import Duration

        if not self.node.context.ok():
            return False
        deadline = time.monotonic() + timeout
        publishers = [*self.publishers.values(),
                      *([self._clock_pub] if self._clock_pub is not None else [])]
        return all(p.wait_for_all_acked(Duration(seconds=max(0.0, deadline - time.monotonic())))
                   for p in publishers)

    def _publish(self, topic: str, payload: bytes | int) -> None:
        if isinstance(payload, int):  # generated clock tick
            from rosgraph_msgs.msg import Clock

            msg = Clock()
            msg.clock.sec, msg.clock.nanosec = ns_to_stamp(payload)
            assert self._clock_pub is not None
            self._clock_pub.publish(msg)
        else:
            self.publishers[topic].publish(payload)
        name = self.options.remap.get(topic, topic)
        self.counts[name] = self.counts.get(name, 0) + 1
