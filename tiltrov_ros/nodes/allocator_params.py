"""The thrust allocator's parameters (a base of
:class:`~tiltrov_ros.nodes.thrust_allocator.ThrustAllocatorNode`): its own table
(:data:`ALLOCATOR_PARAMS`), the core allocator's (``ALLOCATION``), failed thrusters, the
stamp bounds and the robot, declared once, validated by the core's
``AllocatorConfig.from_mapping``, applied at run time where they may change."""

from __future__ import annotations

from dataclasses import asdict
from typing import TYPE_CHECKING

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter

from tiltrov_ros.core.allocation import (
    ALLOCATION,
    SHORTFALL_FRACTION,
    AllocatorConfig,
    load_allocator_config,
    shortfall_tolerances,
)
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.paramtable import Param, ParamTable
from tiltrov_ros.core.scenarios import ThrusterFault, load_scenario
from tiltrov_ros.core.steady import HoldMonitor
from tiltrov_ros.core.validation import failed_thruster_indices

from .parameters import check, declare, declare_failed_thrusters, declare_robot
from .tilt_request import TILT_REQUEST_MODES

if TYPE_CHECKING:
    from .thrust_allocator import ThrustAllocatorNode


#: Where an allocation starts from: the last commanded tilts, or the measured ones.
TILT_SOURCES = ('commanded', 'measured')

#: The node's own parameters (besides the allocator's, failed_thrusters, the stamp
#: bounds and the robot).
ALLOCATOR_PARAMS = ParamTable('thrust_allocator', [
    Param('tilt_request', 'str', 'auto', 'tilts fixed by the controller (switching baseline): '
          'required, ignored, or auto (paired once a request carries a wrench_cmd stamp, free '
          'again after a wrench waited input_timeout in vain)', choices=TILT_REQUEST_MODES,
          read_only=True),
    Param('input_timeout', 'float', 1.0, 'wall seconds a wrench waits for its tilt_request '
          'before the latest one is used (in a lockstep run: before the wait is reported; '
          'it waits on)', 's', low=0.001, high=3600.0),
    Param('wrench_timeout', 'float', 0.5, 'zero thrust (tilts held) is published every '
          'control period while the newest valid wrench_cmd is older than this; on sim time '
          'measured on /clock, else wall time since the message arrived; 0: off', 's',
          low=0.0, high=3600.0),
    Param('respawn_hold', 'float', 0.0, 'with a respawn configured (the launchers set it): a '
          'wrench_cmd older than wrench_timeout is held, not answered with zero thrust, '
          'until it is this old (a respawned controller takes over meanwhile); 0: zero '
          'thrust at wrench_timeout', 's', low=0.0, high=60.0, read_only=True),
    Param('tilt_source', 'str', 'commanded', 'tilts each allocation starts from (and moves '
          'at most max_tilt_step away from): commanded, the last answer; measured, the '
          'servos\' positions in joint_states (the one stamped with the wrench, else the '
          'latest before it)', choices=TILT_SOURCES, read_only=True),
    Param('wrench_tolerance', 'float', SHORTFALL_FRACTION, 'a wrench component missing by '
          'more than this fraction of max_thrust (forces; moments: times min(length, width) / '
          '2) counts as not achieved: logged, counted per component, WARN on /diagnostics',
          '-', low=0.0, high=1.0),
    Param('scenario', 'str', '', 'scenario name or path whose faults (thruster failures) the '
          'allocator is told of at their time + detected_after, by the wrench stamps; empty: '
          'none', read_only=True),
])


class AllocatorParameters:
    """The allocator's parameters (see the module docstring)."""

    def _declare_parameters(self: ThrustAllocatorNode) -> None:
        shipped = load_allocator_config()
        declare(self, ALLOCATION, defaults=asdict(shipped))
        own = declare(self, ALLOCATOR_PARAMS, only=('tilt_request', 'input_timeout',
                                                  'wrench_timeout', 'respawn_hold',
                                                  'wrench_tolerance',
                                                  'tilt_source'))
        self.failed_param = declare_failed_thrusters(self)
        own.update(declare(self, ALLOCATOR_PARAMS, only=('scenario',)))
        self.scenario_faults: tuple[ThrusterFault, ...] = (
            load_scenario(own['scenario']).faults if own['scenario'] else ())
        self.declare_stamp_bounds()
        self.robot, self.control_period = declare_robot(self)
        self.check_overrides()
        own = check(ALLOCATOR_PARAMS, own)
        self.tilt_request_mode = own['tilt_request']
        self.input_timeout = own['input_timeout']
        self.wrench_timeout = own['wrench_timeout']
        self.respawn_hold = own['respawn_hold']
        self.wrench_tolerance = own['wrench_tolerance']
        self.tolerances = shortfall_tolerances(self.robot, self.wrench_tolerance)
        self.measured_tilts = own['tilt_source'] == 'measured'
        self.allocator_config = AllocatorConfig.from_mapping(
            {key: self.get_parameter(key).value for key in ALLOCATION.names})

    def _validate_parameters(self: ThrustAllocatorNode,
                             parameters: list[Parameter]) -> SetParametersResult:
        verdict = self.check_failed_thrusters(parameters)
        if not verdict.successful:
            return verdict
        changes = {p.name: p.value for p in parameters if p.name in ALLOCATION.names}
        if not changes:
            return SetParametersResult(successful=True)
        values = {key: changes.get(key, self.get_parameter(key).value)
                  for key in ALLOCATION.names}
        try:
            AllocatorConfig.from_mapping(values)
        except ParameterError as exc:
            return self.reject(str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self: ThrustAllocatorNode, parameters: list[Parameter]) -> None:
        for p in parameters:
            if p.name == 'wrench_timeout':
                self.wrench_timeout = float(p.value)
            elif p.name == 'wrench_tolerance':
                self.wrench_tolerance = float(p.value)
                self.tolerances = shortfall_tolerances(self.robot, self.wrench_tolerance)
                self._new_hold_monitor()
            elif p.name == 'input_timeout':
                self.input_timeout = float(p.value)
            elif p.name == 'failed_thrusters':
                self.failed_param = failed_thruster_indices(p.value)
                self._use_failed(self._wanted_failed(self._last_ns if self._last_ns >= 0
                                                     else None), 'failed_thrusters set')
        if not any(p.name in ALLOCATION.names for p in parameters):
            return
        self.allocator_config = AllocatorConfig.from_mapping(
            {key: self.get_parameter(key).value for key in ALLOCATION.names})
        self.allocator = self.allocator_config.build(self.robot, self.control_period,
                                                     self.failed)
        self._new_hold_monitor()
        self.get_logger().info(f'allocator changed: {self.allocator_config}')

    def _new_hold_monitor(self: ThrustAllocatorNode) -> None:
        self.hold_monitor = HoldMonitor(self.robot, self.control_period,
                                        self.allocator_config.weights, self.wrench_tolerance)
