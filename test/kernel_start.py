"""Run in a fresh process by test_kernels_start.py: build what a run uses, then run it
and report, as one JSON line on stdout, what was compiled or loaded after construction.

``python test/kernel_start.py stack``: the four stack nodes in-process (a real rclpy
context, the launcher's specs, lockstep pitch_hold with pid), then the runner's
objects for every controller; then, with numba's compile listener installed
(``jit.compilations``), one second of the stack and one of each headless run.
``python test/kernel_start.py runner``: the runner's objects alone, then the runs.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

from tiltrov_ros.core import jit
from tiltrov_ros.core.controllers import CONTROLLER_KINDS
from tiltrov_ros.core.runner import run, stack_config

SCENARIO = 'pitch_hold'
DURATION = 1.0


def _runner_objects() -> list[tuple[Any, ...]]:
    out = []
    for kind in CONTROLLER_KINDS:
        config = stack_config(SCENARIO, kind)
        out.append((config, config.build_plant(), config.build_controller(),
                    config.build_allocator()))
    return out


def _headless(objects: list[tuple[Any, ...]]) -> None:
    for config, plant, controller, allocator in objects:
        run(plant, controller, allocator, config.scenario.reference.at, DURATION,
            control_period_ns=config.control_period_ns)


def _stack() -> tuple[dict[str, Any], Any]:
    """Build the nodes; returns the per-node facts and a function running one second."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from tiltrov_ros.core.names import PLANT
    from tiltrov_ros.stack.inprocess import build_nodes
    from tiltrov_ros.stack.specs import LaunchOptions, stack_specs

    context = Context()
    rclpy.init(context=context)
    specs, _, _ = stack_specs(LaunchOptions(scenario=SCENARIO, controller='pid',
                                            duration=DURATION))
    nodes = build_nodes(specs, context)
    facts = {spec.name: {'groups': list(node.kernel_groups),
                         'warmup': node.kernel_warmup,
                         'sealed': all(k.sealed for k in jit.registered(node.kernel_groups))}
             for spec, node in zip(specs, nodes)}

    def spin() -> bool:
        executor = SingleThreadedExecutor(context=context)
        for node in nodes:
            executor.add_node(node)
        plant = dict(zip((s.name for s in specs), nodes))[PLANT]
        deadline = time.monotonic() + 120.0        # only against a hang
        while not plant.finished.done() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        done = bool(plant.finished.done())
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
        return done

    return facts, spin


def main(which: str) -> int:
    report: dict[str, Any] = {'backend': jit.backend(), 'cache_dir': jit.describe()['cache_dir']}
    spin = None
    if which == 'stack':
        report['nodes'], spin = _stack()
    objects = _runner_objects()
    report['registered'] = {k.name: k.group for k in jit.registered()}
    report['sealed'] = all(k.sealed for k in jit.registered())
    before = jit.overloads()
    with jit.compilations() as compiled:
        if spin is not None:
            report['stack_finished'] = spin()
        _headless(objects)
    report['compiled_after_construction'] = compiled
    report['loaded_after_construction'] = sorted(
        name for name, n in jit.overloads().items() if n != before.get(name))
    print(json.dumps(report))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1]))
