"""The stack in one process (``tiltrov launch --single-process``, the in-process tests):
the nodes of :func:`~tiltrov_ros.stack.specs.stack_specs` built in this process,
with the same parameter files and overrides."""

from __future__ import annotations

from collections.abc import Sequence
import importlib
import os
from pathlib import Path
import signal
import threading
import time
from typing import Any

from tiltrov_ros.core.names import (
    PLANT,
    RECORDER,
)

from .specs import NodeSpec, remap_args
from .supervisor import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, Output, StatusFile


def build_node(spec: NodeSpec, context: Any, namespace: str = '') -> Any:
    """Construct ``spec``'s node class in this process, bound to ``context``."""
    cls = getattr(importlib.import_module(spec.module), spec.class_name)
    cli_args = ['--ros-args']
    for path in spec.params_files:
        cli_args += ['--params-file', str(path)]
    cli_args += remap_args(namespace)
    kwargs = {'context': context, 'cli_args': cli_args,
              'parameter_overrides': spec.all_overrides()}
    if namespace:
        kwargs['namespace'] = namespace
    return cls(**kwargs)


def build_nodes(specs: Sequence[NodeSpec], context: Any, namespace: str = '') -> list[Any]:
    """Every node of ``specs`` in this process; destroyed again if one fails."""
    nodes: list[Any] = []
    try:
        for spec in specs:
            nodes.append(build_node(spec, context, namespace))
    except BaseException:
        for node in reversed(nodes):
            node.destroy_node()
        raise
    return nodes


def run_single_process(specs: Sequence[NodeSpec], namespace: str, out: Output,
                       summary: str, executor_kind: str | None = None, *,
                       status_file: Path | None = None) -> int:
    """Every node in this process, bound to one context (``status_file``: see
    :class:`~tiltrov_ros.stack.supervisor.StatusFile`; every node has this pid).

    The stack nodes share one executor (``nodes.executors.make_executor``). The
    recorder, if any, spins on its own SingleThreadedExecutor in a second
    thread: it takes queued messages itself inside its callbacks, which the
    EventsExecutor (one take per event) does not allow, and it stays off the
    stack's critical path.

    SIGINT and SIGTERM set a flag the spin looks at between slices, as each
    node's own process does (``nodes.executors.main_loop``); the handlers are
    installed after the executor, whose constructor takes the signals for
    itself. Python's default KeyboardInterrupt was raised wherever the main
    thread happened to be, and a Ctrl-C was lost now and then (1 stop in 6 of
    a realtime run: the process ran on for a minute).
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future

    from tiltrov_ros.nodes.executors import (
        FINISH_POLL,
        STARTUP_ERRORS,
        STOP_POLL,
        make_executor,
        spin_until,
    )

    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[Any] = []
    executor = None
    side: Any = None
    side_thread: threading.Thread | None = None
    started = time.monotonic()
    status = StatusFile(status_file)
    code = EXIT_FAILED
    stop = threading.Event()
    hurry = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        (hurry if stop.is_set() else stop).set()

    # Signal handlers belong to the main thread (a caller in another thread stops the
    # run by its own means).
    main = threading.current_thread() is threading.main_thread()
    previous = ({sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
                if main else {})
    try:
        try:
            nodes = build_nodes(specs, context, namespace)
        except STARTUP_ERRORS as exc:
            out.line('launch', f'cannot start the stack: {exc}')
            return code
        by_name = {s.name: n for n, s in zip(nodes, specs)}
        plant = by_name[PLANT]
        executor = make_executor(context, executor_kind)
        for sig in previous:
            signal.signal(sig, on_signal)
        for name, node in by_name.items():
            if name != RECORDER:
                executor.add_node(node)
        if RECORDER in by_name:
            side = SingleThreadedExecutor(context=context)
            side.add_node(by_name[RECORDER])
            side_thread = threading.Thread(target=side.spin, name=RECORDER, daemon=True)
            side_thread.start()
        status.write('running', {s.name: {'pid': os.getpid(), 'starts': 1, 'running': True}
                                 for s in specs})
        spin_until(executor, context, plant.finished, step=STOP_POLL, stop=stop)
        if plant.finished.done():
            out.line('launch', f'{summary} done in {time.monotonic() - started:.2f} s wall')
            code = EXIT_OK
        else:
            out.line('launch', 'SIGINT: stopping every node')
            code = EXIT_INTERRUPTED
    finally:
        # Every node's final counts; then, while the recorder still spins, until it has
        # written them and every message they count (nodes/executors.finish).
        stack = [n for n in nodes if getattr(n, 'stack_node', False)]
        for node in stack:
            node.publish_diagnostics(final=True)
        if executor is not None:
            done = Future()
            while (context.ok() and not hurry.is_set()
                   and not all(n.recorded_by_the_run() for n in stack)):
                executor.spin_until_future_complete(done, timeout_sec=FINISH_POLL)
        if executor is not None:
            executor.shutdown()
        if side is not None:
            side.shutdown()
        if side_thread is not None:
            side_thread.join(timeout=10.0)
        # The recorder (first in start order) is destroyed last: it drains its queues.
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown(context=context)
        recorder = dict(zip((s.name for s in specs), nodes)).get(RECORDER)
        if recorder is not None and recorder.lost_data and code == EXIT_OK:
            out.line('launch', f'the recording lost data: {recorder.stats()}')
            code = EXIT_FAILED
        status.write('ended', {s.name: {'pid': os.getpid(), 'starts': 1, 'running': False}
                               for s in specs}, code)
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return code
