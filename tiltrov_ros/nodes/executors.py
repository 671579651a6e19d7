"""Executors and ``main``: how every node executable spins and ends."""

from __future__ import annotations

from collections.abc import Callable
import ctypes
import faulthandler
import os
import re
import signal
import sys
import threading
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.exceptions import (
    InvalidNamespaceException,
    InvalidNodeNameException,
    ParameterException,
)
from rclpy.executors import (
    Executor,
    ExternalShutdownException,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
import rclpy.logging
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from tiltrov_ros.core.errors import ParameterError, TiltrovError
from tiltrov_ros.core.names import STANDBY_ENV

from .base import TiltrovNode
from .handoff import TOPICS, Standby
from .parameters import parameter_source, remember_init_args

#: Errors that stop a node at start-up with a message and exit code 1.
STARTUP_ERRORS = (TiltrovError, ParameterException, ValueError, OSError,
                  InvalidNodeNameException, InvalidNamespaceException)


#: Executors the nodes can spin on (environment variable TILTROV_EXECUTOR).
EXECUTORS = ('events', 'single', 'multi')
DEFAULT_EXECUTOR = 'events'


#: rcl's "Couldn't parse params file" error: the file and the parser's reason.
_PARAMS_FILE_ERROR = re.compile(r"params file: '--params-file (?P<path>.*?)'\. Error: (?P<why>.*)",
                                re.S)
#: rcl's source locations appended to its messages (``, at /path/file.c:123``).
_RCL_LOCATION = re.compile(r',? at \S+:\d+')


def rcl_error_line(exc: Exception) -> str:
    """One line for an error of ``rclpy.init`` (arguments rcl cannot use): the
    parameter file and why it cannot be read, or rcl's message without its source
    locations."""
    text = ' '.join(_RCL_LOCATION.sub('', str(exc)).split())
    text = text.removeprefix('failed to initialize rcl: ')
    match = _PARAMS_FILE_ERROR.search(text)
    if match is None:
        return text
    path, why = match['path'], match['why'].rstrip(' .,')
    if not os.path.exists(path):
        why = 'no such file'
    elif not os.access(path, os.R_OK) or os.path.isdir(path):
        why = 'not a readable file'
    return f'cannot read parameter file {path}: {why}'


def init(args: list[str] | None, name: str, *, signal_handlers: bool = True) -> bool:
    """``rclpy.init(args)``; on arguments rcl refuses (an unreadable parameter file,
    a malformed ``-p``) print one line naming the node and the file and return False.

    rcl's own log line about it ("Failed to parse global arguments") is silenced:
    the line printed here says more.
    """
    previous = rclpy.logging.get_logger_level('rcl')
    rclpy.logging.set_logger_level('rcl', rclpy.logging.LoggingSeverity.FATAL)
    try:
        rclpy.init(args=args, signal_handler_options=(
            SignalHandlerOptions.ALL if signal_handlers else SignalHandlerOptions.NO))
    except (RuntimeError, ValueError) as exc:   # rclpy's RCLError is a RuntimeError
        print(f'{name}: {rcl_error_line(exc)}', file=sys.stderr, flush=True)
        return False
    finally:
        if rclpy.logging.get_logger_level('rcl') == rclpy.logging.LoggingSeverity.FATAL:
            rclpy.logging.set_logger_level('rcl', previous)   # not set by --log-level
    return True


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
               step: float = 0.5, stop: threading.Event | None = None) -> None:
    """Spin until ``future`` is done (None: for ever), ``stop`` is set or the context
    shuts down (Ctrl-C).

    The wait is handed to the executor in slices of ``step`` seconds
    (``spin_until_future_complete``), never event by event from Python: the
    EventsExecutor then runs its loop in C++ (a ``None`` timeout does not
    return there when the future completes, hence the slices).
    """
    while (context.ok() and (future is None or not future.done())
           and (stop is None or not stop.is_set())):
        if future is None:
            executor.spin_once(timeout_sec=step)
        else:
            executor.spin_until_future_complete(future, timeout_sec=step)


#: s (wall): the longest a stop signal waits for the spin to notice it.
STOP_POLL = 0.2
#: s (wall): how often a stopping node looks whether the recorder is gone (its reports
#: wake it at once).
FINISH_POLL = 0.05
#: s (wall): the longest the teardown of a stopped node process may take (its executor,
#: node and DDS participant: milliseconds when well) before it prints every thread's
#: stack and exits with code 1. It only bounds a hang, below the launchers' 13 s to
#: SIGTERM, which a process stuck in C++ could not act on.
TEARDOWN_BOUND = 10.0


def main_loop(factory: Callable[[], TiltrovNode], args: list[str] | None, name: str, *,
              until: Callable[[TiltrovNode], Future | None] | None = None) -> int:
    """The ``main`` of every stack node: init, spin, end in order, always clean up.

    ``until`` returns a future that ends the spin when done (the plant's end of
    run). The run also ends on SIGINT or SIGTERM (Ctrl-C, the launcher). Either
    way the node then publishes its final /diagnostics (its message counts) and
    spins on until nothing it published can still be lost: in a run with a recorder,
    until the recorder says it has written the final report and every message the
    report counts, or is gone (:meth:`~tiltrov_ros.nodes.base.TiltrovNode.recorded_by_the_run`);
    a node started alone waits for its readers' acknowledgements
    (:meth:`~tiltrov_ros.nodes.base.TiltrovNode.wait_for_delivery`). A second signal
    ends that wait at once. Exit code 0; no KeyboardInterrupt, no death by signal.

    A start-up error (an unreadable parameter file, an invalid parameter, a
    wrong-type YAML value) is printed as one line naming the node and gives exit
    code 1.

    As a program (``args`` None) the process ends here, once the node, its executor
    and the DDS participant are torn down (:data:`TEARDOWN_BOUND` bounds a hang): the
    interpreter's own exit, which would destroy the executor's and DDS's C++ threads
    again in an order of its choosing, is skipped.
    """
    if not init(args, name, signal_handlers=False):
        return 1
    stop = threading.Event()
    hurry = threading.Event()
    takeover = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        (hurry if stop.is_set() else stop).set()

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    standby = os.environ.get(STANDBY_ENV) == '1'
    if standby:
        previous[signal.SIGUSR1] = signal.signal(signal.SIGUSR1,
                                                 lambda signum, frame: takeover.set())
    context = rclpy.get_default_context()
    remember_init_args(context, args)
    node: TiltrovNode | None = None
    executor: Executor | None = None
    code = 0
    retired: Standby | None = None
    try:
        kwargs: dict[str, Any] = {}
        if standby:
            retired = stand_by(factory, name, context, stop, takeover)
            if retired is None:
                return 0
            if TOPICS.get(name):
                kwargs['handoff'] = retired.handoff
        node = factory(**kwargs)
        gone, retired = retired, None
        retire(gone)                # only now that the node exists: see stand_by
        executor = make_executor(context)
        executor.add_node(node)
        future = until(node) if until is not None else None
        # Not executor.spin(): the EventsExecutor's does not return on a stop;
        # spin_until checks the flag between slices.
        spin_until(executor, context, future if future is not None else Future(),
                   step=STOP_POLL, stop=stop)
        node.publish_diagnostics(final=True)     # the final counts, for the recorder
        finish(node, executor, context, hurry)
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
        if args is None:
            faulthandler.dump_traceback_later(TEARDOWN_BOUND, exit=True, file=sys.__stderr__)
        if executor is not None:
            executor.shutdown()
        retire(retired)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        if args is None:
            faulthandler.cancel_dump_traceback_later()
        else:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
    if args is None:
        end_process(code)
    return code


def end_process(code: int) -> None:
    """Flush Python's and C's output streams and end the process with ``code`` now."""
    sys.stdout.flush()
    sys.stderr.flush()
    ctypes.CDLL(None).fflush(None)
    os._exit(code)


def stand_by(factory: Any, name: str, context: Context, stop: threading.Event,
             takeover: threading.Event) -> Standby | None:
    """A standby process: load the node's kernels, keep its predecessor's handoff
    (``<name>_standby``) until SIGUSR1 (return the standby, whose ``handoff`` is what it
    kept: the node is built next) or a stop signal (None).

    At a takeover the standby's node is not destroyed here but by the caller, once the
    node is built (:func:`retire`): rmw ends a context's DDS participant with its last
    node, so destroyed first, it took the process's participant with it, the node came up
    in a new one, and the other processes matched the node's endpoints only once they had
    discovered that participant: 1.4 to 2.5 s in a realtime run, without new commands
    meanwhile (in this order 0.26 to 0.48 s in 18 of 20 stress tries, 1.1 and 1.3 s in two)."""
    from tiltrov_ros.core import jit

    jit.warmup(getattr(factory, 'kernel_groups', ()))
    standby = Standby(name, context)
    executor = make_executor(context)
    executor.add_node(standby.node)
    standby.node.get_logger().info(f'standing by for {name} (SIGUSR1: take over)')
    try:
        done = Future()
        while context.ok() and not stop.is_set() and not takeover.is_set():
            executor.spin_until_future_complete(done, timeout_sec=STOP_POLL)
    finally:
        executor.shutdown()
        if not takeover.is_set():
            standby.node.destroy_node()
    if not takeover.is_set():
        return None
    print(f'{name}: taking over ({sum(len(v) for v in standby.handoff.kept.values())} '
          'handoff messages kept)', file=sys.stderr, flush=True)
    return standby


def retire(standby: Standby | None) -> None:
    """Destroy a standby's node once the node that took over is built."""
    if standby is not None:
        standby.node.destroy_node()


def finish(node: TiltrovNode, executor: Executor, context: Context,
           hurry: threading.Event) -> None:
    """After the final report: spin until the run's recorder has everything this node
    published, or is gone, or ``hurry`` is set (a node without run nodes waits for its
    readers' acknowledgements instead)."""
    if not node.handshake.active:
        node.wait_for_delivery()
        return
    done = Future()
    while context.ok() and not hurry.is_set() and not node.recorded_by_the_run():
        executor.spin_until_future_complete(done, timeout_sec=FINISH_POLL)
