"""The wrench controller's parameters (a base of
:class:`~tiltrov_ros.nodes.wrench_controller.WrenchController`): its own table
(:data:`CONTROLLER_PARAMS`), the control law's (``controller``, ``gains.*``,
``switching.*``), the stamp bounds and the robot, declared once, validated by the core's
``ControllerConfig.from_mapping``, applied at run time where they may change."""

from __future__ import annotations

from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter

from tiltrov_ros.core.controllers import (
    CONTROL_LAW,
    GAINS,
    SWITCHING,
    ControllerConfig,
    load_controller_config,
    retune,
)
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.frames import CONVENTIONS
from tiltrov_ros.core.names import (
    FRAME_BODY,
    FRAME_BODY_FLU,
    FRAME_EARTH,
    FRAME_EARTH_ENU,
    MODES,
    REALTIME,
)
from tiltrov_ros.core.paramtable import Param, ParamTable

from .parameters import check, declare, declare_robot

if TYPE_CHECKING:
    from .wrench_controller import WrenchController


#: The controller node's own parameters (besides the controller's: controller, gains.*,
#: switching.*; and the stamp bounds and the robot).
CONTROLLER_PARAMS = ParamTable('wrench_controller', [
    Param('mode', 'str', REALTIME, 'lockstep: wait for the setpoint stamped with each tick '
          '(deterministic); realtime: use the latest setpoint', choices=MODES, read_only=True),
    Param('use_setpoint_velocity', 'bool', True, 'use setpoint_velocity as the feed-forward '
          'd(eta_d)/dt (false: zero)', read_only=True),
    Param('input_timeout', 'float', 1.0, 'lockstep: wall seconds a tick waits for an input '
          'before the wait is reported (log, /diagnostics); it changes nothing else', 's',
          low=0.001, high=3600.0),
    Param('odom_frame_convention', 'str', 'ned', "odom in NED/FRD (odom_ned, base_link_frd: "
          "the plant's) or ENU/FLU (odom, base_link: REP-103/105, e.g. robot_localization), "
          'converted to NED/FRD on arrival', choices=CONVENTIONS, read_only=True),
    Param('odom_timeout', 'float', 0.5, 'realtime: a zero wrench is published (every control '
          'period) while the newest valid odom is older than this; on sim time measured on '
          '/clock, else wall time since the message arrived; 0: off', 's', low=0.0,
          high=3600.0),
])


def _config_mapping(get: Any) -> dict[str, Any]:
    """The ``wrench_controller`` parameters as ControllerConfig.from_mapping wants them."""
    return {
        'controller': get('controller'),
        'gains': {key: value if isinstance(value, float) else list(value)  # arrays: lists
                  for key in GAINS.names for value in [get(GAINS.full_name(key))]},
        'switching': {key: get(SWITCHING.full_name(key)) for key in SWITCHING.names},
    }


class ControllerParameters:
    """The controller's parameters (see the module docstring)."""

    def _declare_parameters(self: WrenchController) -> None:
        shipped = load_controller_config()
        declare(self, CONTROL_LAW, defaults={'controller': shipped.kind})
        own = declare(self, CONTROLLER_PARAMS)
        self.declare_stamp_bounds()
        declare(self, GAINS, defaults=asdict(shipped.gains))
        declare(self, SWITCHING, defaults=asdict(shipped.switching))
        self.robot, self.control_period = declare_robot(self)
        self.check_overrides()
        own = check(CONTROLLER_PARAMS, own)
        self.mode = own['mode']
        self.use_velocity = own['use_setpoint_velocity']
        self.input_timeout = own['input_timeout']
        self.odom_timeout = own['odom_timeout']
        self.enu = own['odom_frame_convention'] == 'enu'
        self.odom_frames = ((FRAME_EARTH_ENU, FRAME_BODY_FLU) if self.enu
                            else (FRAME_EARTH, FRAME_BODY))
        self.controller_config = ControllerConfig.from_mapping(
            _config_mapping(lambda name: self.get_parameter(name).value))

    def _validate_parameters(self: WrenchController,
                             parameters: list[Parameter]) -> SetParametersResult:
        """Check gains.* and switching.* changes with the core's validation."""
        changes = {p.name: p.value for p in parameters
                   if p.name.startswith(('gains.', 'switching.'))}
        if not changes:
            return SetParametersResult(successful=True)

        def get(name: str) -> Any:
            return changes[name] if name in changes else self.get_parameter(name).value

        try:
            ControllerConfig.from_mapping(_config_mapping(get))
        except ParameterError as exc:
            return self.reject(str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self: WrenchController, parameters: list[Parameter]) -> None:
        for p in parameters:
            if p.name == 'odom_timeout':
                self.odom_timeout = float(p.value)
            elif p.name == 'input_timeout':
                self.input_timeout = float(p.value)
        if not any(p.name.startswith(('gains.', 'switching.')) for p in parameters):
            return
        self.controller_config = ControllerConfig.from_mapping(
            _config_mapping(lambda name: self.get_parameter(name).value))
        self.controller = retune(self.controller, self.controller_config, self.robot)
        self.get_logger().info('gains changed: ' + ', '.join(
            f'{p.name} = {p.value!s}' for p in parameters))
