"""``tiltrov replay BAG``: publish a recorded bag into a live graph
(:class:`tiltrov_ros.bag.replay.Player`), or with ``--through allocator`` re-run it
offline (:mod:`tiltrov_ros.analysis.reallocate`).

    tiltrov replay runs/demo/bag --rate 2 --topics odom wrench_cmd \\
        --remap odom:=/replayed/odom --clock --loop
    tiltrov replay runs/pd/bag --through allocator --out runs/pd/allocation

``--through`` needs no ROS; bad input ends with one line on stderr and exit
code 2, as ``tiltrov analyze``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from tiltrov_ros.bag.bagfile import bag_info
from tiltrov_ros.bag.replay import Player, ReplayOptions, parse_remaps
from tiltrov_ros.core.errors import BagError
from tiltrov_ros.core.names import normalize_namespace

from .output import print_written, report_errors

#: ``--through``: the parts of the stack a bag can be replayed through offline.
THROUGH = ('allocator',)
THROUGH_OUT = 'runs/replay'
#: The player's node name (a run that it joins names it among its run_nodes).
REPLAY_NODE = 'tiltrov_replay'


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
                        help='wait up to SEC until every topic has a subscriber and every '
                             'subscriber seen has matched the player (default 1; 0: no wait)')
    parser.add_argument('--join', default='', metavar='NODE[,NODE...]',
                        help=f"take part in the handshake of a run of these nodes (their "
                             f"run_nodes name {REPLAY_NODE} too): publish the first message "
                             "once every node of the run has matched every other, seen from "
                             "both sides (docs/nodes.md), so that none is lost")
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

    live = {'--rate': args.rate != 1.0, '--topics': bool(args.topics),
            '--remap': bool(args.remap), '--clock': args.clock,
            '--clock-hz': args.clock_hz != 100.0, '--loop': args.loop,
            '--by-stamp': args.by_stamp,
            '--wait-for-subscribers': args.wait_for_subscribers != 1.0,
            '--join': bool(args.join)}
    out = args.out if args.out is not None else Path(THROUGH_OUT)

    def task() -> int:
        check_options(args.through, [name for name, given in live.items() if given])
        namespace = None if args.namespace is None else normalize_namespace(args.namespace)
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
    node = rclpy.create_node(REPLAY_NODE)
    player: Player | None = None
    try:
        player = Player(args.bag, node, options)
        others = [n for n in (part.strip() for part in args.join.split(',')) if n]
        if not others or join_run(node, others):
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


def join_run(node: Any, others: list[str]) -> bool:
    """Take part in the handshake of a run of ``others`` and ``node`` (nodes/handshake.py)
    until the run is ready: True; False when stopped first (Ctrl-C). Says what it waits for
    whenever that changes."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from tiltrov_ros.nodes.handshake import Handshake

    handshake = Handshake(node, [node.get_name(), *others])
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    handshake.start()
    said = None
    try:
        while rclpy.ok(context=node.context) and not handshake.run_ready():
            waiting = handshake.run_waiting_for()
            if waiting != said:
                print(f'tiltrov replay: waiting for the run: {waiting}', flush=True)
                said = waiting
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.remove_node(node)
        executor.shutdown()
    return handshake.run_ready()
