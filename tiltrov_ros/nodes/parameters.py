"""Node parameters from the tables of :mod:`tiltrov_ros.core.paramtable`: ROS
descriptors, declaration, the shared robot block, the order in which command-line
values apply, and error messages that name the file a value came from.

Precedence. rcl merges every ``--params-file`` and ``-p`` into one table keyed
by node name, in the order the names first appear, and a node takes the
entries of every key that matches it in that order: a node's own section of a
parameter file given first beats a later ``-p`` (which rcl files under
``/**``) and a later launch file ``parameters=[{...}]`` (launch_ros writes them
under ``/**`` too). :func:`given_values` applies them as a ROS user reads the
command line instead: one after the other, the later winning; within one
file, a node's own section wins over wildcard sections. The nodes apply that
order before they declare anything (:func:`apply_command_line_order`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
import math
import re
import sys
from typing import Any
import weakref

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
import yaml

from tiltrov_ros.core import validation
from tiltrov_ros.core.names import NODES, standby_name
from tiltrov_ros.core.params import (
    ROBOT,
    STACK,
    RobotParams,
    load_control_period,
    load_robot_params,
)
from tiltrov_ros.core.paramtable import Param, ParamTable
from tiltrov_ros.core.yamlfile import flatten

#: ROS type of each kind of table line (arrays are typed by their elements, also empty).
_ROS_TYPES = {'float': Parameter.Type.DOUBLE, 'int': Parameter.Type.INTEGER,
              'bool': Parameter.Type.BOOL, 'str': Parameter.Type.STRING,
              'floats': Parameter.Type.DOUBLE_ARRAY, 'ints': Parameter.Type.INTEGER_ARRAY,
              'strs': Parameter.Type.STRING_ARRAY}
_CONVERT = {'float': float, 'int': int, 'bool': bool, 'str': str}


def descriptor(param: Param) -> ParameterDescriptor:
    """The ROS descriptor of a table line (``ros2 param describe`` shows it): the
    description with its unit, what is allowed, read-only, and the range ROS itself
    enforces (closed: an open bound is the table's check)."""
    unit = f' [{param.unit}]' if param.unit and param.unit != '-' else ''
    d = ParameterDescriptor(description=param.description + unit, read_only=param.read_only,
                            additional_constraints=param.allowed())
    if param.kind == 'float' and param.bounded:
        d.floating_point_range = [FloatingPointRange(from_value=float(param.low),
                                                     to_value=float(param.high), step=0.0)]
    if param.kind == 'int' and math.isfinite(param.low) and math.isfinite(param.high):
        d.integer_range = [IntegerRange(from_value=int(param.low), to_value=int(param.high),
                                        step=1)]
    return d


def _ros_value(param: Param, value: Any) -> Any:
    if param.is_array:
        item = _CONVERT[{'floats': 'float', 'ints': 'int', 'strs': 'str'}[param.kind]]
        return [item(v) for v in value]
    return _CONVERT[param.kind](value)


def declare(node: Node, table: ParamTable, *, defaults: Mapping[str, Any] | None = None,
            only: Iterable[str] | None = None) -> dict[str, Any]:
    """Declare ``table``'s parameters (``only`` these names) on ``node`` with their
    descriptors; return name -> value (lists for arrays).

    ``defaults`` replace the table's (the shipped files' values for SHIPPED
    lines, a scenario's). Every parameter gets a value, so ``ros2 param get`` and
    ``dump`` show it; arrays have their element type also when empty.
    """
    wanted = set(table.names if only is None else only)
    values: dict[str, Any] = {}
    for param in table:
        if param.name not in wanted:
            continue
        name = table.full_name(param.name)
        default = _ros_value(param, (defaults or {}).get(param.name, param.default))
        d = descriptor(param)
        given = _override(node, name)
        if param.is_array and not (default if given is None else given):
            value = _declare_empty_array(node, name, _ROS_TYPES[param.kind], d)
        elif param.is_array and not default:
            value = node.declare_parameter(name, _ROS_TYPES[param.kind], d).value
        else:
            value = node.declare_parameter(name, default, d).value
        values[param.name] = list(value) if param.is_array else value
    return values


def _override(node: Node, name: str) -> Any:
    """The value given for ``name`` (file, ``-p``, override), or None."""
    given = getattr(node, '_parameter_overrides', {}).get(name)
    return None if given is None else given.value


def _declare_empty_array(node: Node, name: str, kind: Parameter.Type,
                         d: ParameterDescriptor) -> list[Any]:
    """Declare ``name`` as an empty array of ``kind``.

    rclpy infers a declared parameter's type from its value, and an empty list
    reads as a byte array; rclpy's declaration step with an explicitly typed
    value keeps the element type (and read-only parameters stay read-only).
    """
    d.type = kind.value
    node._declare_parameter_common([Parameter(name, kind, [])], {name: d})
    return []


def check(table: ParamTable, values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` (from :func:`declare`) checked against ``table``: the choices,
    array sizes and open bounds ROS does not enforce."""
    return {name: table.check(name, value) for name, value in values.items()}


def allowed_text(d: ParameterDescriptor | None, default: Any) -> str:
    """What a parameter accepts (for error messages): its descriptor's allowed text."""
    if d is not None and d.additional_constraints:
        return str(d.additional_constraints)
    return {bool: 'true or false', int: 'an integer', float: 'a number', str: 'a string',
            list: 'a list'}.get(type(default), 'a value of the declared type')


# --------------------------------------------------------------------------- the command line


class _ValueLoader(yaml.SafeLoader):
    """YAML scalars as rcl reads parameter values: ``1e3`` (no dot) is a number too."""


_ValueLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float', re.compile(r'^[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+$'),
    list('-+0123456789.'))
# launch_ros writes a launch file's list values as Python tuples (``!!python/tuple``),
# which rcl reads as arrays: so do these files.
_ValueLoader.add_constructor('tag:yaml.org,2002:python/tuple',
                             lambda loader, node: loader.construct_sequence(node))

#: ``--ros-args`` options followed by a value that is not a parameter.
_OTHER_OPTIONS = ('-r', '--remap', '-e', '--enclave', '--log-level', '--log-config-file',
                  '--log-file-name')


def ros_arguments(args: Sequence[str]) -> list[tuple[str, str]]:
    """The parameter options of the ``--ros-args`` parts of ``args``, in order:
    ``('file', PATH)`` for ``--params-file``, ``('param', '[NODE:]NAME:=VALUE')`` for
    ``-p``/``--param``."""
    out: list[tuple[str, str]] = []
    inside = False
    i = 0
    while i < len(args):
        arg = args[i]
        if arg == '--ros-args':
            inside = True
        elif arg == '--':
            inside = False
        elif inside and i + 1 < len(args):
            if arg in ('-p', '--param'):
                out.append(('param', args[i + 1]))
                i += 1
            elif arg == '--params-file':
                out.append(('file', args[i + 1]))
                i += 1
            elif arg in _OTHER_OPTIONS:
                i += 1
        i += 1
    return out


def section_matches(key: str, node: str) -> bool:
    """True when the parameter file section ``key`` (``/**``, ``/*/name``, ``name``,
    ``/ns/name``) applies to the node with the full name ``node``: rcl's rules (a
    key without a leading slash is absolute, ``/*`` is one name token, ``/**``
    any number of them)."""
    key = key if key.startswith('/') else f'/{key}'
    pattern = re.escape(key).replace(r'/\*\*', '(?:/[^/]+)*').replace(r'/\*', '/[^/]+')
    return re.fullmatch(pattern, node) is not None


def file_sections(path: str) -> dict[str, dict[str, Any]]:
    """Section key -> its ``ros__parameters`` (flattened names) of a parameter file;
    empty when the file cannot be read (rcl reports that at start-up)."""
    try:
        with open(path, encoding='utf-8') as stream:
            doc = yaml.load(stream, Loader=_ValueLoader)
    except (OSError, yaml.YAMLError, UnicodeDecodeError):
        return {}
    if not isinstance(doc, Mapping):
        return {}
    out: dict[str, dict[str, Any]] = {}
    for key, section in doc.items():
        params = section.get('ros__parameters') if isinstance(section, Mapping) else None
        out[str(key)] = flatten(params) if isinstance(params, Mapping) else {}
    return out


@dataclass(frozen=True)
class Given:
    """A parameter value from the command line: ``source`` is its file (None: ``-p``)."""

    value: Any
    source: str | None


def given_values(args: Sequence[str], node: str) -> dict[str, Given]:
    """The parameter values ``args`` give the node ``node`` (full name), applied in
    order, the later winning; within one file, the node's own sections after the
    wildcard ones (see the module docstring)."""
    values: dict[str, Given] = {}
    for kind, text in ros_arguments(args):
        if kind == 'file':
            matching = [(key, params) for key, params in file_sections(text).items()
                        if section_matches(key, node)]
            for _, params in sorted(matching, key=lambda item: '*' not in item[0]):
                values.update({name: Given(v, text) for name, v in params.items()})
            continue
        rule, _, raw = text.partition(':=')
        target, _, name = rule.rpartition(':')
        if target and not section_matches(target, node):
            continue
        try:
            value = yaml.load(raw, Loader=_ValueLoader)
        except yaml.YAMLError:
            continue        # rcl refused it at start-up already
        values[name] = Given(value, None)
    return values


def misdirected_sections(args: Sequence[str], node: str) -> list[str]:
    """One line per parameter file section in ``args`` that reaches no node it could
    mean: a section naming none of the package's nodes (a typo), or one with this
    node's name that misses it (another namespace) while no section reaches it."""
    name = node.rsplit('/', 1)[-1]
    lines: list[str] = []
    missed: list[str] = []
    reached = False
    for kind, path in ros_arguments(args):
        if kind != 'file':
            continue
        for key in file_sections(path):
            if '*' in key:
                continue
            if section_matches(key, node):
                reached = True
                continue
            base = key.rstrip('/').rsplit('/', 1)[-1]
            if base == name:
                missed.append(f'parameter file {path}: section {key!r} does not reach this '
                              f'node ({node}): name it {node!r} or \'/**\'')
            elif base not in NODES and base not in {standby_name(n) for n in NODES}:
                # (a standby's section reaches the standby, and the node it becomes
                # after a takeover reads its own section from the same file)
                lines.append(f'parameter file {path}: section {key!r} names no node of '
                             f'tiltrov_ros ({", ".join(NODES)}); its parameters reach none')
    return lines + ([] if reached else missed)


#: The arguments each context was initialised with (:func:`remember_init_args`).
_INIT_ARGS: weakref.WeakKeyDictionary[Context, list[str]] = weakref.WeakKeyDictionary()


def remember_init_args(context: Context, args: Sequence[str] | None) -> None:
    """Record the arguments ``rclpy.init`` got for ``context`` (None: ``sys.argv``):
    the process-wide ``--ros-args`` of its nodes."""
    _INIT_ARGS[context] = list(sys.argv if args is None else args)


def init_args(context: Context) -> list[str]:
    """The process-wide arguments of ``context`` (``sys.argv`` if not recorded)."""
    return _INIT_ARGS.get(context, sys.argv)


def apply_command_line_order(node: Node, args: Sequence[str],
                             keep: Iterable[str] = ()) -> dict[str, Given]:
    """Make the values ``args`` give ``node`` the ones it declares (in command-line
    order, see :func:`given_values`), except those named in ``keep`` (constructor
    overrides, which win over the command line as in rclpy). Call before declaring
    anything; ``use_sim_time``, which rclpy declares first, is set again."""
    given = given_values(args, node.get_fully_qualified_name())
    overrides = node._parameter_overrides    # rclpy's values by name, read at declaration
    kept = set(keep)
    for name, g in given.items():
        if name in kept or g.value is None:
            continue
        try:
            overrides[name] = Parameter(name, value=g.value)
        except (TypeError, ValueError):
            continue        # not a ROS value (rcl read it its own way): rcl's stays
    sim = overrides.get('use_sim_time')
    if (sim is not None and 'use_sim_time' not in kept and node.has_parameter('use_sim_time')
            and sim.value != node.get_parameter('use_sim_time').value):
        node.set_parameters([sim])
    return given


def parameter_source(name: str, node: str, args: Sequence[str]) -> str | None:
    """The parameter file in ``args`` whose value of ``name`` (or ``robot.<name>``)
    applies to ``node`` (a full name, or a name: ``/name``); None when the value
    comes from ``-p`` or nowhere."""
    given = given_values(args, node if node.startswith('/') else f'/{node}')
    found = given.get(name) or given.get(f'robot.{name}')
    return found.source if found is not None else None


def declare_failed_thrusters(node: Node) -> tuple[int, ...]:
    """Declare ``failed_thrusters`` (:data:`~tiltrov_ros.core.validation.FAILED_THRUSTERS`,
    run-time changeable) and return the core indices (0..3)."""
    value = declare(node, validation.FAILED_THRUSTERS)['failed_thrusters']
    return validation.failed_thruster_indices(value)


def robot_defaults() -> dict[str, Any]:
    """The shipped ``config/robot.yaml``: the defaults of ``robot.*`` and ``control_period``."""
    return {**load_robot_params().as_dict(), 'control_period': load_control_period()}


def declare_robot(node: Node) -> tuple[RobotParams, float]:
    """Declare ``robot.*`` and ``control_period`` (the shared robot.yaml) and return them.

    Defaults are the shipped ``config/robot.yaml``, so a node started without a
    parameter file runs the shipped robot. All read-only: the geometry and the
    control period of a running stack do not change. Validated by the core
    (:class:`~tiltrov_ros.core.params.RobotParams`); an invalid value raises
    :class:`~tiltrov_ros.core.errors.ParameterError` naming it.
    """
    shipped = robot_defaults()
    values = declare(node, ROBOT, defaults=shipped)
    period = check(STACK, declare(node, STACK, defaults=shipped))['control_period']
    return RobotParams.from_mapping(values), period


Overrides = Mapping[str, Any] | Sequence[Parameter] | None


def as_parameters(overrides: Overrides) -> list[Parameter]:
    """Parameter overrides from a mapping (name -> value) or a list of Parameters."""
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [Parameter(name, value=value) for name, value in overrides.items()]
    return list(overrides)
