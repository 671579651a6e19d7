"""The ``thrust_allocator`` parameters: validated once, read from YAML, built into an allocator."""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any

from tiltrov_ros.core.allocation.allocator import DEFAULT_WEIGHTS, Mode, ThrustAllocator
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.yamlfile import read_yaml
from tiltrov_ros.paths import config_file

ALLOCATOR_YAML = 'thrust_allocator.yaml'


@dataclass(frozen=True)
class AllocatorConfig:
    """The ``thrust_allocator`` parameters (``config/thrust_allocator.yaml``).

    mode : ``'robust'`` or ``'paper'``
    max_tilt_step : rad per control period; <= 0 means the servo's reach,
        ``tilt_rate_limit * control_period``
    weights : per-DOF weights (X, Y, Z, K, M, N) of the wrench error
    """

    mode: Mode = 'robust'
    max_tilt_step: float = -1.0
    weights: tuple[float, ...] = DEFAULT_WEIGHTS

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any], *,
                     source: str | None = None) -> AllocatorConfig:
        """From the ``ros__parameters`` of ``thrust_allocator`` (other keys ignored)."""
        mode = values.get('mode', 'robust')
        if mode not in ('paper', 'robust'):
            raise ParameterError('mode', f"got {mode!r}; allowed: 'robust', 'paper'",
                                 source=source)
        step = values.get('max_tilt_step', -1.0)
        if isinstance(step, bool) or not isinstance(step, (int, float)) or math.isnan(step):
            raise ParameterError('max_tilt_step', f'got {step!r}; allowed: a number of rad '
                                 '(<= 0: the servo reach per control period)', source=source)
        weights = values.get('weights', DEFAULT_WEIGHTS)
        # Any sequence: a list from YAML, array('d') from the ROS parameter service.
        if (isinstance(weights, (str, bytes)) or not isinstance(weights, Sequence)
                or len(weights) != 6
                or not all(isinstance(w, (int, float)) and not isinstance(w, bool)
                           and math.isfinite(w) and w > 0 for w in weights)):
            shown = list(weights) if isinstance(weights, Sequence) else weights
            raise ParameterError('weights', f'got {shown!r}; allowed: 6 finite numbers > 0',
                                 source=source)
        return cls(mode, float(step), tuple(float(w) for w in weights))

    def tilt_step(self, robot: RobotParams, control_period: float) -> float:
        """max_tilt_step in rad, ``auto`` (<= 0) resolved from the servo rate."""
        if self.max_tilt_step > 0:
            return self.max_tilt_step
        return robot.tilt_rate_limit * control_period

    def build(self, robot: RobotParams, control_period: float,
              failed_thrusters: Collection[int] = ()) -> ThrustAllocator:
        """The allocator for ``robot`` (geometry, thrust limit, tilt range and reach)."""
        return ThrustAllocator(robot.length, robot.width, robot.max_thrust,
                               (robot.tilt_min, robot.tilt_max),
                               self.tilt_step(robot, control_period), self.mode,
                               self.weights, failed_thrusters)


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
