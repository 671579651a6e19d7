"""What ``tiltrov launch`` starts: each node of the stack with its parameter files
and overrides (:func:`stack_specs`), validated before anything starts.

The launcher is the one place that knows how the nodes are wired: the node
processes, ``--single-process`` and the in-process tests all start the nodes
of :func:`stack_specs`. ``--record DIR`` adds the ``bag_recorder`` node
(started first, stopped last).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
import copy
from dataclasses import dataclass, field
import json
from pathlib import Path
from typing import Any

import yaml

from tiltrov_ros.core.atomic import replace_text
from tiltrov_ros.core.errors import TiltrovError
from tiltrov_ros.core.names import (
    ALLOCATOR,
    CONTROLLER,
    LOCKSTEP,
    PLANT,
    REALTIME,
    RECORDER,
    REFERENCE,
    STACK_NODES,
    TF_REMAPPINGS,
    join_namespace,
    normalize_namespace,
    standby_name,
)
from tiltrov_ros.core.params import robot_file
from tiltrov_ros.core.runner import StackConfig, stack_config
from tiltrov_ros.core.timebase import seconds, to_ns
from tiltrov_ros.paths import config_dir, config_file

#: Where the recorder node lives; ``--record`` starts it.
RECORDER_MODULE = 'tiltrov_ros.nodes.bag_recorder'

#: s of sim time: with ``--respawn``, how long the plant and the allocator hold the last
#: command (instead of zero thrust) while a respawned node takes over (realtime).
RESPAWN_HOLD = 3.0
#: Nodes ``--respawn`` may start again (the plant holds the run's state).
RESPAWNABLE = (CONTROLLER, ALLOCATOR, REFERENCE)
#: The environment variables naming a Fast DDS profiles file (Fast DDS 2 reads the first).
DDS_PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def dds_environment(environ: Mapping[str, str]) -> dict[str, str]:
    """The environment the launchers add to each node process: the shipped Fast DDS
    profile (``config/fastdds.xml``: announcements every 0.1 s, so that a node or a
    command line started later finds them within a fraction of a second), unless
    ``environ`` names one."""
    if any(environ.get(name) for name in DDS_PROFILE_VARIABLES):
        return {}
    path = str(config_dir() / 'fastdds.xml')
    return {name: path for name in DDS_PROFILE_VARIABLES}


class LaunchError(TiltrovError):
    """The launch cannot start (bad options, missing executable)."""


@dataclass(frozen=True)
class LaunchOptions:
    """What ``tiltrov launch`` was asked for (see :func:`add_arguments`)."""

    scenario: str = 'pitch_hold'
    controller: str | None = None          # None: config/wrench_controller.yaml's
    allocator: str | None = None           # None: config/thrust_allocator.yaml's
    duration: float | None = None          # None: the scenario's
    robot: str | None = None               # robot file or shipped name; None: robot.yaml
    lockstep: bool = True
    real_time_factor: float = 1.0
    record: Path | None = None
    single_process: bool = False
    namespace: str = ''
    params: tuple[str, ...] = ()           # 'node:name:=value'
    stall_timeout: float | None = None
    executor: str | None = None            # None: TILTROV_EXECUTOR or 'events'
    respawn: tuple[str, ...] = ()          # node names started again when they die
    status_file: Path | None = None        # the launch's state as JSON (StatusFile)
    launcher: str = 'tiltrov launch'       # what started the run (the bag's run_info)
    markers: bool = True                   # the plant publishes robot_markers
    tf_thrusters: bool = True              # False: robot_state_publisher publishes them
    join: tuple[str, ...] = ()             # nodes outside the package the run waits for


@dataclass(frozen=True)
class NodeSpec:
    """One node of the stack: how to start it and with what parameters."""

    name: str                               # node name = executable name
    module: str                             # module with main() and the class
    class_name: str
    params_files: tuple[Path, ...] = ()
    overrides: Mapping[str, Any] = field(default_factory=dict)
    raw_params: tuple[str, ...] = ()       # 'name:=value' strings from --param

    def all_overrides(self) -> dict[str, Any]:
        """``overrides`` plus the ``--param`` values (parsed as YAML, as ``-p`` does)."""
        values = dict(self.overrides)
        for raw in self.raw_params:
            name, _, value = raw.partition(':=')
            try:
                values[name] = yaml.safe_load(value)
            except yaml.YAMLError as exc:
                problem = getattr(exc, 'problem', None) or 'not valid YAML'
                raise LaunchError(f'--param {self.name}:{raw}: the value is not YAML '
                                  f'({problem})') from None
        return values

    def write_overrides(self, directory: Path, namespace: str = '', *,
                        standby: bool = False) -> Path:
        """A parameter file with the overrides, keyed by the node's full name (and, for
        its ``standby``, the standby's too: it joins the run's handshake before it builds
        the node).

        Not ``-p``: rcl stores ``-p`` values under ``/**`` and a node-specific
        section of a parameter file given earlier wins over them; a later file
        section for the node's own name wins over both.
        """
        path = directory / f'{standby_name(self.name) if standby else self.name}.overrides.yaml'
        document = {f'{namespace}/{self.name}': {'ros__parameters': self.all_overrides()}}
        if standby:     # a copy: YAML aliases are not read by rcl
            document[f'{namespace}/{standby_name(self.name)}'] = copy.deepcopy(
                document[f'{namespace}/{self.name}'])
        # Written aside and renamed into place: a new standby's file is written again at
        # every takeover, while the node taking over reads it (its command-line order).
        replace_text(path, yaml.safe_dump(document, sort_keys=False))
        return path

    def ros_args(self, overrides_file: Path | None, namespace: str = '') -> list[str]:
        """``--ros-args ...`` for a separate process."""
        args = ['--ros-args']
        if namespace:
            args += ['-r', f'__ns:={namespace}']
        args += remap_args(namespace)
        for path in self.params_files:
            args += ['--params-file', str(path)]
        if overrides_file is not None:
            args += ['--params-file', str(overrides_file)]
        return args


def remap_args(namespace: str) -> list[str]:
    """``-r`` arguments of a node in ``namespace``: ``/tf`` and ``/tf_static`` moved into
    it (each stack its own tree, as Nav2 does for several robots); none at the root."""
    if not namespace:
        return []
    return [arg for old, new in TF_REMAPPINGS for arg in ('-r', f'{old}:={new}')]


def robot_path(options: LaunchOptions) -> Path:
    """The robot parameter file of a launch (``--robot``; default the shipped one)."""
    if options.robot is None:
        return config_file('robot.yaml')
    return robot_file(options.robot).resolve()


def resolve(options: LaunchOptions) -> tuple[StackConfig, float]:
    """The stack configuration and the duration (s), validated before anything starts."""
    scenario = options.scenario
    if Path(scenario).suffix:
        scenario = str(Path(scenario).resolve())
    config = stack_config(scenario, options.controller, allocator_mode=options.allocator,
                          robot_file=robot_path(options))
    duration = config.scenario.duration if options.duration is None else options.duration
    step = config.step_ns
    if to_ns(duration) <= 0 or to_ns(duration) % step:
        raise LaunchError(f'--duration {duration!r}: must be a positive whole number of '
                          f'plant steps ({seconds(step):g} s)')
    return config, float(duration)


def run_node_names(options: LaunchOptions) -> list[str]:
    """The names of the run's nodes, as every node is told them (``run_nodes``): the
    recorder with ``--record``, the four stack nodes, the standby of each ``--respawn``
    node (a kill right after the start finds its handoff kept), and those that
    ``--join``."""
    return [*((RECORDER,) if options.record is not None else ()),
            ALLOCATOR, CONTROLLER, REFERENCE, PLANT,
            *(standby_name(n) for n in options.respawn), *options.join]


def stack_specs(options: LaunchOptions, *, config_dir: Path | None = None,
                extra_odom_readers: int = 0) -> tuple[list[NodeSpec], StackConfig, float]:
    """The nodes of a launch, in start order (the recorder, if any, first).

    ``config_dir`` holds the parameter files to use (default: the shipped ones;
    :func:`namespaced_config` rewrites them for a namespace).
    ``extra_odom_readers`` counts readers of ``odom`` outside the stack (a test
    probe) that the plant should wait for in lockstep.
    """
    config, duration = resolve(options)
    # A name stays a name; a file is passed as an absolute path.
    scenario_param = (str(Path(options.scenario).resolve()) if Path(options.scenario).suffix
                      else options.scenario)

    robot_yaml = robot_path(options)

    def files(node: str) -> tuple[Path, ...]:
        if config_dir is not None:
            return (config_dir / robot_yaml.name, config_dir / f'{node}.yaml')
        return (robot_yaml, config_file(f'{node}.yaml'))

    robot = {f'robot.{key}': (list(value) if isinstance(value, (list, tuple)) else value)
             for key, value in config.scenario.robot_overrides}
    raw: dict[str, list[str]] = {}
    for item in options.params:
        node, sep, assignment = item.partition(':')
        if not sep or ':=' not in assignment:
            raise LaunchError(f'--param {item!r}: expected NODE:NAME:=VALUE')
        raw.setdefault(node, []).append(assignment)
    mode = LOCKSTEP if options.lockstep else REALTIME
    sim = {'use_sim_time': True}
    kind = config.controller.kind

    # Every node is told the run's nodes: the handshake (nodes/handshake.py) starts the
    # run once each has matched every other, seen from both sides.
    run = {'run_nodes': run_node_names(options)}
    plant: dict[str, Any] = {
        'mode': mode, 'real_time_factor': float(options.real_time_factor),
        'scenario': scenario_param, 'duration': duration, 'exit_at_end': True,
        'startup_subscribers': 1 + (options.record is not None) + extra_odom_readers,
        **run, **robot}
    if options.record is not None and options.respawn:
        # A node may be killed: the plant uses no command before the bag has it.
        plant['recorder_window'] = 0.0
    if options.respawn:
        # Realtime: the last command holds while a respawned node takes over.
        plant['respawn_hold'] = RESPAWN_HOLD
    if options.stall_timeout is not None:
        plant['stall_timeout'] = float(options.stall_timeout)
    if not options.markers:
        plant['markers_period'] = 0.0
    if not options.tf_thrusters:
        plant['tf_thrusters'] = False
    controller = {'controller': kind, 'mode': mode, **run, **sim, **robot}
    allocator: dict[str, Any] = {
        'tilt_request': 'required' if kind == 'switching' else 'ignored',
        'scenario': scenario_param, **run, **sim, **robot}
    if options.allocator is not None:
        allocator['mode'] = options.allocator
    if options.respawn:
        allocator['respawn_hold'] = RESPAWN_HOLD
    reference = {'scenario': scenario_param, 'duration': duration, **run, **sim, **robot}

    def spec(name: str, module: str, cls: str, overrides: dict[str, Any]) -> NodeSpec:
        return NodeSpec(name, f'tiltrov_ros.nodes.{module}', cls, files(name), overrides,
                        tuple(raw.pop(name, ())))

    specs = [
        spec(ALLOCATOR, 'thrust_allocator', 'ThrustAllocatorNode', allocator),
        spec(CONTROLLER, 'wrench_controller', 'WrenchController', controller),
        spec(REFERENCE, 'reference_publisher', 'ReferencePublisher', reference),
        spec(PLANT, 'plant_simulator', 'PlantSimulator', plant),
    ]
    if options.record is not None:
        specs.insert(0, recorder_spec(options, config, duration, raw.pop(RECORDER, []),
                                      run_nodes=run['run_nodes']))
    if raw:
        raise LaunchError(f'--param for unknown node(s): {", ".join(sorted(raw))}; nodes: '
                          f'{", ".join(s.name for s in specs)}')
    for s in specs:
        s.all_overrides()       # every --param value is YAML, before anything starts
    return specs, config, duration


def run_info(options: LaunchOptions, config: StackConfig, duration: float) -> dict[str, Any]:
    """What the recorder stores about the run (bag metadata)."""
    info = config.describe()
    namespace = normalize_namespace(options.namespace)
    # The nodes whose final report the bag must hold (bag/losses.py): one that never
    # reached the bag at all is missing too.
    info.update(duration=duration, mode=LOCKSTEP if options.lockstep else REALTIME,
                namespace=namespace, launcher=options.launcher,
                nodes=[join_namespace(namespace, n) for n in STACK_NODES])
    if not options.lockstep:
        info['real_time_factor'] = options.real_time_factor
    return info


def recorder_spec(options: LaunchOptions, config: StackConfig, duration: float,
                  raw: Sequence[str] = (), *, run_nodes: Sequence[str] = ()) -> NodeSpec:
    """The ``bag_recorder`` node recording every topic into ``--record DIR``, one of the
    run's nodes (``run_nodes``).

    It runs on sim time so the bag's log times are the stack's.
    """
    assert options.record is not None
    overrides = {'output': str(Path(options.record).resolve()),
                 'run_info': json.dumps(run_info(options, config, duration), sort_keys=True),
                 'use_sim_time': True, 'run_nodes': list(run_nodes)}
    return NodeSpec(RECORDER, RECORDER_MODULE, 'BagRecorder', (), overrides, tuple(raw))


def namespaced_config(specs: Iterable[NodeSpec], namespace: str, directory: Path) -> None:
    """Copy the parameter files into ``directory`` with node keys for ``namespace``.

    A ``<node>: ros__parameters:`` section only reaches the node ``/<node>``;
    in a namespace the key must be the node's full name. ``/**`` keys are kept.
    """
    for spec in specs:
        for path in spec.params_files:
            target = directory / path.name
            if target.exists():
                continue
            with path.open(encoding='utf-8') as stream:
                document = yaml.safe_load(stream)
            renamed = {(key if str(key).startswith('/') else f'{namespace}/{key}'): value
                       for key, value in document.items()}
            with target.open('w', encoding='utf-8') as stream:
                yaml.safe_dump(renamed, stream, sort_keys=False)
