"""``tiltrov launch``: start the whole stack for one scenario (no ``ros2 launch`` needed).

Each node runs as its own process, as ``ros2 launch`` would start it: the
node's executable with ``--ros-args --params-file config/robot.yaml
--params-file config/<node>.yaml -p ...`` (the scenario, the mode, the
duration, the scenario's robot overrides). Output lines are prefixed with the
node's name. The run ends when the plant reaches ``--duration`` of sim time:
the plant (``exit_at_end``) exits 0 once its last messages are acknowledged,
and the launcher stops the other nodes (SIGINT, then SIGTERM, then SIGKILL) and
exits 0. A node that exits before that stops the launch: the others are
stopped and the launcher exits 1 naming it. Ctrl-C stops every node cleanly
(exit code 130).

``--single-process`` builds the same nodes, with the same parameter files and
overrides, in this process on one executor (the code path the
in-process tests use: :func:`stack_specs` and :func:`build_nodes`).

``--record DIR`` adds the ``bag_recorder`` node (started first, stopped last)
when the package has it (:data:`RECORDER_MODULE`).

``--respawn NODE`` (controller, allocator or reference; repeatable) starts
that node again, with the same arguments, when its process dies mid-run: the
plant keeps its state, re-publishes the tick it waits at (lockstep) and the
loop resumes with the new process (README.md, "Reliability").
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Mapping, Sequence
import contextlib
from dataclasses import dataclass, field
import importlib
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time
from typing import IO, Any

import yaml

from tiltrov_ros.core.controllers import CONTROLLER_KINDS
from tiltrov_ros.core.errors import TiltrovError
from tiltrov_ros.core.names import (
    ALLOCATOR,
    ALLOCATOR_MODES,
    CONTROLLER,
    LOCKSTEP,
    PLANT,
    REALTIME,
    RECORDER,
    REFERENCE,
    normalize_namespace,
)
from tiltrov_ros.core.runner import StackConfig, stack_config
from tiltrov_ros.core.scenarios import scenario_names
from tiltrov_ros.core.timebase import seconds, to_ns
from tiltrov_ros.paths import config_file

#: Where the recorder node lives; ``--record`` starts it.
RECORDER_MODULE = 'tiltrov_ros.nodes.bag_recorder'

#: s (wall) a node gets to exit after SIGINT, then after SIGTERM, before SIGKILL.
STOP_TIMEOUTS = (5.0, 3.0)
#: s (wall) the plant waits, once the recorder reads odom, before the initial state.
RECORDER_STARTUP_DELAY = 0.5
#: Nodes ``--respawn`` may start again (the plant holds the run's state).
RESPAWNABLE = (CONTROLLER, ALLOCATOR, REFERENCE)
#: s (wall) the recorder gets to close its bag after SIGINT.
RECORDER_STOP_TIMEOUT = 20.0
POLL = 0.05

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


class LaunchError(TiltrovError):
    """The launch cannot start (bad options, missing executable)."""


@dataclass(frozen=True)
class LaunchOptions:
    """What ``tiltrov launch`` was asked for (see :func:`add_arguments`)."""

    scenario: str = 'pitch_hold'
    controller: str | None = None          # None: config/wrench_controller.yaml's
    allocator: str | None = None           # None: config/thrust_allocator.yaml's
    duration: float | None = None          # None: the scenario's
    lockstep: bool = True
    real_time_factor: float = 1.0
    record: Path | None = None
    single_process: bool = False
    namespace: str = ''
    params: tuple[str, ...] = ()           # 'node:name:=value'
    stall_timeout: float | None = None
    executor: str | None = None            # None: TILTROV_EXECUTOR or 'events'
    respawn: tuple[str, ...] = ()          # node names started again when they die


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
            values[name] = yaml.safe_load(value)
        return values

    def write_overrides(self, directory: Path, namespace: str = '') -> Path:
        """A parameter file with the overrides, keyed by the node's full name.

        Not ``-p``: rcl stores ``-p`` values under ``/**`` and a node-specific
        section of a parameter file given earlier wins over them; a later file
        section for the node's own name wins over both.
        """
        path = directory / f'{self.name}.overrides.yaml'
        document = {f'{namespace}/{self.name}': {'ros__parameters': self.all_overrides()}}
        with path.open('w', encoding='utf-8') as stream:
            yaml.safe_dump(document, stream, sort_keys=False)
        return path

    def ros_args(self, overrides_file: Path | None, namespace: str = '') -> list[str]:
        """``--ros-args ...`` for a separate process."""
        args = ['--ros-args']
        if namespace:
            args += ['-r', f'__ns:={namespace}']
        for path in self.params_files:
            args += ['--params-file', str(path)]
        if overrides_file is not None:
            args += ['--params-file', str(overrides_file)]
        return args


def resolve(options: LaunchOptions) -> tuple[StackConfig, float]:
    """The stack configuration and the duration (s), validated before anything starts."""
    scenario = options.scenario
    if Path(scenario).suffix:
        scenario = str(Path(scenario).resolve())
    config = stack_config(scenario, options.controller, allocator_mode=options.allocator)
    duration = config.scenario.duration if options.duration is None else options.duration
    step = config.step_ns
    if to_ns(duration) <= 0 or to_ns(duration) % step:
        raise LaunchError(f'--duration {duration!r}: must be a positive whole number of '
                          f'plant steps ({seconds(step):g} s)')
    return config, float(duration)


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

    def files(node: str) -> tuple[Path, ...]:
        if config_dir is not None:
            return (config_dir / 'robot.yaml', config_dir / f'{node}.yaml')
        return (config_file('robot.yaml'), config_file(f'{node}.yaml'))

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

    plant: dict[str, Any] = {
        'mode': mode, 'real_time_factor': float(options.real_time_factor),
        'scenario': scenario_param, 'duration': duration, 'exit_at_end': True,
        'startup_subscribers': 1 + (options.record is not None) + extra_odom_readers,
        **robot}
    if options.record is not None:
        # The recorder must have matched every writer of the stack, not only odom's.
        plant['startup_delay'] = RECORDER_STARTUP_DELAY
    if options.stall_timeout is not None:
        plant['stall_timeout'] = float(options.stall_timeout)
    controller = {'controller': kind, 'mode': mode, **sim, **robot}
    allocator: dict[str, Any] = {
        'tilt_request': 'required' if kind == 'switching' else 'ignored',
        'scenario': scenario_param, **sim, **robot}
    if options.allocator is not None:
        allocator['mode'] = options.allocator
    reference = {'scenario': scenario_param, 'duration': duration, **sim, **robot}
    if options.record is not None and options.lockstep:
        # Nothing these nodes publish goes out before the recorder reads it (matters
        # for a node started again mid-run: --respawn).
        for overrides in (controller, allocator, reference):
            overrides['wait_for_recorder'] = RECORDER

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
        specs.insert(0, recorder_spec(options, config, duration, raw.pop(RECORDER, [])))
    if raw:
        raise LaunchError(f'--param for unknown node(s): {", ".join(sorted(raw))}; nodes: '
                          f'{", ".join(s.name for s in specs)}')
    return specs, config, duration


def run_info(options: LaunchOptions, config: StackConfig, duration: float) -> dict[str, Any]:
    """What the recorder stores about the run (bag metadata)."""
    info = config.describe()
    info.update(duration=duration, mode=LOCKSTEP if options.lockstep else REALTIME,
                namespace=normalize_namespace(options.namespace), launcher='tiltrov launch')
    if not options.lockstep:
        info['real_time_factor'] = options.real_time_factor
    return info


def recorder_spec(options: LaunchOptions, config: StackConfig, duration: float,
                  raw: Sequence[str] = ()) -> NodeSpec:
    """The ``bag_recorder`` node recording every topic into ``--record DIR``.

    It runs on sim time so the bag's log times are the stack's.
    """
    assert options.record is not None
    overrides = {'output': str(Path(options.record).resolve()),
                 'run_info': json.dumps(run_info(options, config, duration), sort_keys=True),
                 'use_sim_time': True}
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


# --------------------------------------------------------------------------- in process


def build_node(spec: NodeSpec, context: Any, namespace: str = '') -> Any:
    """Construct ``spec``'s node class in this process, bound to ``context``."""
    cls = getattr(importlib.import_module(spec.module), spec.class_name)
    cli_args = ['--ros-args']
    for path in spec.params_files:
        cli_args += ['--params-file', str(path)]
    kwargs = {'context': context, 'cli_args': cli_args,
              'parameter_overrides': spec.all_overrides()}
    if namespace:
        kwargs['namespace'] = namespace
    return cls(**kwargs)


def build_nodes(specs: Sequence[NodeSpec], context: Any, namespace: str = '') -> list[Any]:
    """Every node of ``specs`` in this process; destroyed again if one fails."""
    nodes: list[Any] = []
    try:
        for spec in specs:
            nodes.append(build_node(spec, context, namespace))
    except BaseException:
        for node in reversed(nodes):
            node.destroy_node()
        raise
    return nodes


# --------------------------------------------------------------------------- output


class _Output:
    """Prefixed, line-atomic output of several processes."""

    def __init__(self, stream: IO[str]) -> None:
        self._stream = stream
        self._lock = threading.Lock()
        self.width = 0

    def line(self, name: str, text: str) -> None:
        with self._lock:
            self._stream.write(f'[{name}]{" " * (self.width - len(name))} {text}\n')
            self._stream.flush()

    def pump(self, name: str, pipe: IO[bytes]) -> None:
        for raw in iter(pipe.readline, b''):
            self.line(name, raw.decode('utf-8', 'replace').rstrip('\n'))
        pipe.close()


# --------------------------------------------------------------------------- processes


def executable(spec: NodeSpec) -> list[str]:
    """argv[0:] that runs ``spec``'s node: its console script, else ``python -m``.

    Looked for next to the running ``tiltrov`` script (``lib/tiltrov_ros`` of a
    colcon install, ``bin`` of a venv) and next to the interpreter.
    """
    for directory in (Path(sys.argv[0]).resolve().parent, Path(sys.executable).parent):
        candidate = directory / spec.name
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return [str(candidate)]
    return [sys.executable, '-m', spec.module]


def _die_with_parent() -> None:  # pragma: no cover - runs in the child
    """Linux: the child gets SIGTERM if the launcher dies without stopping it."""
    with contextlib.suppress(Exception):
        import ctypes
        ctypes.CDLL('libc.so.6', use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


@dataclass
class _Child:
    spec: NodeSpec
    process: subprocess.Popen[bytes]
    pump: threading.Thread


class _Stop(Exception):
    """Raised by the signal handler to leave the wait loop."""


def _stop_children(children: Sequence[_Child], out: _Output,
                   hurry: threading.Event | None = None) -> None:
    """SIGINT the stack nodes, then the recorder; escalate to SIGTERM and SIGKILL.

    ``hurry`` set (a second Ctrl-C) cuts every wait short.
    """
    stack = [c for c in children if c.spec.name != RECORDER]
    recorder = [c for c in children if c.spec.name == RECORDER]
    for group, first_timeout in ((stack, STOP_TIMEOUTS[0]),
                                 (recorder, RECORDER_STOP_TIMEOUT)):
        for sig, timeout in ((signal.SIGINT, first_timeout), (signal.SIGTERM, STOP_TIMEOUTS[1]),
                             (signal.SIGKILL, STOP_TIMEOUTS[1])):
            alive = [c for c in group if c.process.poll() is None]
            if not alive:
                break
            if sig != signal.SIGINT:
                out.line('launch', f'sending {sig.name} to '
                                   f'{", ".join(c.spec.name for c in alive)}')
            for child in alive:
                with contextlib.suppress(ProcessLookupError):
                    child.process.send_signal(sig)
            deadline = time.monotonic() + timeout
            while (time.monotonic() < deadline and not (hurry and hurry.is_set())
                   and any(c.process.poll() is None for c in alive)):
                time.sleep(POLL)
    for child in children:
        child.pump.join(timeout=2.0)


class Monitor:
    """Hooks of :func:`run_processes` (``tiltrov soak`` measures through them)."""

    def poll(self, pids: Mapping[str, int]) -> None:
        """Called about every POLL s with each live node's pid."""

    def finished(self, pids: Mapping[str, int]) -> None:
        """Called once the plant has ended the run, before the others are stopped."""


def run_processes(specs: Sequence[NodeSpec], namespace: str, out: _Output,
                  summary: str, workdir: Path, extra_env: Mapping[str, str] | None = None,
                  *, respawn: Sequence[str] = (), monitor: Monitor | None = None,
                  linger: float = 0.0) -> int:
    """Start every node as a process; return when the run ends or a node dies.

    A node named in ``respawn`` that dies is started again instead. ``linger``:
    wall seconds to wait after the plant's end before stopping the others (their
    last /diagnostics, with final counts, reach the recorder).
    """
    env = dict(os.environ, PYTHONUNBUFFERED='1', RCUTILS_LOGGING_BUFFERED_STREAM='1',
               **(extra_env or {}))
    out.width = max(len(s.name) for s in specs)
    children: list[_Child] = []
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}

    stopping = threading.Event()
    hurry = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        if stopping.is_set():       # already stopping: a second Ctrl-C hurries it
            hurry.set()
            return
        stopping.set()
        raise _Stop(signal.Signals(signum).name)

    started = time.monotonic()
    code = EXIT_OK
    try:
        for sig in previous:
            signal.signal(sig, on_signal)
        def start(spec: NodeSpec) -> _Child:
            argv = executable(spec) + spec.ros_args(spec.write_overrides(workdir, namespace),
                                                     namespace)
            process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                       stderr=subprocess.STDOUT, env=env,
                                       start_new_session=True, preexec_fn=_die_with_parent)
            pump = threading.Thread(target=out.pump, args=(spec.name, process.stdout),
                                    daemon=True)
            pump.start()
            out.line('launch', f'started {spec.name} (pid {process.pid})')
            return _Child(spec, process, pump)

        for spec in specs:
            children.append(start(spec))
        while True:
            for i, child in enumerate(children):
                rc = child.process.poll()
                if rc is None:
                    continue
                if child.spec.name == PLANT and rc == 0:
                    wall = time.monotonic() - started
                    if monitor is not None:
                        monitor.finished(_pids(children))
                    if linger > 0:
                        time.sleep(linger)
                    out.line('launch', f'{summary} done in {wall:.2f} s wall; stopping the '
                                       'other nodes')
                    return code
                if child.spec.name in respawn:
                    child.pump.join(timeout=2.0)
                    out.line('launch', f'{child.spec.name} died (exit code {rc}); starting '
                                       'it again (--respawn)')
                    children[i] = start(child.spec)
                    continue
                out.line('launch', f'{child.spec.name} died (exit code {rc}); stopping the '
                                   'other nodes')
                code = EXIT_FAILED
                return code
            if monitor is not None:
                monitor.poll(_pids(children))
            time.sleep(POLL)
    except _Stop as stop:
        out.line('launch', f'{stop.args[0]}: stopping every node')
        code = EXIT_INTERRUPTED
        return code
    finally:
        stopping.set()              # from here on a signal only hurries the stop
        try:
            _stop_children(children, out, hurry)
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        if code == EXIT_FAILED:
            dead = [c.spec.name for c in children
                    if c.process.returncode not in (0, None, -signal.SIGINT)]
            print(f'tiltrov launch: failed: {", ".join(dead) or "a node"} died', file=sys.stderr)


def _pids(children: Sequence[_Child]) -> dict[str, int]:
    return {c.spec.name: c.process.pid for c in children if c.process.poll() is None}


def run_single_process(specs: Sequence[NodeSpec], namespace: str, out: _Output,
                       summary: str, executor_kind: str | None = None) -> int:
    """Every node in this process, bound to one context.

    The stack nodes share one executor (``nodes.executors.make_executor``). The
    recorder, if any, spins on its own SingleThreadedExecutor in a second
    thread: it takes queued messages itself inside its callbacks, which the
    EventsExecutor (one take per event) does not allow, and it stays off the
    stack's critical path.
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from tiltrov_ros.nodes.executors import STARTUP_ERRORS, make_executor, spin_until

    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[Any] = []
    executor = None
    side: Any = None
    side_thread: threading.Thread | None = None
    started = time.monotonic()
    try:
        try:
            nodes = build_nodes(specs, context, namespace)
        except STARTUP_ERRORS as exc:
            out.line('launch', f'cannot start the stack: {exc}')
            return EXIT_FAILED
        by_name = {s.name: n for n, s in zip(nodes, specs)}
        plant = by_name[PLANT]
        executor = make_executor(context, executor_kind)
        for name, node in by_name.items():
            if name != RECORDER:
                executor.add_node(node)
        if RECORDER in by_name:
            side = SingleThreadedExecutor(context=context)
            side.add_node(by_name[RECORDER])
            side_thread = threading.Thread(target=side.spin, name=RECORDER, daemon=True)
            side_thread.start()
        try:
            spin_until(executor, context, plant.finished)
        except KeyboardInterrupt:
            out.line('launch', 'SIGINT: stopping every node')
            return EXIT_INTERRUPTED
        out.line('launch', f'{summary} done in {time.monotonic() - started:.2f} s wall')
        return EXIT_OK
    finally:
        if executor is not None:
            executor.shutdown()
        if side is not None:
            side.shutdown()
        if side_thread is not None:
            side_thread.join(timeout=10.0)
        # The recorder (first in start order) is destroyed last: it drains its queues.
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown(context=context)


# --------------------------------------------------------------------------- CLI


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--scenario', default='pitch_hold', metavar='NAME|FILE',
                        help=f'shipped scenario ({", ".join(scenario_names())}) or a scenario '
                             'YAML file (default: pitch_hold)')
    parser.add_argument('--controller', choices=CONTROLLER_KINDS, default=None,
                        help="control law (default: config/wrench_controller.yaml's, pd)")
    parser.add_argument('--allocator', choices=ALLOCATOR_MODES, default=None,
                        help="allocation mode (default: config/thrust_allocator.yaml's, robust)")
    parser.add_argument('--duration', type=float, default=None, metavar='SEC',
                        help="sim time to run, s (default: the scenario's)")
    timing = parser.add_mutually_exclusive_group()
    timing.add_argument('--lockstep', dest='lockstep', action='store_true', default=True,
                        help='deterministic, as fast as possible (default)')
    timing.add_argument('--realtime', dest='lockstep', action='store_false',
                        help='wall-clock stepping at --real-time-factor')
    parser.add_argument('--real-time-factor', type=float, default=1.0, metavar='X',
                        help='--realtime: sim seconds per wall second (default 1.0)')
    parser.add_argument('--record', type=Path, default=None, metavar='DIR',
                        help='record every topic into the bag directory DIR (bag_recorder)')
    parser.add_argument('--single-process', action='store_true',
                        help='run every node in this process on one executor')
    parser.add_argument('--executor', choices=('events', 'single', 'multi'), default=None,
                        help="executor of every node: rclpy's EventsExecutor (default), "
                             'SingleThreadedExecutor or MultiThreadedExecutor (one shared '
                             'by all nodes with --single-process)')
    parser.add_argument('--namespace', default='', metavar='NS',
                        help='push the whole stack into namespace NS (topics become /NS/odom, '
                             '...; /clock and /diagnostics stay global)')
    parser.add_argument('--param', action='append', default=[], metavar='NODE:NAME:=VALUE',
                        help='extra parameter for one node, e.g. '
                             "wrench_controller:gains.kp:='[100.0, 100.0, 100.0, 30.0, 60.0, "
                             "50.0]' (repeatable)")
    parser.add_argument('--stall-timeout', type=float, default=None, metavar='SEC',
                        help='lockstep: wall seconds before the plant reports a stall')
    parser.add_argument('--respawn', action='append', default=[], choices=RESPAWNABLE,
                        metavar='NODE',
                        help='start NODE again when its process dies mid-run '
                             f'({", ".join(RESPAWNABLE)}; repeatable)')


def options_from_args(args: argparse.Namespace) -> LaunchOptions:
    return LaunchOptions(
        scenario=args.scenario, controller=args.controller, allocator=args.allocator,
        duration=args.duration, lockstep=args.lockstep,
        real_time_factor=args.real_time_factor, record=args.record,
        single_process=args.single_process, namespace=args.namespace,
        params=tuple(args.param), stall_timeout=args.stall_timeout, executor=args.executor,
        respawn=tuple(args.respawn))


def launch(options: LaunchOptions, stream: IO[str] | None = None, *,
           monitor: Monitor | None = None, linger: float = 0.0) -> int:
    """Run one launch; the exit code of ``tiltrov launch`` (``monitor``, ``linger``:
    see :func:`run_processes`; separate processes only)."""
    out = _Output(stream if stream is not None else sys.stdout)
    namespace = normalize_namespace(options.namespace)
    try:
        if options.real_time_factor <= 0:
            raise LaunchError('--real-time-factor must be > 0')
        specs, config, duration = stack_specs(options)
    except (TiltrovError, FileNotFoundError) as exc:
        print(f'tiltrov launch: {exc}', file=sys.stderr)
        return EXIT_USAGE
    mode = 'lockstep' if options.lockstep else f'realtime x{options.real_time_factor:g}'
    summary = (f'{config.scenario.name} with {config.controller.kind} / '
               f'{config.allocator.mode}, {mode}: {duration:g} s of sim time')
    out.line('launch', f'{summary}{f" in {namespace}" if namespace else ""}'
                       f'{f", recording into {options.record}" if options.record else ""}')
    with tempfile.TemporaryDirectory(prefix='tiltrov_launch_') as tmp:
        if namespace:
            namespaced_config(specs, namespace, Path(tmp))
            specs, _, _ = stack_specs(options, config_dir=Path(tmp))
        if options.single_process:
            return run_single_process(specs, namespace, out, summary, options.executor)
        env = {'TILTROV_EXECUTOR': options.executor} if options.executor else {}
        return run_processes(specs, namespace, out, summary, Path(tmp), env,
                             respawn=options.respawn, monitor=monitor, linger=linger)


def run(args: argparse.Namespace) -> int:
    return launch(options_from_args(args))
