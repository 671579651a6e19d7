"""Where the package's shipped files (config YAML, scenarios) live.

At the bottom of the package's layers: it imports nothing of the package, so
the core can find ``config/`` without reaching up.

Three layouts are supported, tried in this order:

1. a source checkout or editable install: ``config/`` next to ``package.xml``
   at the repository root;
2. a colcon install inside a ROS 2 workspace: ``share/tiltrov_ros/config``
   found through the ament index;
3. a plain pip install: ``<sys.prefix>/share/tiltrov_ros/config``.
"""

from __future__ import annotations

from functools import cache
from pathlib import Path
import sys

PACKAGE_NAME = 'tiltrov_ros'


@cache
def share_dir() -> Path:
    """Return the directory that holds ``package.xml`` and ``config/``."""
    source_root = Path(__file__).resolve().parent.parent
    if (source_root / 'package.xml').is_file() and (source_root / 'config').is_dir():
        return source_root
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )
    except ImportError:
        pass
    else:
        try:
            return Path(get_package_share_directory(PACKAGE_NAME))
        except PackageNotFoundError:
            pass
    prefix_share = Path(sys.prefix) / 'share' / PACKAGE_NAME
    if (prefix_share / 'config').is_dir():
        return prefix_share
    raise FileNotFoundError(
        f'cannot find the {PACKAGE_NAME} share directory (config/): not a source '
        f'checkout, not in the ament index, not under {prefix_share}')


def config_dir() -> Path:
    """Directory of the shipped parameter YAML files."""
    return share_dir() / 'config'


def config_file(name: str) -> Path:
    """Path of a shipped YAML file, e.g. ``config_file('robot.yaml')``."""
    path = config_dir() / name
    if not path.is_file():
        raise FileNotFoundError(f'no shipped config file {name!r} in {config_dir()}')
    return path


def scenario_dir() -> Path:
    """Directory of the shipped scenario files."""
    return config_dir() / 'scenarios'
