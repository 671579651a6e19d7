"""``docs/parameters.md``, generated from the parameter tables (``make docs``).

::

    python -m tiltrov_ros.nodes.parameter_docs docs/parameters.md          # write
    python -m tiltrov_ros.nodes.parameter_docs --check docs/parameters.md  # compare

A test keeps the committed page equal to :func:`render` and each node's
declared parameters equal to the tables listed here for it (:data:`NODES`).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
import sys
from typing import Any

from tiltrov_ros.core.allocation import ALLOCATION, load_allocator_config
from tiltrov_ros.core.controllers import (
    CONTROL_LAW,
    GAINS,
    SWITCHING,
    load_controller_config,
)
from tiltrov_ros.core.names import ALLOCATOR, CONTROLLER, PLANT, RECORDER, REFERENCE
from tiltrov_ros.core.params import ROBOT, STACK
from tiltrov_ros.core.paramtable import ParamTable
from tiltrov_ros.core.validation import FAILED_THRUSTERS

from .allocator_params import ALLOCATOR_PARAMS
from .base import RUN
from .controller_params import CONTROLLER_PARAMS
from .guard import STAMP_BOUNDS
from .parameters import robot_defaults
from .plant_config import PLANT_PARAMS
from .recorder_config import RECORDER_PARAMS
from .reference_publisher import REFERENCE_PARAMS


@dataclass(frozen=True)
class NodeParameters:
    """The parameter sets one node declares: its own tables, then the shared ones."""

    node: str
    tables: tuple[ParamTable, ...]
    shared: tuple[ParamTable, ...]

    @property
    def names(self) -> set[str]:
        """Every parameter name the node declares (besides rclpy's ``use_sim_time``)."""
        return {t.full_name(p.name) for t in (*self.tables, *self.shared) for p in t}


_ROBOT = (ROBOT, STACK)
NODES = (
    NodeParameters(PLANT, (PLANT_PARAMS, FAILED_THRUSTERS),
                   (STAMP_BOUNDS, RUN, *_ROBOT)),
    NodeParameters(CONTROLLER, (CONTROL_LAW, CONTROLLER_PARAMS, GAINS, SWITCHING),
                   (STAMP_BOUNDS, RUN, *_ROBOT)),
    NodeParameters(ALLOCATOR, (ALLOCATION, ALLOCATOR_PARAMS, FAILED_THRUSTERS),
                   (STAMP_BOUNDS, RUN, *_ROBOT)),
    NodeParameters(REFERENCE, (REFERENCE_PARAMS,), (RUN, *_ROBOT)),
    NodeParameters(RECORDER, (RECORDER_PARAMS,), (RUN,)),
)

_INTRO = """\
# Parameters

Generated from the parameter tables in the code (`make docs`; a test keeps this
page equal to them): one line per parameter gives its type, default, allowed
values, unit, whether it can change at run time, and its meaning. The same
line gives the ROS descriptor (`ros2 param describe` shows the description,
the allowed values and the range) and the validation of parameter files and
of the core's configuration files.

Every node runs with no parameter file at all: the defaults below are its
values then (for the robot, the gains and the allocator: the shipped
`config/*.yaml`). Parameters that cannot change (`changeable: no`) are
read-only: `ros2 param set` refuses them. The others are checked when set, by
ROS against the range and by the core against the rest; a refused change
returns the reason ([nodes.md](nodes.md)).

A value of the wrong type in a file (`1` where `1.0` is declared), out of
range or otherwise invalid stops the node at start with exit code 1 and one
line naming the parameter, the file that set it, the value and what is
allowed; an unknown parameter in a file is reported as a warning
([reliability.md](reliability.md)).
"""


def _defaults() -> dict[str, dict[str, Any]]:
    """The shipped files' values of the SHIPPED lines, by table title."""
    robot = robot_defaults()
    controller = load_controller_config()
    return {ROBOT.title: robot, STACK.title: robot,
            CONTROL_LAW.title: {'controller': controller.kind},
            GAINS.title: asdict(controller.gains),
            SWITCHING.title: asdict(controller.switching),
            ALLOCATION.title: asdict(load_allocator_config())}


def render() -> str:
    """The whole page."""
    defaults = _defaults()
    shared_by: dict[str, list[str]] = {}
    for entry in NODES:
        for table in entry.shared:
            shared_by.setdefault(table.title, []).append(entry.node)
    parts = [_INTRO]
    for entry in NODES:
        parts += [f'## {entry.node}', '',
                  f'Parameter file: `config/{entry.node}.yaml`.', '']
        parts += [table.markdown(defaults.get(table.title), header=i == 0)
                  for i, table in enumerate(entry.tables)] + ['']
        if entry.shared:
            parts += ['Also: ' + ', '.join(f'[{t.title}](#{_anchor(t.title)})'
                                           for t in entry.shared) + '.', '']
    parts += ['## Shared by several nodes', '']
    seen: set[str] = set()
    for entry in NODES:
        for table in entry.shared:
            if table.title in seen:
                continue
            seen.add(table.title)
            parts += [f'### {table.title}', '',
                      f'Nodes: {", ".join(shared_by[table.title])}.', '',
                      table.markdown(defaults.get(table.title)), '']
    return '\n'.join(parts).rstrip('\n') + '\n'


def _anchor(title: str) -> str:
    return title.lower().replace(' ', '-').replace('.', '')


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog='python -m tiltrov_ros.nodes.parameter_docs',
                                     description=__doc__.splitlines()[0])
    parser.add_argument('page', type=Path, help='the Markdown file (docs/parameters.md)')
    parser.add_argument('--check', action='store_true',
                        help='exit 1 if the file differs from the tables instead of writing')
    args = parser.parse_args(argv)
    text = render()
    if args.check:
        current = args.page.read_text(encoding='utf-8') if args.page.is_file() else ''
        if current != text:
            print(f'{args.page} is not what the parameter tables give: run make docs',
                  file=sys.stderr)
            return 1
        return 0
    args.page.write_text(text, encoding='utf-8')
    print(f'wrote {args.page}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
