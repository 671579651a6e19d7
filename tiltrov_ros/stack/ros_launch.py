"""``ros2 launch tiltrov_ros tiltrov.launch.py``: the stack of ``tiltrov launch`` as
launch_ros ``Node`` actions, for a ROS 2 install.

The nodes, their parameter files and overrides are :func:`.specs.stack_specs`'
(the one place that knows the wiring), so in lockstep the run gives the
numbers of ``tiltrov launch`` and ``tiltrov sim``. Arguments::

    scenario:=pitch_hold  controller:=pd|switching|pid  allocator:=robust|paper
    robot:=robot_past_vertical|FILE  mode:=lockstep|realtime  real_time_factor:=1.0  duration:=SEC
    namespace:=NS  record:=DIR  markers:=true|false

Where robot_state_publisher is installed (a ROS install) it is started too,
with the URDF of the robot in use (:func:`~tiltrov_ros.core.robot_description.robot_urdf`:
the scenario's robot overrides applied) as ``robot_description``, and it
publishes the thruster links from ``joint_states`` instead of the plant
(``tf_thrusters: false``). In a namespace every node's ``/tf`` and ``/tf_static``
are remapped into it (:func:`.specs.remap_args`).

The run ends as ``tiltrov launch`` ends it: when the plant reaches
``duration`` it exits (code 0), the other nodes are stopped (SIGINT), then the
recorder, which closes its bag; then the launch ends with code 0. A node that
exits otherwise (an error, a crash) ends the launch with code 1 and a line
naming it. Ctrl-C stops every node cleanly (exit code 0 each); a node gets
13 s from SIGINT before SIGTERM, the recorder 20 s, as with ``tiltrov launch``.

Imported only by the launch file: ``launch`` and ``launch_ros`` come with ROS
(or the ros2 command line), not with this package's requirements.
"""

from __future__ import annotations

from dataclasses import replace
import os
from pathlib import Path
import shutil
import signal
import tempfile
from typing import Any

from launch import LaunchContext, LaunchDescription
from launch.actions import (
    DeclareLaunchArgument,
    EmitEvent,
    OpaqueFunction,
    RegisterEventHandler,
)
from launch.event_handlers import OnProcessExit, OnShutdown
from launch.events import Shutdown
from launch.events.process import ProcessExited, ShutdownProcess, SignalProcess
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from tiltrov_ros.core.names import (
    LOCKSTEP,
    MODES,
    PLANT,
    RECORDER,
    STANDBY_ENV,
    TF_REMAPPINGS,
    normalize_namespace,
    standby_name,
)
from tiltrov_ros.core.robot_description import robot_urdf
from tiltrov_ros.core.runner import StackConfig
from tiltrov_ros.core.timebase import NS_PER_S

from .specs import (
    RESPAWNABLE,
    LaunchError,
    LaunchOptions,
    NodeSpec,
    dds_environment,
    namespaced_config,
    stack_specs,
)
from .supervisor import RECORDER_STOP_TIMEOUT, STOP_TIMEOUTS

PACKAGE = 'tiltrov_ros'
#: The package (and executable) that publishes a URDF's links from joint_states.
ROBOT_STATE_PUBLISHER = 'robot_state_publisher'

#: name -> (default, description) of the launch arguments.
ARGUMENTS = {
    'scenario': ('pitch_hold', 'scenario name (config/scenarios) or path of a scenario file'),
    'controller': ('', "pd, switching or pid; empty: config/wrench_controller.yaml's"),
    'allocator': ('', "robust or paper; empty: config/thrust_allocator.yaml's"),
    'robot': ('', 'robot parameter file, or the name of a shipped one (robot_past_vertical: '
                  "servos past vertical); empty: config/robot.yaml, the paper's +-90 deg"),
    'mode': (LOCKSTEP, 'lockstep (deterministic, as fast as possible) or realtime'),
    'real_time_factor': ('1.0', 'realtime mode: sim seconds per wall second'),
    'duration': ('', "sim seconds to run; empty: the scenario's"),
    'namespace': ('', 'namespace pushed on every node and relative topic'),
    'record': ('', 'bag directory to record every topic into (must not exist); empty: none'),
    'markers': ('true', 'true: the plant publishes robot_markers (for RViz and Foxglove)'),
    'respawn': ('', 'comma-separated nodes taken over by a standby when they die mid-run '
                    f'({", ".join(RESPAWNABLE)}); empty: none'),
    'join': ('', "comma-separated nodes outside the package that join the run's handshake "
                 '(the run starts once they have matched every node too); empty: none'),
}


def generate_launch_description() -> LaunchDescription:
    """The launch arguments and the stack they describe."""
    declared = [DeclareLaunchArgument(name, default_value=default, description=text)
                for name, (default, text) in ARGUMENTS.items()]
    return LaunchDescription([*declared, OpaqueFunction(function=_stack)])


def options_from(values: dict[str, str]) -> LaunchOptions:
    """The :class:`LaunchOptions` of the launch arguments' values (strings)."""
    mode = values['mode']
    if mode not in MODES:
        raise LaunchError(f'mode:={mode!r}: allowed: {" or ".join(MODES)}')
    try:
        duration = float(values['duration']) if values['duration'] else None
        factor = float(values['real_time_factor'])
    except ValueError as exc:
        raise LaunchError(f'duration and real_time_factor are numbers: {exc}') from None
    if factor <= 0:
        raise LaunchError(f'real_time_factor:={factor:g}: must be > 0')
    if values['markers'] not in ('true', 'false'):
        raise LaunchError(f'markers:={values["markers"]!r}: allowed: true or false')
    respawn = tuple(n for n in values['respawn'].split(',') if n)
    unknown = [n for n in respawn if n not in RESPAWNABLE]
    if unknown:
        raise LaunchError(f'respawn:={values["respawn"]!r}: {", ".join(unknown)} cannot be '
                          f'respawned; allowed: {", ".join(RESPAWNABLE)}')
    return LaunchOptions(
        scenario=values['scenario'], controller=values['controller'] or None,
        allocator=values['allocator'] or None, duration=duration,
        robot=values['robot'] or None, lockstep=mode == LOCKSTEP,
        real_time_factor=factor, record=Path(values['record']) if values['record'] else None,
        namespace=values['namespace'], launcher='ros2 launch',
        markers=values['markers'] == 'true', respawn=respawn,
        join=tuple(n for n in values['join'].split(',') if n))


def _stack(context: LaunchContext) -> list[Any]:
    values = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    options = options_from(values)
    rsp = robot_state_publisher_installed()
    if rsp:
        options = replace(options, tf_thrusters=False)
    specs, config, _ = stack_specs(options)
    namespace = normalize_namespace(options.namespace)
    actions: list[Any] = []
    if namespace:
        # The shipped files' node sections name the nodes without a namespace.
        workdir = Path(tempfile.mkdtemp(prefix='tiltrov_launch_'))
        namespaced_config(specs, namespace, workdir)
        specs, _, _ = stack_specs(options, config_dir=workdir)
        actions.append(RegisterEventHandler(OnShutdown(
            on_shutdown=lambda *_: shutil.rmtree(workdir, ignore_errors=True))))
    nodes = {spec.name: _node(spec, namespace) for spec in specs}
    if rsp:
        nodes[ROBOT_STATE_PUBLISHER] = _robot_state_publisher(config, namespace)
    respawned = {spec.name: spec for spec in specs if spec.name in options.respawn}
    watcher = _EndOfRun(nodes, respawned, namespace)
    actions += list(nodes.values())
    actions += [RegisterEventHandler(OnProcessExit(target_action=node, on_exit=watcher.exited))
                for node in nodes.values()]
    for name in respawned:
        actions += watcher.new_standby(name)
    return actions


def _node(spec: NodeSpec, namespace: str, *, standby: bool = False) -> Node:
    # A stopping node of the run waits until the recorder has its last messages (the
    # recorder until it has every node's): SIGTERM only bounds a hang, as in tiltrov
    # launch (13 s, the recorder 20 s). The shipped Fast DDS profile, unless one is set.
    extra: dict[str, Any] = {'sigterm_timeout': str(
        RECORDER_STOP_TIMEOUT if spec.name == RECORDER else STOP_TIMEOUTS[0])}
    env = dds_environment(os.environ)
    if standby:
        # Its own node name until it takes over (no __node remapping: the node it builds
        # then keeps the node's name); the environment makes it a standby.
        env[STANDBY_ENV] = '1'
    if env:
        extra['additional_env'] = env
    return Node(package=PACKAGE, executable=spec.name, name=None if standby else spec.name,
                namespace=namespace or None, output='screen',
                parameters=[*(str(path) for path in spec.params_files), spec.all_overrides()],
                remappings=list(TF_REMAPPINGS) if namespace else None, **extra)


def robot_state_publisher_installed() -> bool:
    """robot_state_publisher is in the ament index (a ROS install; not the venv)."""
    try:
        from ament_index_python.packages import get_package_share_directory
        get_package_share_directory(ROBOT_STATE_PUBLISHER)
    except (ImportError, LookupError, ValueError, OSError):
        return False
    return True


def robot_state_publisher_parameters(config: StackConfig) -> dict[str, Any]:
    """The URDF of the robot in use, sim time, and the thruster links at every
    ``joint_states`` (the plant step: the odometry's rate; its default is 20 Hz)."""
    return {'robot_description': robot_urdf(config.robot), 'use_sim_time': True,
            'publish_frequency': NS_PER_S / config.step_ns}


def _robot_state_publisher(config: StackConfig, namespace: str) -> Node:
    return Node(package=ROBOT_STATE_PUBLISHER, executable=ROBOT_STATE_PUBLISHER,
                namespace=namespace or None, output='screen',
                parameters=[robot_state_publisher_parameters(config)],
                remappings=list(TF_REMAPPINGS) if namespace else None)


class _EndOfRun:
    """Ends the launch when the plant has finished the run (see the module docstring);
    a respawned node's exit hands over to its standby (SIGUSR1) and starts a new one."""

    def __init__(self, nodes: dict[str, Node], respawned: dict[str, NodeSpec],
                 namespace: str) -> None:
        self.nodes = nodes
        self.names = {id(node): name for name, node in nodes.items()}
        self.running = set(nodes)
        self.finished = False
        self.respawned = respawned
        self.namespace = namespace
        self.standbys: dict[str, Node] = {}

    def new_standby(self, name: str) -> list[Any]:
        """The actions that start a standby of ``name`` and watch it."""
        standby = _node(self.respawned[name], self.namespace, standby=True)
        self.standbys[name] = standby
        return [standby, RegisterEventHandler(OnProcessExit(target_action=standby,
                                                            on_exit=self.exited))]

    def _take_over(self, name: str) -> list[Any]:
        standby = self.standbys.pop(name)
        self.nodes[name] = standby
        self.names[id(standby)] = name
        self.running.add(name)
        return [EmitEvent(event=SignalProcess(signal_number=signal.SIGUSR1,
                                              process_matcher=_is(standby))),
                *self.new_standby(name)]

    def _stop(self, names: list[str]) -> list[Any]:
        return [EmitEvent(event=ShutdownProcess(process_matcher=_is(self.nodes[name])))
                for name in names]

    def exited(self, event: ProcessExited, context: LaunchContext) -> list[Any] | None:
        if id(event.action) not in self.names:      # a standby that never took over
            if context.is_shutdown or self.finished:
                return None
            # The run waits for it (a node of the handshake): its death ends the launch.
            name = next((n for n, s in self.standbys.items() if s is event.action), '?')
            raise LaunchError(f'{standby_name(name)} exited with code {event.returncode}')
        name = self.names[id(event.action)]
        self.running.discard(name)
        if context.is_shutdown:
            return None
        if name in self.respawned and not self.finished and name in self.standbys:
            return self._take_over(name)
        if event.returncode != 0:
            raise LaunchError(f'{name} exited with code {event.returncode}')
        if name == PLANT:
            self.finished = True
            return self._stop(sorted(self.running - {RECORDER}))
        if not self.finished:
            raise LaunchError(f'{name} exited before the end of the run')
        if self.running - {RECORDER}:
            return None
        if RECORDER in self.running:
            return self._stop([RECORDER])
        return [EmitEvent(event=Shutdown(reason='end of the run'))]


def _is(node: Node) -> Any:
    return lambda action: action is node
