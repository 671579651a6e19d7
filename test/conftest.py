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

from collections.abc import Iterator
import os
from pathlib import Path
from typing import Any

from domains import claim_domain
from harness import RosHarness
from hypothesis import settings
import pytest

if 'TILTROV_TEST_DOMAIN_ID' not in os.environ or os.environ.get('PYTEST_XDIST_WORKER'):
    # A nested session (a test that runs pytest or colcon test) inherits its parent's;
    # each worker of a parallel run (pytest-xdist) takes its own, not its master's.
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


#: ``make test`` runs the suite on two workers (pytest-xdist, ``--dist loadgroup``),
#: each with its own DDS domain. Every file runs whole on one worker (its module and
#: session fixtures are built once) and a folder whose tests share a session fixture
#: stays together, except these files: long tests that share nothing, spread over the
#: workers one by one.
SPREAD = frozenset({'test/test_kernels_start.py', 'test/stack/test_reliability.py',
                    'test/stack/test_launch.py', 'test/core/test_allocation_optimum.py'})
TOGETHER = ('test/ros2cli/', 'test/campaign/')


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        path = Path(str(item.fspath)).resolve()
        try:
            name = path.relative_to(REPO_ROOT).as_posix()
        except ValueError:
            continue
        if name in SPREAD:
            continue
        group = next((folder for folder in TOGETHER if name.startswith(folder)), name)
        item.add_marker(pytest.mark.xdist_group(group))
