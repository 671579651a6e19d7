"""Node parameters from the tables of :mod:`tiltrov_ros.core.paramtable`: ROS
descriptors, declaration, the shared robot block, and error messages that name
the file a value came from."""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
import math
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter
import yaml

from tiltrov_ros.core import validation
from tiltrov_ros.core.params import (
    ROBOT,
    STACK,
    RobotParams,
    load_control_period,
    load_robot_params,
)
from tiltrov_ros.core.paramtable import UNSET, Param, ParamTable

#: ROS type of a parameter declared without a value.
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
    descriptors; return name -> value (lists for arrays, None for an unset one).

    ``defaults`` replace the table's (the shipped files' values for SHIPPED
    lines). An array declared empty (``[]``) has dynamic typing: it has no
    element type to check.
    """
    wanted = set(table.names if only is None else only)
    values: dict[str, Any] = {}
    for param in table:
        if param.name not in wanted:
            continue
        default = (defaults or {}).get(param.name, param.default)
        d = descriptor(param)
        name = table.full_name(param.name)
        if default is UNSET:
            value = node.declare_parameter(name, _ROS_TYPES[param.kind], d).value
        else:
            ros_default = _ros_value(param, default)
            if param.is_array and not ros_default:
                d.dynamic_typing = True
            value = node.declare_parameter(name, ros_default, d).value
        values[param.name] = list(value) if param.is_array and value is not None else value
    return values


def check(table: ParamTable, values: Mapping[str, Any]) -> dict[str, Any]:
    """``values`` (from :func:`declare`) checked against ``table``: the choices,
    array sizes and open bounds ROS does not enforce. Unset ones stay None."""
    return {name: (value if value is None else table.check(name, value))
            for name, value in values.items()}


def allowed_text(d: ParameterDescriptor | None, default: Any) -> str:
    """What a parameter accepts (for error messages): its descriptor's allowed text."""
    if d is not None and d.additional_constraints:
        return str(d.additional_constraints)
    return {bool: 'true or false', int: 'an integer', float: 'a number', str: 'a string',
            list: 'a list'}.get(type(default), 'a value of the declared type')


def _flatten(doc: Any, prefix: str = '') -> set[str]:
    names: set[str] = set()
    if isinstance(doc, Mapping):
        for key, value in doc.items():
            names |= _flatten(value, f'{prefix}{key}.') if isinstance(value, Mapping) else {
                f'{prefix}{key}'}
    return names


def parameter_source(name: str, node_name: str, args: Sequence[str]) -> str | None:
    """The last ``--params-file`` in ``args`` that sets ``name`` (or ``robot.<name>``)
    for ``node_name`` or ``/**``; None when no file does (an override, ``-p``)."""
    files = [args[i + 1] for i, a in enumerate(args[:-1]) if a == '--params-file']
    for path in reversed(files):
        try:
            with open(path, encoding='utf-8') as stream:
                doc = yaml.safe_load(stream)
        except (OSError, yaml.YAMLError):
            continue
        if not isinstance(doc, Mapping):
            continue
        for key, section in doc.items():
            key = str(key)
            if key not in ('/**', '**', node_name) and not key.endswith(f'/{node_name}'):
                continue
            params = section.get('ros__parameters') if isinstance(section, Mapping) else None
            names = _flatten(params)
            if name in names or f'robot.{name}' in names:
                return str(path)
    return None


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
