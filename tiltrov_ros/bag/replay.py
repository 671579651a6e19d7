"""``tiltrov replay BAG``: publish a recorded bag into a live graph.

Each message is published as the recorded CDR bytes (raw publishers, nothing
deserialized), at its log time relative to the first message divided by
``--rate``, on a fixed wall-clock schedule (no drift). ``--by-stamp`` uses the
header stamps instead (the stamp is read from the CDR bytes): a lockstep run
outpaces the recorder, whose log times then bunch up, and replayed by log time
such a bag would arrive in bursts a subscriber's queue cannot hold. ``/clock`` is only
published with ``--clock``: the bag's own ``/clock`` messages, or, for a bag
recorded without one, a clock generated from the log times at ``--clock-hz``,
so nodes with ``use_sim_time`` follow the bag. Publishers offer the recorded
reliability and durability (see :mod:`.qos`).

    tiltrov replay runs/demo/bag --rate 2 --topics odom wrench_cmd \\
        --remap odom:=/replayed/odom --clock --loop

``--through allocator`` replays offline instead, without ROS: the recorded
``wrench_cmd`` through the allocator in both modes, compared with the recorded
answers (:mod:`tiltrov_ros.analysis.reallocate`); bad input ends with one line on
stderr and exit code 2, as ``tiltrov analyze``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
import time
from typing import Any

from tiltrov_ros.core.errors import BagError
from tiltrov_ros.core.names import CLOCK, join_namespace
from tiltrov_ros.core.timebase import ns_to_stamp, seconds, to_ns

from .bagfile import BagInfo, RawMessage, bag_info, iter_raw

#: ``--through``: the parts of the stack a bag can be replayed through offline.
THROUGH = ('allocator',)
THROUGH_OUT = 'runs/replay'
_MAX_SLEEP = 0.05  # s: sleep in slices this long so a shutdown is noticed quickly
# s: after every publisher sees its subscribers, let the subscribers' side finish
# matching too (DDS matches the two ends separately; a volatile reader drops what
# a writer sends before the reader has matched it).
SETTLE = 0.25


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
        publishers = [*self.publishers.values(),
                      *([self._clock_pub] if self._clock_pub is not None else [])]
        if self.options.wait_for_subscribers <= 0:
            return
        deadline = time.monotonic() + self.options.wait_for_subscribers
        while (time.monotonic() < deadline and self._ok(should_stop)
               and not all(p.get_subscription_count() > 0 for p in publishers)):
            time.sleep(0.01)
        self._sleep_until(time.monotonic() + SETTLE, should_stop)

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


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='bag directory (or its .mcap file)')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='playback speed: 2 plays twice as fast (default 1)')
    parser.add_argument('--topics', nargs='+', default=[], metavar='TOPIC',
                        help='replay only these topics (default: all but /clock)')
    parser.add_argument('--remap', action='append', default=[], metavar='OLD:=NEW',
                        help='publish topic OLD under the name NEW (repeatable)')
    parser.add_argument('--clock', action='store_true',
                        help="publish /clock: the bag's, or generated from the log times")
    parser.add_argument('--clock-hz', type=float, default=100.0,
                        help='rate of the generated /clock when the bag has none (default 100)')
    parser.add_argument('--loop', action='store_true', help='start again at the end')
    parser.add_argument('--by-stamp', action='store_true',
                        help='publish on the schedule of the header stamps (sim time) instead '
                             'of the log times: a lockstep bag, whose log times bunch up where '
                             'the recorder lagged, replays at its simulated pace (holds the '
                             'replayed messages in memory)')
    parser.add_argument('--wait-for-subscribers', type=float, default=1.0, metavar='SEC',
                        help='wait up to SEC for every topic to have a subscriber, then '
                             f'{SETTLE} s for the matching to settle (default 1; 0: no wait)')
    offline = parser.add_argument_group(
        'offline (no ROS)', 'replay through a part of the stack in this process instead')
    offline.add_argument('--through', choices=THROUGH, default=None,
                         help='allocator: re-run the recorded wrench_cmd through the allocator '
                              '(paper and robust modes) and compare with the recorded '
                              'thrust_cmd/tilt_cmd')
    offline.add_argument('--out', type=Path, default=None, metavar='DIR',
                         help=f'--through: output directory (default: {THROUGH_OUT})')
    offline.add_argument('--namespace', default=None, metavar='NS',
                         help="--through: the stack's namespace in the bag (default: the "
                              "namespace of the bag's one wrench_cmd topic)")
    offline.add_argument('--no-figures', action='store_true',
                         help='--through: skip allocation.png')
    offline.add_argument('--dpi', type=int, default=None,
                         help='--through: figure resolution (default 100)')


def _through(args: argparse.Namespace) -> int:
    """``--through allocator``: offline, no rclpy."""
    from tiltrov_ros.analysis.reallocate import check_options, reallocate, summary_lines
    from tiltrov_ros.analysis.runs import print_written, report_errors

    live = {'--rate': args.rate != 1.0, '--topics': bool(args.topics),
            '--remap': bool(args.remap), '--clock': args.clock,
            '--clock-hz': args.clock_hz != 100.0, '--loop': args.loop,
            '--by-stamp': args.by_stamp,
            '--wait-for-subscribers': args.wait_for_subscribers != 1.0}
    out = args.out if args.out is not None else Path(THROUGH_OUT)

    def task() -> int:
        check_options(args.through, [name for name, given in live.items() if given])
        namespace = None if args.namespace is None else (
            '/' + args.namespace.strip('/') if args.namespace.strip('/') else '')
        comparison, written = reallocate(args.bag, out, namespace=namespace,
                                         figure=not args.no_figures,
                                         dpi=100 if args.dpi is None else args.dpi)
        print(f"{comparison.summary['ticks']} wrench_cmd ticks of {args.bag} through the "
              'allocator:')
        for line in summary_lines(comparison):
            print(f'  {line}')
        print_written(written, out)
        return 0

    return report_errors('tiltrov replay', task)


def run(args: argparse.Namespace) -> int:
    if args.through is not None:
        return _through(args)
    for name in ('out', 'namespace', 'dpi'):
        if getattr(args, name) is not None:
            print(f'tiltrov replay: --{name} needs --through')
            return 1
    if args.no_figures:
        print('tiltrov replay: --no-figures needs --through')
        return 1
    import rclpy
    from rclpy.executors import ExternalShutdownException

    try:
        options = ReplayOptions(rate=args.rate, topics=args.topics,
                                remap=parse_remaps(args.remap), clock=args.clock,
                                clock_hz=args.clock_hz, loop=args.loop,
                                by_stamp=args.by_stamp,
                                wait_for_subscribers=args.wait_for_subscribers)
        bag_info(args.bag)  # fail early, before starting ROS, on a bad bag
    except BagError as exc:
        print(f'tiltrov replay: {exc}')
        return 1
    rclpy.init()
    node = rclpy.create_node('tiltrov_replay')
    player: Player | None = None
    try:
        player = Player(args.bag, node, options)
        player.run()
    except BagError as exc:
        print(f'tiltrov replay: {exc}')
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    counts = player.counts if player is not None else {}
    total = sum(counts.values())
    print(f'published {total} messages: ' + ', '.join(
        f'{name} {count}' for name, count in sorted(counts.items())))
    return 0
