"""The robot's parameters: one frozen, validated dataclass, loaded from ``config/robot.yaml``.

Values come from the paper's Appendix A (M of (A.2), the quadratic damping of
(A.4)); everything the paper does not give (geometry, weight and buoyancy,
centres of gravity and buoyancy, actuator limits) is an engineering estimate,
marked ``[estimate]`` with its reasoning in the YAML file. The parameters are
declared once, in :data:`ROBOT` (and ``control_period`` in :data:`STACK`).

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
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.paramtable import SHIPPED, Param, ParamTable, ros_parameters
from tiltrov_ros.paths import config_file

FloatArray = NDArray[np.float64]

#: Prefix of the robot parameters in the ROS parameter tree and in error messages.
PREFIX = 'robot'
#: Name of the shipped robot file in ``config/``.
ROBOT_YAML = 'robot.yaml'

_PI = math.pi

#: ``robot.*``: every value from the shipped ``config/robot.yaml`` (read-only in the nodes).
ROBOT = ParamTable('robot', [
    Param('mass_matrix', 'floats', SHIPPED, 'diagonal of M (A.2), rigid body plus added mass',
          'kg (surge, sway, heave), kg m^2 (roll, pitch, yaw)', size=6, low=0.0,
          low_open=True, read_only=True, note=' (M must be positive definite)'),
    Param('quadratic_damping', 'floats', SHIPPED,
          'quadratic damping d_i of (A.4), D(nu) = diag(d_i abs(nu_i))',
          'N s^2/m^2, N m s^2', size=6, low=0.0, read_only=True),
    Param('linear_damping', 'floats', SHIPPED,
          'linear damping added to (A.4) (the paper has none; may be left out: zero)',
          'N s/m, N m s', size=6, low=0.0, read_only=True),
    Param('weight', 'float', SHIPPED, 'W = m g', 'N', low=0.1, high=1e6, read_only=True),
    Param('buoyancy', 'float', SHIPPED, 'B', 'N', low=0.0, high=1e6, read_only=True),
    Param('center_of_gravity', 'floats', SHIPPED, 'nominal r_g in base_link_frd '
          '(the plant adds its com_error)', 'm', size=3, read_only=True),
    Param('center_of_buoyancy', 'floats', SHIPPED, 'r_b in base_link_frd', 'm', size=3,
          read_only=True),
    Param('length', 'float', SHIPPED, 'l of eq. (4), thruster spacing along x', 'm',
          low=0.01, high=100.0, read_only=True),
    Param('width', 'float', SHIPPED, 'd of eq. (4), thruster spacing along y', 'm', low=0.01,
          high=100.0, read_only=True),
    Param('max_thrust', 'float', SHIPPED, 'thrust limit of each thruster in both directions',
          'N', low=0.01, high=1e5, read_only=True),
    Param('thruster_time_constant', 'float', SHIPPED,
          'first-order thruster time constant (0: the thrust follows the command at once)',
          's', low=0.0, high=100.0, read_only=True),
    Param('tilt_min', 'float', SHIPPED, 'lower servo angle limit (below tilt_max)', 'rad',
          low=-_PI, high=_PI, read_only=True),
    Param('tilt_max', 'float', SHIPPED, 'upper servo angle limit', 'rad', low=-_PI, high=_PI,
          read_only=True),
    Param('tilt_rate_limit', 'float', SHIPPED, 'servo rate limit', 'rad/s', low=0.01,
          high=1000.0, read_only=True),
], prefix=PREFIX)

#: The paper's control cycle (Section 4), s; ``control_period`` when a file has none.
DEFAULT_CONTROL_PERIOD = 0.05

#: ``control_period``, next to ``robot`` in ``config/robot.yaml`` (``/**``).
STACK = ParamTable('control period', [
    Param('control_period', 'float', SHIPPED, 'control period T of the stack (a multiple of '
          'the plant step); control ticks are the sim times that are multiples of T', 's',
          low=0.001, high=60.0, read_only=True),
])


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
        for param in ROBOT:
            object.__setattr__(self, param.name, ROBOT.check(
                param.name, getattr(self, param.name), source=self.source))
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
        checked = ROBOT.complete(values, source=source,
                                 defaults={'linear_damping': (0.0,) * 6})
        return cls(**checked, source=source)


def robot_file(name: str | Path) -> Path:
    """A robot parameter file by path, or by the name of a shipped one
    (``robot_past_vertical`` for ``config/robot_past_vertical.yaml``).

    Raises
    ------
    ParameterError
        If it names neither an existing file nor a shipped one.
    """
    path = Path(name)
    if path.is_file():
        return path
    if not path.suffix and len(path.parts) == 1:
        try:
            return config_file(f'{name}.yaml')
        except FileNotFoundError:
            pass
    raise ParameterError('robot', f'got {str(name)!r}; allowed: a robot parameter file, or '
                         'the name of a shipped one (robot, robot_past_vertical)')


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
    path = config_file(ROBOT_YAML) if path is None else Path(path)
    source = str(path)
    params = ros_parameters(path, having=PREFIX)
    if params is None or not isinstance(params[PREFIX], Mapping):
        raise ParameterError(PREFIX, 'no <node>: ros__parameters: robot: block found',
                             source=source)
    return RobotParams.from_mapping(params[PREFIX], source=source)


def load_control_period(path: str | Path | None = None) -> float:
    """The stack's ``control_period`` (s) from the shared robot file (default: shipped).

    It sits next to the ``robot`` block in ``/**: ros__parameters:``, so every
    node reads the same value; absent, it is the paper's 50 ms.
    """
    path = config_file(ROBOT_YAML) if path is None else Path(path)
    params = ros_parameters(path, having='control_period')
    value = params['control_period'] if params is not None else DEFAULT_CONTROL_PERIOD
    return float(STACK.check('control_period', value, source=str(path)))
