"""``tiltrov demo``: the README's first command.

Runs whatever part of the stack exists and says plainly what does not yet.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import time


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--out', type=Path, default=Path('runs/demo'),
                        help='output directory (default: runs/demo)')


def _dds_round_trip() -> float:
    """Publish one message through DDS and receive it; return the seconds it took."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    context = Context()
    rclpy.init(context=context)
    node = rclpy.create_node('tiltrov_demo_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    received: list[str] = []
    try:
        node.create_subscription(String, 'tiltrov_demo_probe', lambda m: received.append(m.data),
                                 10)
        pub = node.create_publisher(String, 'tiltrov_demo_probe', 10)
        start = time.monotonic()
        while not received and time.monotonic() - start < 10.0:
            pub.publish(String(data='ping'))
            executor.spin_once(timeout_sec=0.05)
        if not received:
            raise RuntimeError('no message came back through DDS within 10 s')
        return time.monotonic() - start
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)


def run(args: argparse.Namespace) -> int:
    args.out.mkdir(parents=True, exist_ok=True)
    seconds = _dds_round_trip()
    print(f'rclpy and Fast DDS work: a message went round trip in {seconds * 1000:.1f} ms')
    print('Not built yet: the plant simulator, the controllers, the allocator, the launcher '
          'and the bag tools (see the open issues). Nothing else to run.')
    return 0
