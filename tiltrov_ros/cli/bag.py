"""``tiltrov bag``: look into a bag and repair one whose recorder was killed.

    tiltrov bag info BAG      topics, types, counts, duration, run_info
    tiltrov bag repair BAG    recover a bag whose recorder died (see bag/repair.py)
"""

from __future__ import annotations

import argparse
import json

from tiltrov_ros.core.errors import BagError
from tiltrov_ros.core.timebase import seconds


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest='action', metavar='ACTION', required=True)
    info = sub.add_parser('info', help='topics, types, message counts, duration and run_info')
    info.add_argument('bag', help='bag directory (or its .mcap file)')
    fix = sub.add_parser(
        'repair', help='recover the messages of a bag whose recorder was killed',
        description='Rewrite BAG from every complete chunk of its MCAP file, with a full '
                    'summary and metadata.yaml; the originals are kept as *.bak.')
    fix.add_argument('bag', help='bag directory (or its .mcap file)')
    fix.add_argument('--force', action='store_true',
                     help='rewrite the bag even when it is intact')


def run(args: argparse.Namespace) -> int:
    try:
        if args.action == 'info':
            return _info(args.bag)
        return _repair(args.bag, force=args.force)
    except BagError as exc:
        print(f'tiltrov bag {args.action}: {exc}')
        return 1


def _info(path: str) -> int:
    from tiltrov_ros.bag.bagfile import bag_info

    info = bag_info(path)
    print(f'bag:       {info.path}')
    print(f'messages:  {info.message_count}')
    print(f'duration:  {seconds(info.duration_ns):.3f} s (log time)')
    width = max((len(name) for name in info.topics), default=0)
    for name, topic in sorted(info.topics.items()):
        print(f'  {name:<{width}}  {topic.count:>8}  {topic.msgtype}')
    if info.run_info:
        print(f'run_info:  {json.dumps(info.run_info, sort_keys=True)}')
    from tiltrov_ros.bag.losses import losses

    found = losses(path)
    nothing = ("nothing (the nodes' counts and the recorder agree)" if found.whole_run else
               'nothing the recorder knows of (the nodes\' counts are compared in recordings '
               'of a whole run, by tiltrov launch --record)')
    print('lost:      ' + (nothing if not found else f'{len(found.lines())} finding(s)'))
    for line in found.lines():
        print(f'  {line}')
    return 0


def _repair(path: str, *, force: bool) -> int:
    from tiltrov_ros.bag.repair import repair

    result = repair(path, force=force)
    if not result.backups:
        print(f'{result.path} is intact; nothing to repair (--force rewrites it anyway)')
        return 0
    print(f'{result.path}: {result.reason}')
    print(f'recovered {result.total} messages from the first {result.stopped_at} of '
          f'{result.file_size} bytes:')
    for name, count in sorted(result.counts.items()):
        print(f'  {name}: {count}')
    print('originals kept as ' + ', '.join(p.name for p in result.backups))
    return 0
