"""The rclpy harness of the tests: one context with its nodes and executor.

In a module of its own (test/ is on sys.path) so that a test can build one for a
module-scoped fixture; ``conftest.py`` gives each test its own (``ros``).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
import os
import subprocess
import tempfile
import time
from typing import Any

#: pytest-timeout of a test whose waits give up on a hang (``spin_while_progressing``,
#: ``wait_while_progressing``), not on a slow machine: only a hang that its own waits
#: missed reaches it.
HANG_BOUND = 1200


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
    return progressing_until(predicate, progress, idle,
                             lambda: executor.spin_once(timeout_sec=step))


def progressing_until(predicate: Callable[[], bool], progress: Callable[[], object],
                      idle: float = 120.0, pause: Callable[[], None] | None = None) -> bool:
    """Until ``predicate()`` is true, for as long as ``progress()`` keeps changing: False
    once it has not changed for ``idle`` wall seconds (a hang, however slow the machine).
    ``pause`` runs between looks (default: sleep 0.05 s)."""
    seen, since = progress(), time.monotonic()
    while not predicate():
        now = progress()
        if now != seen:
            seen, since = now, time.monotonic()
        elif time.monotonic() - since > idle:
            return bool(predicate())
        if pause is None:
            time.sleep(0.05)
        else:
            pause()
    return True


def tree_cpu(root: int) -> int:
    """CPU time (clock ticks, user and system, reaped children's included) used so far by
    process ``root`` and every process below it: how far a start or a stop has got, on a
    machine however loaded (a process that waits uses none, one that imports or compiles
    does)."""
    stats: dict[int, tuple[int, int]] = {}
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open(f'/proc/{entry}/stat', 'rb') as stat:
                fields = stat.read().rpartition(b')')[2].split()
        except OSError:             # ended meanwhile
            continue
        # fields[1]: ppid; fields[11:15]: utime, stime, cutime, cstime (proc(5)).
        stats[int(entry)] = (int(fields[1]), sum(int(x) for x in fields[11:15]))
    children: dict[int, list[int]] = defaultdict(list)
    for pid, (ppid, _) in stats.items():
        children[ppid].append(pid)
    total, todo = 0, [root]
    while todo:
        pid = todo.pop()
        if pid in stats:
            total += stats[pid][1]
            todo += children[pid]
    return total


class TreeProgress:
    """``progress`` for :func:`spin_while_progressing` while processes start or stop: the
    CPU time of the trees of ``roots`` (:func:`tree_cpu`), looked at most every
    ``every`` wall seconds (a look reads every process's stat)."""

    def __init__(self, *roots: int, every: float = 0.5) -> None:
        self.roots = roots
        self.every = every
        self._at = -float('inf')
        self._value = 0

    def __call__(self) -> int:
        now = time.monotonic()
        if now - self._at >= self.every:
            self._at, self._value = now, sum(tree_cpu(root) for root in self.roots)
        return self._value


def wait_while_progressing(proc: Any, idle: float = 120.0) -> int:
    """Wait for ``proc`` (a Popen) to end, for as long as its process tree keeps using CPU
    (:class:`TreeProgress`): its exit code; AssertionError once it has used none for
    ``idle`` wall seconds (a hang, not a slow machine)."""
    assert progressing_until(lambda: proc.poll() is not None, TreeProgress(proc.pid), idle), \
        f'pid {proc.pid} idle for {idle} s'
    return int(proc.returncode)


def run_while_progressing(argv: list[str], cwd: Any = None, idle: float = 120.0,
                          **kwargs: Any) -> subprocess.CompletedProcess[str]:
    """``subprocess.run(argv, capture_output=True, text=True)`` without a wall-clock
    timeout: the command runs to its end however slowly a loaded machine runs it, and
    only a hang (no CPU used by its processes for ``idle`` s) fails it
    (:func:`wait_while_progressing`)."""
    with tempfile.TemporaryFile('w+') as out, tempfile.TemporaryFile('w+') as err:
        proc = subprocess.Popen(argv, cwd=cwd, stdout=out, stderr=err, text=True, **kwargs)
        try:
            code = wait_while_progressing(proc, idle)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        out.seek(0)
        err.seek(0)
        return subprocess.CompletedProcess(argv, code, out.read(), err.read())
