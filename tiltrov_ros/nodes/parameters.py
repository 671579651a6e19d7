"""Node parameters: declaration with descriptors, the robot block, error messages
naming the file a value came from, and overrides."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter
import yaml

from tiltrov_ros.core import validation
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.params import RobotParams, load_control_period, load_robot_params


def descriptor(description: str, *, read_only: bool = False,
               floating: tuple[float, float] | None = None,
               integer: tuple[int, int] | None = None,
               constraints: str = '') -> ParameterDescriptor:
    """A ParameterDescriptor with an optional range (shown by ``ros2 param describe``)."""
    d = ParameterDescriptor(description=description, read_only=read_only,
                            additional_constraints=constraints)
    if floating is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float(floating[0]),
                                                     to_value=float(floating[1]), step=0.0)]
    if integer is not None:
        d.integer_range = [IntegerRange(from_value=integer[0], to_value=integer[1], step=1)]
    return d


# robot.* (config/robot.yaml, '/**'): description and range of each scalar. Read-only.
_ROBOT_DOC: dict[str, tuple[str, tuple[float, float] | None]] = {
    'mass_matrix': ('diagonal of M (A.2), rigid body + added mass: kg (surge, sway, heave), '
                    'kg m^2 (roll, pitch, yaw); 6 numbers > 0', None),
    'quadratic_damping': ('quadratic damping d_i of (A.4), D(nu) = diag(d_i |nu_i|): '
                          'N s^2/m^2, N m s^2; 6 numbers >= 0', None),
    'linear_damping': ('linear damping added to (A.4): N s/m, N m s; 6 numbers >= 0', None),
    'weight': ('W = m g, N (> 0)', (0.0, math.inf)),
    'buoyancy': ('B, N (>= 0)', (0.0, math.inf)),
    'center_of_gravity': ('nominal r_g in base_link_frd, m (3 numbers)', None),
    'center_of_buoyancy': ('r_b in base_link_frd, m (3 numbers)', None),
    'length': ('l, thruster spacing along x, m (> 0)', (0.0, math.inf)),
    'width': ('d, thruster spacing along y, m (> 0)', (0.0, math.inf)),
    'max_thrust': ('thrust limit of each thruster in both directions, N (> 0)',
                   (0.0, math.inf)),
    'thruster_time_constant': ('first-order thruster time constant, s (0: ideal)',
                               (0.0, math.inf)),
    'tilt_min': ('lower servo angle limit, rad', (-math.pi, math.pi)),
    'tilt_max': ('upper servo angle limit, rad', (-math.pi, math.pi)),
    'tilt_rate_limit': ('servo rate limit, rad/s (> 0)', (0.0, math.inf)),
}


def allowed_text(d: ParameterDescriptor | None, default: Any) -> str:
    """What a parameter accepts, from its descriptor and default (for error messages)."""
    kind = {bool: 'true or false', int: 'an integer', float: 'a number', str: 'a string',
            list: 'a list'}.get(type(default), 'a value of the declared type')
    parts = [kind]
    if d is not None:
        for r in d.floating_point_range:
            parts.append(f'in [{r.from_value:g}, {r.to_value:g}]')
        for r in d.integer_range:
            parts.append(f'in [{r.from_value}, {r.to_value}]')
        if d.additional_constraints:
            parts.append(f'({d.additional_constraints})')
    return ' '.join(parts)


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
    """Declare ``failed_thrusters`` (thruster numbers 1..4, run-time changeable) and
    return the core indices (0..3). Validated by
    :func:`tiltrov_ros.core.validation.failed_thruster_indices`."""
    d = descriptor('thrusters that give no thrust, by number: 1..4 = thruster_1..thruster_4 '
                   '(e.g. [2]); [] none; settable at run time',
                   constraints='distinct integers 1..4')
    d.dynamic_typing = True     # [] has no element type
    value = node.declare_parameter('failed_thrusters', [], d).value
    return validation.failed_thruster_indices(value)


def declare_robot(node: Node) -> tuple[RobotParams, float]:
    """Declare ``robot.*`` and ``control_period`` (the shared robot.yaml) and return them.

    Defaults are the shipped ``config/robot.yaml``, so a node started without a
    parameter file runs the shipped robot. All read-only: the geometry and the
    control period of a running stack do not change. Validated by the core
    (:class:`~tiltrov_ros.core.params.RobotParams`); an invalid value raises
    :class:`~tiltrov_ros.core.errors.ParameterError` naming it.
    """
    shipped = load_robot_params().as_dict()
    values: dict[str, Any] = {}
    for name, (text, rng) in _ROBOT_DOC.items():
        default = shipped[name]
        if isinstance(default, list):
            default = [float(v) for v in default]
        else:
            default = float(default)
        param = node.declare_parameter(f'robot.{name}', default,
                                       descriptor(text, read_only=True, floating=rng))
        values[name] = list(param.value) if isinstance(default, list) else param.value
    period = node.declare_parameter(
        'control_period', load_control_period(),
        descriptor('control period T of the stack, s (a multiple of the plant step); '
                   'control ticks are the sim times that are multiples of T',
                   read_only=True, floating=(0.0, 60.0))).value
    robot = RobotParams.from_mapping(values)
    if not period > 0:
        raise ParameterError('control_period', f'got {period!r}; allowed: a number of '
                             'seconds > 0')
    return robot, float(period)


Overrides = Mapping[str, Any] | Sequence[Parameter] | None


def as_parameters(overrides: Overrides) -> list[Parameter]:
    """Parameter overrides from a mapping (name -> value) or a list of Parameters."""
    if overrides is None:
        return []
    if isinstance(overrides, Mapping):
        return [Parameter(name, value=value) for name, value in overrides.items()]
    return list(overrides)
