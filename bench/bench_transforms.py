"""Benchmark (not a test): what the plant's transform tree costs per step.

Measured in one run, so the ratios hold on any machine (best of ``--repeats``
rounds, the measures interleaved in each):

* the plant's state publication per step (``/clock``, ``joint_states``, ``odom``
  and, with ``tf``, ``/tf``; no markers), with the tree and without: their
  difference is what the tree adds to each plant step;
* ``/tf`` alone with the tilts moving at every step (the thruster links
  recomputed): the serialized template rewritten in place, as the plant does,
  against the baseline of refilling the TFMessage's objects with the same
  numbers and publishing them.

Run ``python bench/bench_transforms.py`` (a few seconds); ``main()`` returns the
numbers as a dict and prints a table.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import time
from typing import Any

import rclpy
from rclpy.context import Context


def _best_us(runs: dict[str, Callable[[int], None]], steps: int, repeats: int
             ) -> dict[str, float]:
    """Microseconds per call of each ``fn(i)`` (``steps`` calls): the best of ``repeats``
    rounds, the functions interleaved within each round (a machine's load changes)."""
    best = dict.fromkeys(runs, float('inf'))
    for _ in range(repeats):
        for name, fn in runs.items():
            start = time.perf_counter()
            for i in range(steps):
                fn(i)
            best[name] = min(best[name], (time.perf_counter() - start) / steps * 1e6)
    return best


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--steps', type=int, default=5000)
    parser.add_argument('--repeats', type=int, default=5)
    args = parser.parse_args(argv)

    from tiltrov_ros.nodes.plant_simulator import PlantSimulator
    from tiltrov_ros.nodes.transforms import TFMessage

    if TFMessage is None:
        raise SystemExit('bench_transforms: tf2_msgs is not importable (make install)')
    context = Context()
    rclpy.init(context=context)
    plants: list[Any] = []
    try:
        for tf in (False, True):
            plants.append(PlantSimulator(
                node_name=f'bench_plant_{"tf" if tf else "no_tf"}', context=context,
                parameter_overrides={'mode': 'lockstep', 'startup_subscribers': 0,
                                     'scenario': 'pitch_hold', 'markers_period': 0.0,
                                     'tf': tf}))
        without, with_tf = plants
        transforms = with_tf.transforms
        first = with_tf.plant.sample()
        samples = [first._replace(tilts=(1e-4 * i, -2e-4 * i)) for i in range(args.steps)]
        msg = transforms._message(transforms.values(first), 0)
        raw = transforms.publisher.publisher

        def objects(i: int) -> None:
            """The baseline: the same numbers into the message objects, then publish."""
            values = transforms.values(samples[i])
            for k, t in enumerate(msg.transforms):
                t.header.stamp.sec, t.header.stamp.nanosec = 0, i
                r = t.transform.rotation
                if k == 0:
                    v = t.transform.translation
                    v.x, v.y, v.z = (float(x) for x in values[0:3])
                    r.w, r.x, r.y, r.z = (float(x) for x in values[3:7])
                else:
                    r.w, r.x, r.y, r.z = (float(x) for x in values[3 + 4 * k:7 + 4 * k])
            raw.publish(msg)

        results = _best_us({
            'state_us_without_tf': lambda i: without._publish_state(),
            'state_us_with_tf': lambda i: with_tf._publish_state(),
            'tf_us_template': lambda i: transforms.publish(samples[i]),
            'tf_us_objects': objects,
        }, args.steps, args.repeats)
    finally:
        for plant in plants:
            plant.destroy_node()
        rclpy.try_shutdown(context=context)
    results['state_with_tf_over_without'] = (results['state_us_with_tf']
                                             / results['state_us_without_tf'])
    results['tf_objects_over_template'] = (results['tf_us_objects']
                                           / results['tf_us_template'])
    print(f'{"measure":32s} {"value":>12s}')
    for key, value in results.items():
        print(f'{key:32s} {value:12.3f}')
    return results


if __name__ == '__main__':
    main()
