"""tiltrov_ros.core never imports rclpy (nor any ROS message package)."""

from __future__ import annotations

from pathlib import Path
import subprocess
import sys

import tiltrov_ros.core

CORE = Path(tiltrov_ros.core.__file__).parent


def test_importing_every_core_module_loads_no_ros() -> None:
    modules = sorted(f'tiltrov_ros.core.{p.stem}' for p in CORE.glob('*.py')
                     if p.stem != '__init__')
    assert len(modules) >= 3
    code = (
        'import importlib, sys\n'
        f'for name in {modules!r}:\n'
        '    importlib.import_module(name)\n'
        "ros = sorted(m for m in sys.modules if m.split('.')[0] in "
        "{'rclpy', 'rosidl_runtime_py', 'std_msgs', 'geometry_msgs', 'nav_msgs', "
        "'sensor_msgs', 'rosgraph_msgs', 'diagnostic_msgs', 'builtin_interfaces'})\n"
        'print(ros)\n'
        'sys.exit(1 if ros else 0)\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 0, result.stdout + result.stderr
