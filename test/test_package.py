"""Packaging: the colcon build a ROS 2 user makes, and the package manifest."""

from __future__ import annotations

import ast
import os
from pathlib import Path

from catkin_pkg.package import parse_package
import pytest
from workspace import Workspace, colcon

REPO = Path(__file__).resolve().parent.parent


def _console_scripts() -> list[str]:
    """Executable names declared in setup.py's console_scripts."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    for node in ast.walk(tree):
        if (isinstance(node, ast.Assign) and len(node.targets) == 1
                and getattr(node.targets[0], 'id', None) == 'console_scripts'):
            entries = ast.literal_eval(node.value)
            return [entry.split('=')[0].strip() for entry in entries]
    raise AssertionError('setup.py declares no console_scripts list')


def test_package_xml_is_format_3_ament_python() -> None:
    package = parse_package(str(REPO / 'package.xml'))
    assert package.package_format == 3
    assert package.name == 'tiltrov_ros'
    assert package.get_build_type() == 'ament_python'
    exec_deps = {dep.name for dep in package.exec_depends}
    assert {'rclpy', 'nav_msgs', 'geometry_msgs', 'sensor_msgs', 'std_msgs', 'rosgraph_msgs',
            'diagnostic_msgs', 'tf2_msgs', 'robot_state_publisher', 'python3-numpy',
            'python3-scipy'} <= exec_deps
    assert 'python3-pytest' in {dep.name for dep in package.test_depends}


def test_ros_wheels_are_not_install_requires() -> None:
    """A colcon build inside a ROS install must not pull a second rclpy from PyPI."""
    setup_py = (REPO / 'setup.py').read_text()
    tree = ast.parse(setup_py)
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == 'install_requires':
            requires = ast.literal_eval(node.value)
            assert not [r for r in requires if r.startswith(('ros-', 'rclpy'))], requires
            break
    else:
        raise AssertionError('no install_requires in setup.py')


@pytest.mark.slow
def test_colcon_build_installs_what_ros2_run_needs(colcon_workspace: Workspace) -> None:
    assert colcon().exists(), 'colcon-common-extensions is part of the dev install'
    prefix = colcon_workspace.prefix
    lib = prefix / 'lib' / 'tiltrov_ros'
    for name in _console_scripts():
        exe = lib / name
        assert exe.is_file(), f'{name} missing from {lib}: {sorted(os.listdir(lib))}'
        assert os.access(exe, os.X_OK)
    share = prefix / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / 'tiltrov_ros').is_file()
    assert (share / 'tiltrov_ros' / 'package.xml').is_file()
    shipped = sorted(p.relative_to(REPO) for pattern in ('*.yaml', '*.json', '*.xml', '*.rviz')
                     for p in (REPO / 'config').rglob(pattern))
    shipped += [p.relative_to(REPO) for p in (REPO / 'urdf').glob('*.urdf')]
    assert shipped, 'config/ ships parameter files and layouts'
    shipped += [p.relative_to(REPO) for p in (REPO / 'launch').glob('*.launch.py')]
    for rel in shipped:
        assert (share / 'tiltrov_ros' / rel).is_file(), rel
    assert (share / 'tiltrov_ros' / 'launch' / 'tiltrov.launch.py').is_file()
