"""The package driven with the real ``ros2`` command line (ros2cli, launch_ros),
after a colcon build in a temporary workspace (one per session), with the
environment of ``source install/setup.bash``.

Skipped, with the reason, when the command line is not installed: ``make
ros2-cli`` adds it to the venv from ``TILTROV_ROS2_CLI``; in a ROS 2 install it
is the system's. Graph commands run without the daemon (``--no-daemon``) and
wait on conditions (``--timeout``, a node seen by a probe), never on sleeps.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from ros2_cli import Ros2, missing_cli
from workspace import Workspace


@pytest.fixture(scope='session')
def ros2_workspace(request: pytest.FixtureRequest) -> Workspace:
    """The colcon workspace, once the command line is known to be there."""
    reason = missing_cli()
    if reason:
        pytest.skip(reason)
    workspace: Workspace = request.getfixturevalue('colcon_workspace')
    return workspace


@pytest.fixture
def ros2(ros2_workspace: Workspace) -> Iterator[Ros2]:
    runner = Ros2(ros2_workspace)
    try:
        yield runner
    finally:
        runner.cleanup()
