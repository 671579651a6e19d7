"""Test harness shared by the whole suite.

* DDS isolation: one ``ROS_DOMAIN_ID`` per test session that no other session on
  the machine holds (a lock per domain, :func:`domains.claim_domain`) and
  ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, set before rclpy is imported
  anywhere, so two test runs on one machine (CI and a developer) never hear
  each other. Subprocesses started by tests inherit both.
* ``ros``: a fresh rclpy ``Context`` per test, with nodes and executors bound
  to it and torn down in order (executor shutdown, destroy nodes, shutdown).
* ``spin_until``: spins in a capped loop with a wall-clock timeout.
* Per-test timeout: ``timeout`` in pyproject.toml (pytest-timeout).
* Hypothesis: profile ``ci`` (derandomized: the same examples every run, no
  example database) when ``TILTROV_HYPOTHESIS_PROFILE=ci`` or ``CI`` is set, as
  ``make test`` and ``.ci/run`` do; otherwise Hypothesis's random default, to
  find new cases while developing.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import os
from pathlib import Path
import time
from typing import Any

from domains import claim_domain
from hypothesis import settings
import pytest

if 'TILTROV_TEST_DOMAIN_ID' not in os.environ:
    # A nested session (a test that runs pytest or colcon test) inherits its parent's.
    _domain, _domain_lock = claim_domain()      # the lock is held open for the session
    os.environ['TILTROV_TEST_DOMAIN_ID'] = str(_domain)
os.environ['ROS_DOMAIN_ID'] = os.environ['TILTROV_TEST_DOMAIN_ID']
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_STATIC_PEERS', None)
os.environ.setdefault('MPLBACKEND', 'Agg')

REPO_ROOT = Path(__file__).resolve().parent.parent

settings.register_profile('ci', derandomize=True, database=None, print_blob=True)
settings.register_profile('dev')
settings.load_profile(os.environ.get('TILTROV_HYPOTHESIS_PROFILE')
                      or ('ci' if os.environ.get('CI') else 'dev'))


def pytest_report_header(config: pytest.Config) -> str:
    return (f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
            f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}")


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


@pytest.fixture
def ros() -> Iterator[RosHarness]:
    """A fresh rclpy context for one test, torn down in order afterwards."""
    harness = RosHarness()
    try:
        yield harness
    finally:
        harness.close()


@pytest.fixture
def repo_root() -> Path:
    return REPO_ROOT


@pytest.fixture(scope='session')
def colcon_workspace(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """The package colcon-built in a temporary workspace, once per session
    (:func:`workspace.build_workspace`)."""
    from workspace import build_workspace
    return build_workspace(tmp_path_factory.mktemp('ws'))
