"""The rclpy harness of the tests: one context with its nodes and executor.

In a module of its own (test/ is on sys.path) so that a test can build one for a
module-scoped fixture; ``conftest.py`` gives each test its own (``ros``).
"""

from __future__ import annotations

from collections.abc import Callable
import time
from typing import Any


class RosHarness:
    """One rclpy context with its nodes and executor, for a single test."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        self._rclpy = rclpy
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes: list[Any] = []

    def add(self, node: Any) -> Any:
        """Register a node built with ``context=harness.context``; return it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def node(self, name: str, **kwargs: Any) -> Any:
        """Create a plain rclpy node bound to this context."""
        return self.add(self._rclpy.create_node(name, context=self.context, **kwargs))

    def spin_until(self, predicate: Callable[[], bool], timeout: float = 10.0,
                   step: float = 0.01) -> bool:
        """Spin until ``predicate()`` is true or ``timeout`` wall seconds pass.

        Returns the last value of the predicate, so tests ``assert`` on it.
        """
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return bool(predicate())
            self.executor.spin_once(timeout_sec=step)
        return True

    def spin_while_progressing(self, predicate: Callable[[], bool],
                               progress: Callable[[], object], idle: float = 120.0,
                               step: float = 0.01) -> bool:
        """:func:`spin_while_progressing` on this harness's executor."""
        return spin_while_progressing(self.executor, predicate, progress, idle, step)

    def spin_for(self, seconds: float, step: float = 0.01) -> None:
        """Spin for a fixed wall-clock duration (to let late messages arrive)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=step)

    def close(self) -> None:
        self.executor.shutdown()
        for node in reversed(self.nodes):
            node.destroy_node()
        self.nodes.clear()
        self._rclpy.try_shutdown(context=self.context)


def spin_while_progressing(executor: Any, predicate: Callable[[], bool],
                           progress: Callable[[], object], idle: float = 120.0,
                           step: float = 0.01) -> bool:
    """Spin ``executor`` until ``predicate()`` is true, for as long as ``progress()`` keeps
    changing: give up once it has not changed for ``idle`` wall seconds (a hang, however
    slow the machine; a loaded one takes longer, never too long). Returns the last value
    of the predicate, so tests ``assert`` on it."""
    seen, since = progress(), time.monotonic()
    while not predicate():
        now = progress()
        if now != seen:
            seen, since = now, time.monotonic()
        elif time.monotonic() - since > idle:
            return bool(predicate())
        executor.spin_once(timeout_sec=step)
    return True
