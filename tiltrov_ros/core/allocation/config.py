"""The ``thrust_allocator`` parameters: validated once, read from YAML, built into an allocator."""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tiltrov_ros.core.allocation.allocator import (
    DEFAULT_WEIGHTS,
    FAILED_WEIGHTS,
    Mode,
    ThrustAllocator,
)
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.names import ALLOCATOR_MODES
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.paramtable import SHIPPED, Param, ParamTable
from tiltrov_ros.core.yamlfile import read_yaml
from tiltrov_ros.paths import config_file

ALLOCATOR_YAML = 'thrust_allocator.yaml'

#: The allocator's parameters (the ``thrust_allocator`` section that ``tiltrov sim``
#: reads and the node declares; defaults: the shipped file's): validated by
#: :meth:`AllocatorConfig.from_mapping`, declared and documented from here.
ALLOCATION = ParamTable('allocation', [
    Param('mode', 'str', SHIPPED, 'robust: exact when attainable, else least weighted wrench '
          'error; paper: Section 3 of the paper', choices=ALLOCATOR_MODES),
    Param('max_tilt_step', 'float', SHIPPED, 'how far each tilt may move per control period; '
          '<= 0: the servo reach (tilt_rate_limit x control_period)', 'rad', low=-1e6,
          high=1e6),
    Param('weights', 'floats', SHIPPED, 'robust mode: weights of the wrench error', 'per '
          'component X Y Z K M N', size=6, low=0.0, low_open=True),
    Param('weights_failed', 'floats', SHIPPED, 'robust mode: weights of the wrench error '
          'while a thruster has failed (three cannot hold every DOF: the small weights give '
          'way)', 'per component X Y Z K M N', size=6, low=0.0, low_open=True),
])


@dataclass(frozen=True)
class AllocatorConfig:
    """The ``thrust_allocator`` parameters (``config/thrust_allocator.yaml``).

    mode : ``'robust'`` or ``'paper'``
    max_tilt_step : rad per control period; <= 0 means the servo's reach,
        ``tilt_rate_limit * control_period``
    weights : per-DOF weights (X, Y, Z, K, M, N) of the wrench error
    weights_failed : the weights while a thruster has failed
    """

    mode: Mode = 'robust'
    max_tilt_step: float = -1.0
    weights: tuple[float, ...] = DEFAULT_WEIGHTS
    weights_failed: tuple[float, ...] = FAILED_WEIGHTS

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *,
                     source: str | None = None) -> AllocatorConfig:
        """From the ``ros__parameters`` of ``thrust_allocator`` (other keys ignored)."""
        # Any sequence of weights: a list from YAML, array('d') from the ROS parameter
        # service. Keys of other tables (the node's) are ignored.
        checked = ALLOCATION.complete(values, source=source, unknown=True,
                                      defaults={'mode': 'robust', 'max_tilt_step': -1.0,
                                                'weights': DEFAULT_WEIGHTS,
                                                'weights_failed': FAILED_WEIGHTS})
        return cls(checked['mode'], checked['max_tilt_step'], tuple(checked['weights']),
                   tuple(checked['weights_failed']))

    def tilt_step(self, robot: RobotParams, control_period: float) -> float:
        """max_tilt_step in rad, ``auto`` (<= 0) resolved from the servo rate."""
        if self.max_tilt_step > 0:
            return self.max_tilt_step
        return robot.tilt_rate_limit * control_period

    def build(self, robot: RobotParams, control_period: float,
              failed_thrusters: Collection[int] = ()) -> ThrustAllocator:
        """The allocator for ``robot`` (geometry, thrust limit, tilt range and reach),
        with ``weights_failed`` when ``failed_thrusters`` is not empty."""
        return ThrustAllocator(robot.length, robot.width, robot.max_thrust,
                               (robot.tilt_min, robot.tilt_max),
                               self.tilt_step(robot, control_period), self.mode,
                               self.weights_failed if failed_thrusters else self.weights,
                               failed_thrusters)


def load_allocator_config(path: str | Path | None = None) -> AllocatorConfig:
    """Read ``thrust_allocator: ros__parameters:`` from a YAML file (default: shipped)."""
    if path is None:
        path = config_file(ALLOCATOR_YAML)
    source = str(path)
    document = read_yaml(path)
    section = document.get('thrust_allocator') if isinstance(document, Mapping) else None
    params = section.get('ros__parameters') if isinstance(section, Mapping) else None
    if not isinstance(params, Mapping):
        raise ParameterError('thrust_allocator', 'no thrust_allocator: ros__parameters: '
                             'block found', source=source)
    return AllocatorConfig.from_mapping(params, source=source)
