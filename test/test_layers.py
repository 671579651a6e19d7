"""The package's layers: each imports only what ARCHITECTURE.md's table allows.

Every import of every module counts, at module level and inside functions
(the commands import lazily), relative ones resolved. The rules are read from
ARCHITECTURE.md ("Layers"), so the drawing and the check cannot drift apart.
"""

from __future__ import annotations

import ast
from pathlib import Path
import re
import sys

from harness import run_while_progressing
import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGE = REPO / 'tiltrov_ros'
#: Modules at the package root, below every layer.
BASE = {'tiltrov_ros', 'tiltrov_ros.paths', 'tiltrov_ros.progress'}


def _rules() -> dict[str, set[str]]:
    """layer -> layers it may import, from the table between the markers."""
    text = (REPO / 'ARCHITECTURE.md').read_text(encoding='utf-8')
    table = text.split('<!-- layers:begin -->')[1].split('<!-- layers:end -->')[0]
    rules: dict[str, set[str]] = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip('|').split('|')]
        if len(cells) != 2 or not cells[0].startswith('`'):
            continue
        layer = cells[0].strip('`/')
        allowed = set(re.findall(r'`(\w+)/?`', cells[1]))
        rules[layer] = allowed | {layer}
    return rules


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix('').parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


def _layer(module: str) -> str:
    if module in BASE:
        return 'base'
    return module.split('.')[1]


def _is_module(name: str) -> bool:
    path = PACKAGE.parent / name.replace('.', '/')
    return path.is_dir() or path.with_suffix('.py').is_file()


def _imports(path: Path) -> set[str]:
    """Every tiltrov_ros module ``path`` imports, anywhere in it."""
    module = _module_name(path)
    package = module if path.name == '__init__.py' else module.rpartition('.')[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')
                base = base[:len(base) - node.level + 1]
                target = '.'.join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ''
            found.add(target)
            # ``from tiltrov_ros import cli``: the names may be modules themselves
            found |= {f'{target}.{alias.name}' for alias in node.names
                      if _is_module(f'{target}.{alias.name}')}
    return {name for name in found if name == 'tiltrov_ros' or name.startswith('tiltrov_ros.')}


MODULES = sorted(PACKAGE.rglob('*.py'))


def test_every_module_belongs_to_a_layer_of_the_table() -> None:
    rules = _rules()
    assert set(rules) == {'base', 'core', 'bag', 'nodes', 'analysis', 'campaign', 'stack', 'cli'}
    layers = {_layer(_module_name(path)) for path in MODULES}
    assert layers <= set(rules), layers - set(rules)


@pytest.mark.parametrize('path', MODULES, ids=lambda p: str(p.relative_to(REPO)))
def test_imports_follow_the_layers(path: Path) -> None:
    rules = _rules()
    layer = _layer(_module_name(path))
    wrong = sorted(name for name in _imports(path) if _layer(name) not in rules[layer])
    assert not wrong, f'{layer} may import {sorted(rules[layer])}, not {wrong}'


def test_the_check_sees_function_level_and_relative_imports() -> None:
    """The walker itself: a lazy import inside a function and a relative one count."""
    sample = PACKAGE / 'core' / 'params.py'
    assert 'tiltrov_ros.paths' in _imports(sample)
    assert 'tiltrov_ros.nodes.base' in _imports(PACKAGE / 'nodes' / 'executors.py')
    lazy = PACKAGE / 'stack' / 'inprocess.py'          # imports nodes inside a function
    assert 'tiltrov_ros.nodes.executors' in _imports(lazy)


ROS_PACKAGES = {'rclpy', 'rosidl_runtime_py', 'std_msgs', 'geometry_msgs', 'nav_msgs',
                'sensor_msgs', 'rosgraph_msgs', 'diagnostic_msgs', 'builtin_interfaces'}


@pytest.mark.parametrize('package', ['analysis', 'campaign'])
def test_the_analysis_and_the_campaigns_load_no_ros(package: str) -> None:
    """The analysis of runs and bags and the campaigns need no ROS install (the
    core's own test: test/core/test_core_is_ros_free.py)."""
    modules = sorted(_module_name(p) for p in (PACKAGE / package).rglob('*.py'))
    code = (
        'import importlib, sys\n'
        f'for name in {modules!r}:\n'
        '    importlib.import_module(name)\n'
        f'ros = sorted(m for m in sys.modules if m.split(".")[0] in {ROS_PACKAGES!r})\n'
        'print(ros)\n'
        'sys.exit(1 if ros else 0)\n')
    result = run_while_progressing([sys.executable, '-c', code])
    assert result.returncode == 0, result.stdout + result.stderr
