"""Executors and ``main``: how every node executable spins and ends."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
import os
import signal
import sys

import rclpy
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import (
    Executor,
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.task import Future

from tiltrov_ros.core.errors import ParameterError, TiltrovError

from .base import TiltrovNode
from .parameters import parameter_source, remember_init_args

#: Errors that stop a node at start-up with a message and exit code 1.
STARTUP_ERRORS = (TiltrovError, ParameterException, ValueError, FileNotFoundError)


#: Executors the nodes can spin on (environment variable TILTROV_EXECUTOR).
EXECUTORS = ('events', 'single', 'multi')
DEFAULT_EXECUTOR = 'events'


def make_executor(context: Context | None = None, kind: str | None = None) -> Executor:
    """The executor the stack spins on.

    ``events`` (default): rclpy's EventsExecutor (C++, shipped with Jazzy's rclpy
    as ``rclpy.experimental``), several times faster per callback than the
    Python executors, which rebuild a wait set over every entity of every node
    (parameter services included) for each callback taken. ``single`` and
    ``multi`` are rclpy's SingleThreadedExecutor and MultiThreadedExecutor.
    ``kind`` None reads ``TILTROV_EXECUTOR``.
    """
    kind = kind or os.environ.get('TILTROV_EXECUTOR', DEFAULT_EXECUTOR)
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    if kind == 'multi':
        return MultiThreadedExecutor(context=context)
    raise ValueError(f'TILTROV_EXECUTOR={kind!r}; allowed: {", ".join(EXECUTORS)}')


def spin_until(executor: Executor, context: Context, future: Future | None = None,
               step: float = 0.5) -> None:
    """Spin until ``future`` is done (None: for ever) or the context shuts down (Ctrl-C).

    The wait is handed to the executor in slices of ``step`` seconds
    (``spin_until_future_complete``), never event by event from Python: the
    EventsExecutor then runs its loop in C++ (a ``None`` timeout does not
    return there when the future completes, hence the slices).
    """
    while context.ok() and (future is None or not future.done()):
        if future is None:
            executor.spin_once(timeout_sec=step)
        else:
            executor.spin_until_future_complete(future, timeout_sec=step)


def main_loop(factory: Callable[[], TiltrovNode], args: list[str] | None, name: str, *,
              until: Callable[[TiltrovNode], Future | None] | None = None,
              before_exit: Callable[[TiltrovNode], None] | None = None) -> int:
    """The Jazzy ``main``: init, spin, and always destroy the node and shut down.

    ``until`` returns a future that ends the spin when done (the plant's end of
    run); ``before_exit`` runs after a normal end (flush deliveries). A start-up
    error (an invalid parameter, a wrong-type YAML value) is printed as one line
    naming the node and gives exit code 1; Ctrl-C (the context shut down by
    rclpy's signal handler) gives 0, also when a second SIGINT comes during the
    clean-up.
    """
    rclpy.init(args=args)
    context = rclpy.get_default_context()
    remember_init_args(context, args)
    node: TiltrovNode | None = None
    executor: Executor | None = None
    code = 0
    try:
        node = factory()
        executor = make_executor(context)
        executor.add_node(node)
        future = until(node) if until is not None else None
        # Not executor.spin(): the EventsExecutor's does not return when Ctrl-C shuts
        # the context down; spin_until checks the context between slices.
        spin_until(executor, context, future if future is not None else Future())
        if future is not None and future.done() and before_exit is not None:
            before_exit(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except STARTUP_ERRORS as exc:
        text = str(exc)
        if isinstance(exc, ParameterError) and exc.source is None:
            source = parameter_source(exc.name, name, list(args or sys.argv))
            prefix = f'parameter {exc.name!r}'
            if source and text.startswith(prefix):
                text = f'{prefix} (in {source}){text[len(prefix):]}'
        print(f'{name}: {text}', file=sys.stderr, flush=True)
        code = 1
    finally:
        # As a program (args None) the process ends next: SIGINT stays ignored.
        with _sigint_ignored(restore=args is not None):
            if executor is not None:
                executor.shutdown()
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
    return code


@contextmanager
def _sigint_ignored(*, restore: bool) -> Iterator[None]:
    """SIGINT ignored while the node is taken down (and after, unless ``restore``):
    Ctrl-C in a terminal reaches every process of ``ros2 launch`` and launch sends
    its own SIGINT too, and the second one must not break the clean-up the first
    one started (a KeyboardInterrupt traceback, a death by signal: exit code -2)."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:          # not the main thread: signals are not ours to set
        yield
        return
    try:
        yield
    finally:
        if restore:
            signal.signal(signal.SIGINT, previous)
