"""The ``plant_simulator`` node's parameters (:data:`PLANT_PARAMS`) and the configuration
built from them (:class:`PlantConfig`): one line per parameter, validated once."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from tiltrov_ros.core.disturbances import Disturbances
from tiltrov_ros.core.errors import ParameterError
from tiltrov_ros.core.kinematics import quat_from_euler
from tiltrov_ros.core.names import MODES, REALTIME
from tiltrov_ros.core.params import RobotParams
from tiltrov_ros.core.paramtable import Param, ParamTable
from tiltrov_ros.core.plant import Plant
from tiltrov_ros.core.scenarios import InitialState, Scenario, ThrusterFault, load_scenario
from tiltrov_ros.core.timebase import seconds, to_ns
from tiltrov_ros.core.visual import Scales

from .parameters import check, declare, declare_failed_thrusters, declare_robot
from .qos import paced_window_limit_ns

if TYPE_CHECKING:
    from .base import TiltrovNode

#: The plant's own parameters (besides failed_thrusters, the stamp bounds and the robot).
PLANT_PARAMS = ParamTable('plant_simulator', [
    Param('mode', 'str', REALTIME, 'lockstep: as fast as possible, deterministic, waits at each '
          'control tick for the thrust_cmd and tilt_cmd stamped with it; realtime: wall-clock '
          'stepping', choices=MODES, read_only=True),
    Param('real_time_factor', 'float', 1.0, 'realtime mode: sim seconds per wall second '
          '(1.0 = wall clock)', '-', low=0.001, high=1000.0),
    Param('step_size', 'float', 0.01, 'plant step h (RK4); the control period must be a '
          'multiple of it', 's', low=1e-5, high=1.0, read_only=True),
    Param('scenario', 'str', '', 'scenario name (config/scenarios/<name>.yaml) or path: '
          'initial state, disturbances and robot overrides; empty: at rest at the origin, no '
          'disturbance', read_only=True),
    Param('com_error', 'floats', (0.0, 0.0, 0.0), "true center of gravity minus the nominal "
          "one, in base_link_frd (the paper's disturbance); default: the scenario's (zero "
          "without one)", 'm', size=3, read_only=True),
    Param('current', 'floats', (0.0, 0.0, 0.0), "mean ocean current in odom_ned; default: the "
          "scenario's (zero without one)", 'm/s', size=3, read_only=True),
    Param('duration', 'float', 0.0, 'sim time at which the run ends (a whole number of '
          'steps); 0: never', 's', low=0.0, high=1e9, read_only=True),
    Param('exit_at_end', 'bool', False, 'exit the process (code 0) when duration is reached, '
          'once every reader acknowledged the last messages', read_only=True),
    Param('stall_timeout', 'float', 1.0, 'lockstep: wall seconds without the commands of a '
          'tick before the wait is reported as a stall (log, /diagnostics); it changes '
          'nothing else', 's', low=0.01, high=3600.0),
    Param('startup_subscribers', 'int', 1, 'odom readers to wait for (on the plant\'s side) '
          'before publishing the initial state (realtime: before time starts), besides the '
          'run\'s handshake; 0: none', low=0, high=1000, read_only=True),
    Param('recorder_window', 'float', 1.0, 'lockstep with the bag recorder among run_nodes: '
          'the plant steps past a control tick only while it is at most this far ahead of '
          'what the recorder has written of /clock and the tick topics (0: every tick waits '
          'until its commands are written); at most what the writers keep (49.85 s with the '
          'default step, control and markers periods)', 's', low=0.0, high=3600.0,
          read_only=True),
    Param('command_timeout', 'float', 0.5, 'realtime: sim seconds without a thrust_cmd after '
          'which the thrusters are commanded to zero (tilts held) until commands return; '
          '0: off', 's', low=0.0, high=3600.0),
    Param('respawn_hold', 'float', 0.0, 'realtime, with a respawn configured (the launchers '
          'set it): thrust_cmd older than command_timeout is held, not zeroed, until it is '
          'this old (a respawned allocator takes over meanwhile); 0: zero thrust at '
          'command_timeout', 's', low=0.0, high=60.0, read_only=True),
    Param('markers_period', 'float', 0.1, 'sim time between two robot_markers (at the steps '
          'that are multiples of it, a whole number of steps); 0: none', 's', low=0.0,
          high=60.0, read_only=True),
    Param('marker_scales', 'floats', (Scales.thrust, Scales.force, Scales.moment),
          'robot_markers arrow lengths: per newton of thrust, per newton of force, per '
          'newton metre of moment', 'm/N, m/N, m/(N m)', size=3, low=0.0, high=10.0,
          read_only=True),
    Param('tf', 'bool', True, 'publish the transform tree (REP-105): odom -> base_link on /tf '
          "at every step with the odometry's stamp, odom -> odom_ned and base_link -> "
          'base_link_frd on /tf_static (transient local)', read_only=True),
    Param('tf_thrusters', 'bool', True, 'with tf: also the thruster links (base_link_frd -> '
          'thruster_i_link at the actual tilts) on /tf and the URDF on robot_description, '
          "robot_state_publisher's work where it does not run", read_only=True),
])
#: Parameters whose defaults are the scenario's (declared once the scenario is known).
_FROM_SCENARIO = ('com_error', 'current')


@dataclass(frozen=True)
class PlantConfig:
    """The plant node's parameters, validated."""

    mode: str
    real_time_factor: float
    step_ns: int
    control_period_ns: int
    robot: RobotParams               # nominal robot, scenario overrides applied
    disturbances: Disturbances
    initial_state: InitialState
    scenario: str                    # name, path or '' (none)
    duration_ns: int                 # 0: no end
    exit_at_end: bool
    stall_timeout: float             # s, wall
    startup_subscribers: int
    recorder_window_ns: int          # sim ns; pacing when the recorder is a run node
    command_timeout: float = 0.5     # s, sim time; 0: off
    respawn_hold: float = 0.0        # s, sim time: command_timeout while a respawn may hold
    markers_period_ns: int = 0                      # robot_markers; 0: none
    marker_scales: Scales = field(default_factory=Scales)
    tf: bool = True                                 # /tf and /tf_static
    tf_thrusters: bool = True                       # the thruster links, robot_description
    failed_thrusters: tuple[int, ...] = ()          # indices 0..3 (parameter)
    faults: tuple[ThrusterFault, ...] = ()          # the scenario's

    def build_plant(self) -> Plant:
        """The plant at the initial state, as ``StackConfig.build_plant`` makes it."""
        init = self.initial_state
        return Plant(self.robot, self.disturbances, step_ns=self.step_ns,
                     position=init.position, quaternion=quat_from_euler(*init.euler),
                     nu=init.nu)


def declare_parameters(node: TiltrovNode) -> PlantConfig:
    """Declare the plant's parameters on ``node`` and return them validated."""
    first = [name for name in PLANT_PARAMS.names if name not in _FROM_SCENARIO]
    declared = declare(node, PLANT_PARAMS, only=first)
    scenario_name = check(PLANT_PARAMS, {'scenario': declared['scenario']})['scenario']
    scenario: Scenario | None = load_scenario(scenario_name) if scenario_name else None
    disturbances = scenario.disturbances if scenario is not None else Disturbances()
    declared.update(declare(node, PLANT_PARAMS, only=_FROM_SCENARIO, defaults={
        'com_error': disturbances.com_error, 'current': disturbances.current}))
    failed = declare_failed_thrusters(node)
    node.declare_stamp_bounds()
    robot, period = declare_robot(node)
    node.check_overrides()

    v = check(PLANT_PARAMS, declared)
    disturbances = replace(disturbances, com_error=v['com_error'], current=v['current'])
    step_ns = to_ns(v['step_size'])
    period_ns = to_ns(period)
    if period_ns % step_ns:
        raise ParameterError('control_period', f'got {period!r} s; allowed: a whole '
                             f'multiple of step_size ({v["step_size"]!r} s)')
    duration_ns = to_ns(v['duration'])
    markers_ns = to_ns(v['markers_period'])
    for name, ns in (('duration', duration_ns), ('markers_period', markers_ns)):
        if ns % step_ns:
            raise ParameterError(name, f'got {v[name]!r} s; allowed: 0 or a whole number of '
                                 f'steps ({v["step_size"]!r} s)')
    window_ns = to_ns(v['recorder_window'])
    window_limit = paced_window_limit_ns(step_ns, period_ns, markers_ns)
    if window_ns > window_limit:
        raise ParameterError('recorder_window', f'got {v["recorder_window"]!r} s; allowed: at '
                             f'most {seconds(window_limit):g} s with step_size '
                             f'{v["step_size"]!r} s, control_period {period!r} s and '
                             f'markers_period {v["markers_period"]!r} s (what the writers '
                             f'keep for a recorder that far behind)')
    return PlantConfig(
        mode=v['mode'], real_time_factor=v['real_time_factor'], step_ns=step_ns,
        control_period_ns=period_ns,
        robot=scenario.robot(robot) if scenario is not None else robot,
        disturbances=disturbances,
        initial_state=scenario.initial_state if scenario is not None else InitialState(),
        scenario=v['scenario'], duration_ns=duration_ns, exit_at_end=v['exit_at_end'],
        stall_timeout=v['stall_timeout'], startup_subscribers=v['startup_subscribers'],
        recorder_window_ns=window_ns, command_timeout=v['command_timeout'],
        respawn_hold=v['respawn_hold'],
        markers_period_ns=markers_ns, marker_scales=Scales(*v['marker_scales']),
        tf=v['tf'], tf_thrusters=v['tf_thrusters'],
        failed_thrusters=failed, faults=scenario.faults if scenario is not None else ())
