"""The robot's parameters: one frozen, validated dataclass, loaded from ``config/robot.yaml``.

Values come from the paper's Appendix A (M of (A.2), the quadratic damping of
(A.4)); everything the paper does not give (geometry, weight and buoyancy,
centres of gravity and buoyancy, actuator limits) is an engineering estimate,
marked ``[estimate]`` with its reasoning in the YAML file and in
``robot-parameters.md``.

Every construction validates (``__post_init__``), so ``dataclasses.replace`` on a
valid instance cannot produce an invalid one. A bad value raises
:class:`~tiltrov_ros.core.errors.ParameterError` naming the parameter
(``robot.<field>``, as the ROS parameter is called), the value, the allowed
range and the source file when there is one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
import math
from numbers import Real
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
import yaml

from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.paths import config_file

FloatArray = NDArray[np.float64]

#: Prefix of the robot parameters in the ROS parameter tree and in error messages.
PREFIX = 'robot'
#: Name of the shipped robot file in ``config/``.
ROBOT_YAML = 'robot.yaml'

_INF = math.inf


@dataclass(frozen=True)
class _Rule:
    """Allowed values of one parameter: ``size`` numbers (0: a scalar) in a range."""

    size: int
    low: float = -_INF
    high: float = _INF
    low_open: bool = False
    high_open: bool = False
    note: str = ''

    def range_text(self) -> str:
        lo = '(' if self.low_open or self.low == -_INF else '['
        hi = ')' if self.high_open or self.high == _INF else ']'
        text = f'{lo}{self.low:g}, {self.high:g}{hi}'
        what = f'{self.size} finite numbers, each in {text}' if self.size else \
            f'a finite number in {text}'
        return f'{what}{self.note}'

    def accepts(self, x: float) -> bool:
        if not math.isfinite(x):
            return False
        low_ok = x > self.low if self.low_open else x >= self.low
        high_ok = x < self.high if self.high_open else x <= self.high
        return low_ok and high_ok


_RULES: dict[str, _Rule] = {
    'mass_matrix': _Rule(6, 0.0, low_open=True,
                         note=' (the diagonal of M, which must be positive definite)'),
    'quadratic_damping': _Rule(6, 0.0),
    'linear_damping': _Rule(6, 0.0),
    'weight': _Rule(0, 0.0, low_open=True),
    'buoyancy': _Rule(0, 0.0),
    'center_of_gravity': _Rule(3),
    'center_of_buoyancy': _Rule(3),
    'length': _Rule(0, 0.0, low_open=True),
    'width': _Rule(0, 0.0, low_open=True),
    'max_thrust': _Rule(0, 0.0, low_open=True),
    'thruster_time_constant': _Rule(0, 0.0, note=' (0: the thrust follows the command at once)'),
    'tilt_min': _Rule(0, -math.pi, math.pi),
    'tilt_max': _Rule(0, -math.pi, math.pi),
    'tilt_rate_limit': _Rule(0, 0.0, low_open=True),
}


def _is_number(x: object) -> bool:
    return isinstance(x, Real) and not isinstance(x, bool)


def _check(name: str, value: object, rule: _Rule, source: str | None) -> float | tuple[float, ...]:
    """Return ``value`` as a float (or tuple of floats) if ``rule`` allows it, else raise."""
    full = f'{PREFIX}.{name}'

    def fail() -> ParameterError:
        shown = value.tolist() if isinstance(value, np.ndarray) else value
        return ParameterError(full, f'got {shown!r}; allowed: {rule.range_text()}',
                              source=source)

    if rule.size == 0:
        if not _is_number(value):
            raise fail()
        x = float(value)  # type: ignore[arg-type]
        if not rule.accepts(x):
            raise fail()
        return x
    if isinstance(value, str | bytes | Mapping) or not hasattr(value, '__len__'):
        raise fail()
    items = list(value)  # type: ignore[call-overload]
    if len(items) != rule.size or not all(_is_number(v) for v in items):
        raise fail()
    out = tuple(float(v) for v in items)
    if not all(rule.accepts(v) for v in out):
        raise fail()
    return out


@dataclass(frozen=True)
class RobotParams:
    """The robot: rigid body, hydrodynamics, geometry and actuator limits (SI units, rad).

    Parameters
    ----------
    mass_matrix : tuple of 6 float
        Diagonal of M = M_RB + M_A, eq. (A.2): kg for surge, sway, heave;
        kg m^2 for roll, pitch, yaw. Each > 0 (M positive definite).
    quadratic_damping : tuple of 6 float
        d_i of D(nu) = diag(d_i |nu_i|), eq. (A.4): N s^2/m^2 and N m s^2. Each >= 0.
    linear_damping : tuple of 6 float
        Linear damping added to (A.4) (the paper has none): N s/m and N m s. Each >= 0.
    weight : float
        W = m g, N, > 0.
    buoyancy : float
        B, N, >= 0.
    center_of_gravity : tuple of 3 float
        r_g in the body frame (FRD), m.
    center_of_buoyancy : tuple of 3 float
        r_b in the body frame (FRD), m.
    length, width : float
        l and d of eq. (4), the thruster spacing along x and y, m, > 0.
    max_thrust : float
        Thrust limit of each thruster in both directions, N, > 0.
    thruster_time_constant : float
        First-order thruster response time constant, s, >= 0 (0: ideal).
    tilt_min, tilt_max : float
        Servo angle limits, rad, in [-pi, pi] with tilt_min < tilt_max.
    tilt_rate_limit : float
        Servo rate limit, rad/s, > 0.
    source : str or None
        File the values came from (for error messages only; not compared).
    """

    mass_matrix: tuple[float, ...]
    quadratic_damping: tuple[float, ...]
    linear_damping: tuple[float, ...]
    weight: float
    buoyancy: float
    center_of_gravity: tuple[float, ...]
    center_of_buoyancy: tuple[float, ...]
    length: float
    width: float
    max_thrust: float
    thruster_time_constant: float
    tilt_min: float
    tilt_max: float
    tilt_rate_limit: float
    source: str | None = field(default=None, compare=False, repr=False)

    def __post_init__(self) -> None:
        for name, rule in _RULES.items():
            object.__setattr__(self, name, _check(name, getattr(self, name), rule, self.source))
        if not self.tilt_min < self.tilt_max:
            raise ParameterError(
                f'{PREFIX}.tilt_min', f'got {self.tilt_min!r} with tilt_max = {self.tilt_max!r}; '
                'allowed: tilt_min < tilt_max', source=self.source)

    # -- derived quantities (numpy copies; the dataclass itself stays immutable) --

    @property
    def M(self) -> FloatArray:
        """The 6x6 mass matrix M of (A.2) (rigid body plus added mass)."""
        return np.diag(self.mass_matrix)

    @property
    def r_g(self) -> FloatArray:
        """Center of gravity in the body frame, m, shape (3,)."""
        return np.array(self.center_of_gravity)

    @property
    def r_b(self) -> FloatArray:
        """Center of buoyancy in the body frame, m, shape (3,)."""
        return np.array(self.center_of_buoyancy)

    def as_dict(self) -> dict[str, Any]:
        """The parameters as a JSON-serialisable dict (YAML keys, lists for vectors)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            if f.name == 'source':
                continue
            value = getattr(self, f.name)
            out[f.name] = list(value) if isinstance(value, tuple) else value
        return out

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *, source: str | None = None) -> RobotParams:
        """Build from a mapping of YAML keys (the ``robot:`` block) to values.

        Unknown and missing keys raise :class:`ParameterError` (a typo must not
        silently fall back to something else). ``linear_damping`` may be omitted
        (zero).
        """
        known = [f.name for f in fields(cls) if f.name != 'source']
        for key in values:
            if key not in known:
                raise ParameterError(f'{PREFIX}.{key}', f'unknown parameter; known: {known}',
                                     source=source)
        kwargs = dict(values)
        kwargs.setdefault('linear_damping', (0.0,) * 6)
        for key in known:
            if key not in kwargs:
                raise ParameterError(f'{PREFIX}.{key}',
                                     f'missing; allowed: {_RULES[key].range_text()}',
                                     source=source)
        return cls(**kwargs, source=source)


def load_robot_params(path: str | Path | None = None) -> RobotParams:
    """Load :class:`RobotParams` from a ROS 2 parameter file (default: the shipped one).

    The file has the form ``<node or /**>: ros__parameters: robot: {...}``; the
    first section holding a ``robot`` block is used.

    Raises
    ------
    ParameterError
        If the file has no ``robot`` block or a value is invalid (the message
        names the file).
    """
    if path is None:
        path = config_file(ROBOT_YAML)
    path = Path(path)
    source = str(path)
    with path.open(encoding='utf-8') as stream:
        document = yaml.safe_load(stream)
    if isinstance(document, Mapping):
        for section in document.values():
            ros_params = section.get('ros__parameters') if isinstance(section, Mapping) else None
            if isinstance(ros_params, Mapping) and isinstance(ros_params.get(PREFIX), Mapping):
                return RobotParams.from_mapping(ros_params[PREFIX], source=source)
    raise ParameterError(PREFIX, 'no <node>: ros__parameters: robot: block found',
                         source=source)


#: The paper's control cycle (Section 4), s; the default of ``control_period``.
DEFAULT_CONTROL_PERIOD = 0.05


def load_control_period(path: str | Path | None = None) -> float:
    """The stack's ``control_period`` (s) from the shared robot file (default: shipped).

    It sits next to the ``robot`` block in ``/**: ros__parameters:``, so every
    node reads the same value; absent, it is the paper's 50 ms.
    """
    if path is None:
        path = config_file(ROBOT_YAML)
    source = str(path)
    with Path(path).open(encoding='utf-8') as stream:
        document = yaml.safe_load(stream)
    value: Any = DEFAULT_CONTROL_PERIOD
    if isinstance(document, Mapping):
        for section in document.values():
            ros_params = section.get('ros__parameters') if isinstance(section, Mapping) else None
            if isinstance(ros_params, Mapping) and 'control_period' in ros_params:
                value = ros_params['control_period']
                break
    if (isinstance(value, bool) or not isinstance(value, (int, float))
            or not math.isfinite(value) or value <= 0):
        raise ParameterError('control_period', f'got {value!r}; allowed: a number of '
                             'seconds > 0', source=source)
    return float(value)
