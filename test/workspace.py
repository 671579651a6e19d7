"""A colcon workspace holding the package, as a ROS 2 user builds it: the sources
copied to ``src/tiltrov_ros``, ``colcon build``, and the environment of
``source install/setup.bash`` (for ``ros2 run``, ``ros2 launch`` and colcon test)."""

from __future__ import annotations

from dataclasses import dataclass
import os
from pathlib import Path
import shutil
import subprocess
import sys

REPO = Path(__file__).resolve().parent.parent
PACKAGE = 'tiltrov_ros'

#: What a workspace checkout does not have (build products, caches, the venv).
NOT_SOURCES = ('.venv', '.git', 'build', 'install', 'log', 'runs', '__pycache__',
               '*.egg-info', '.pytest_cache', '.mypy_cache', '.ruff_cache', '.hypothesis')


@dataclass(frozen=True)
class Workspace:
    root: Path
    env: dict[str, str]     # the environment after ``source install/setup.bash``

    @property
    def source(self) -> Path:
        return self.root / 'src' / PACKAGE

    @property
    def prefix(self) -> Path:
        return self.root / 'install' / PACKAGE

    @property
    def share(self) -> Path:
        return self.prefix / 'share' / PACKAGE


def colcon() -> Path:
    """colcon (colcon-common-extensions, part of the dev install): on PATH or in the venv."""
    found = shutil.which('colcon')
    return Path(found) if found else Path(sys.executable).with_name('colcon')


def build_workspace(root: Path) -> Workspace:
    """``colcon build`` of a copy of the package's sources in ``root``; raises
    AssertionError with colcon's output when the build fails."""
    shutil.copytree(REPO, root / 'src' / PACKAGE, ignore=shutil.ignore_patterns(*NOT_SOURCES))
    env = dict(os.environ, COLCON_HOME=str(root / 'colcon_home'))
    # The venv's python builds and runs the package (its scripts' shebang).
    env['PATH'] = os.pathsep.join([str(Path(sys.executable).parent), env.get('PATH', '')])
    result = subprocess.run(
        [str(colcon()), 'build', '--event-handlers', 'console_direct-'],
        cwd=root, env=env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    sourced = subprocess.run(
        ['bash', '-c', 'source install/setup.bash && env -0'], cwd=root, env=env,
        capture_output=True, text=True, timeout=60, check=True)
    env = dict(line.split('=', 1) for line in sourced.stdout.split('\0') if '=' in line)
    # The ros2 command line's wheels in the venv ship no setup script: their prefix is
    # added as their README says (a ROS install's own setup.bash has done it already).
    prefixes = env.get('AMENT_PREFIX_PATH', '').split(os.pathsep)
    if sys.prefix not in prefixes:
        env['AMENT_PREFIX_PATH'] = os.pathsep.join([*filter(None, prefixes), sys.prefix])
    return Workspace(root, env)
