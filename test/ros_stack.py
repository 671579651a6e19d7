"""Helpers of the node and stack tests: a topic probe, message builders, running the stack.

Imported as ``ros_stack`` (test/ is on sys.path: it holds conftest.py).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
import json
import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import threading
import time
from typing import Any, TypeVar

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from harness import HANG_BOUND as HANG_BOUND  # re-exported: the tests import it from here
from harness import TreeProgress, progressing_until, spin_while_progressing
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from visualization_msgs.msg import MarkerArray

from tiltrov_ros.core import names
from tiltrov_ros.core.names import PLANT
from tiltrov_ros.core.timebase import NS_PER_S as NS
from tiltrov_ros.nodes.conversions import stamp_ns
from tiltrov_ros.paths import executable
from tiltrov_ros.stack.inprocess import build_nodes
from tiltrov_ros.stack.specs import LaunchOptions, NodeSpec, stack_specs

MS = 1_000_000

#: Probe readers: reliable, keep everything (the stack's writers are reliable).
KEEP_ALL = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_ALL)

TOPIC_TYPES: dict[str, Any] = {
    'odom': Odometry, 'joint_states': JointState, '/clock': Clock,
    'setpoint': PoseStamped, 'setpoint_velocity': TwistStamped,
    'wrench_cmd': WrenchStamped, 'tilt_request': JointState,
    'pid_integral': JointState, 'tilt_target': JointState,
    'thrust_cmd': JointState, 'tilt_cmd': JointState, 'wrench_achieved': WrenchStamped,
    '/diagnostics': DiagnosticArray, 'robot_markers': MarkerArray,
}


#: Readers of what is written once for every reader (/tf_static, robot_description).
LATCHED = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     history=HistoryPolicy.KEEP_LAST, depth=1)


def require_tf2_msgs() -> Any:
    """tf2_msgs/msg/TFMessage, for the tests of /tf and /tf_static. The venv has it once
    ``make install`` built it (tools/tf2_msgs), a ROS install always: where it is missing
    the test is skipped, except under CI (``CI`` set, as .ci/run does), whose fresh clone
    must have built it, where that is a failure."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError as exc:
        reason = f'tf2_msgs is not importable ({exc}): `make install` builds it'
        if os.environ.get('CI'):
            pytest.fail(reason, pytrace=False)
        pytest.skip(reason)
    return TFMessage


class Probe:
    """Subscribes to topics and keeps every message, in arrival order."""

    def __init__(self, node: Any, topics: Sequence[str]) -> None:
        self.node = node
        self.messages: dict[str, list[Any]] = {topic: [] for topic in topics}
        self.subscriptions = [
            node.create_subscription(TOPIC_TYPES[topic], topic, self.messages[topic].append,
                                     KEEP_ALL) for topic in topics]

    def matched(self) -> bool:
        """Every reader of the probe is matched with a writer (it gets what is published
        from now on)."""
        return all(sub.get_publisher_count() > 0 for sub in self.subscriptions)

    def __getitem__(self, topic: str) -> list[Any]:
        return self.messages[topic]

    def stamps(self, topic: str) -> list[int]:
        if topic == '/clock':
            return [stamp_ns(m.clock) for m in self.messages[topic]]
        return [stamp_ns(m.header.stamp) for m in self.messages[topic]]

    def by_stamp(self, topic: str) -> dict[int, Any]:
        """Last message of each stamp."""
        return dict(zip(self.stamps(topic), self.messages[topic]))

    def clear(self) -> None:
        for messages in self.messages.values():
            messages.clear()


def stamped(msg: Any, ns: int, frame_id: str = '') -> Any:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, NS)
    msg.header.frame_id = frame_id
    return msg


def joint_state(ns: int, names: Sequence[str], **fields: Sequence[float]) -> JointState:
    msg = stamped(JointState(), ns)
    msg.name = list(names)
    for key, values in fields.items():
        setattr(msg, key, [float(v) for v in values])
    return msg


def odometry(ns: int, position: Sequence[float], quaternion_wxyz: Sequence[float],
             nu: Sequence[float]) -> Odometry:
    msg = stamped(Odometry(), ns, 'odom_ned')
    msg.child_frame_id = 'base_link_frd'
    p, o = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.w, o.x, o.y, o.z = (float(v) for v in quaternion_wxyz)
    t = msg.twist.twist
    t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z = (
        float(v) for v in nu)
    return msg


def pose(ns: int, position: Sequence[float], quaternion_wxyz: Sequence[float],
         frame_id: str = 'odom_ned') -> PoseStamped:
    msg = stamped(PoseStamped(), ns, frame_id)
    p, o = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z = (float(v) for v in position)
    o.w, o.x, o.y, o.z = (float(v) for v in quaternion_wxyz)
    return msg


def twist(ns: int, velocity: Sequence[float]) -> TwistStamped:
    msg = stamped(TwistStamped(), ns, 'odom_ned')
    t = msg.twist
    t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z = (
        float(v) for v in velocity)
    return msg


def wrench(ns: int, values: Sequence[float]) -> WrenchStamped:
    msg = stamped(WrenchStamped(), ns, 'base_link_frd')
    f, t = msg.wrench.force, msg.wrench.torque
    f.x, f.y, f.z, t.x, t.y, t.z = (float(v) for v in values)
    return msg


def odom_rows(messages: Sequence[Odometry]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position, quaternion (w x y z), nu) arrays of odometry messages."""
    p = np.array([[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z]
                  for m in messages])
    q = np.array([[m.pose.pose.orientation.w, m.pose.pose.orientation.x,
                   m.pose.pose.orientation.y, m.pose.pose.orientation.z] for m in messages])
    nu = np.array([[m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z,
                    m.twist.twist.angular.x, m.twist.twist.angular.y, m.twist.twist.angular.z]
                   for m in messages])
    return p, q, nu


def wrench_rows(messages: Sequence[WrenchStamped]) -> np.ndarray:
    return np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z,
                      m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z]
                     for m in messages])


def effort_rows(messages: Sequence[JointState]) -> np.ndarray:
    return np.array([list(m.effort) for m in messages])


def spin(executor: Any, predicate: Callable[[], bool], timeout: float) -> bool:
    """Spin ``executor`` until ``predicate()`` or ``timeout`` wall seconds."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return bool(predicate())
        executor.spin_once(timeout_sec=0.01)
    return True


@dataclass
class StackRun:
    """What a probe recorded during one in-process lockstep run."""

    nodes: list[Any]
    probe: Probe
    specs: list[NodeSpec]
    config: Any
    duration: float
    extra: dict[str, Any] = field(default_factory=dict)

    def node(self, name: str) -> Any:
        return next(n for n, s in zip(self.nodes, self.specs) if s.name == name)


#: The stack's topics but /diagnostics and robot_markers (not part of the control loop).
STACK_TOPICS = tuple(t for t in names.STACK_TOPICS
                     if t not in (names.DIAGNOSTICS, names.ROBOT_MARKERS))


def run_stack(context: Any, executor: Any, options: LaunchOptions, *,
              topics: Sequence[str] = STACK_TOPICS, idle: float = 120.0,
              namespace: str = '', last: Callable[[Probe, int], bool] | None = None
              ) -> StackRun:
    """Build the launcher's nodes in ``context``, spin ``executor`` until the plant ends.

    The caller owns ``executor``; the nodes and the probe node are removed from
    it and destroyed before returning (the messages stay in the probe), once the
    last ``odom`` (and ``last(probe, end_ns)``, if given) reached the probe. ``idle``:
    wall seconds without progress that make a hang (no bound on a slow run).
    """
    import rclpy

    specs, config, duration = stack_specs(options, extra_odom_readers=1)
    probe_node = rclpy.create_node('stack_probe', context=context,
                                   namespace=namespace or None)
    probe = Probe(probe_node, topics)
    nodes = build_nodes(specs, context, namespace)
    run = StackRun(nodes, probe, specs, config, duration)
    try:
        for node in (probe_node, *nodes):
            executor.add_node(node)
        plant = run.node(PLANT)
        # While the plant's time moves, however slowly: ``idle`` s without a step (or
        # before the first: the handshake) is a hang.
        assert spin_while_progressing(
            executor, plant.finished.done, lambda: plant.plant.time_ns, idle=idle), (
            f'the plant stopped at {plant.plant.time_ns / NS} s of {duration} s')
        # The last messages: the state at the end reaches the probe.
        end = plant.plant.time_ns
        assert spin(executor, lambda: (
            'odom' not in topics or (probe.stamps('odom') or [0])[-1] >= end)
            and (last is None or last(probe, end)), idle), 'the end never reached the probe'
        run.extra['stalls'] = plant.stalls
        run.extra['republished'] = plant.republished
    finally:
        for node in (*nodes, probe_node):
            executor.remove_node(node)
            node.destroy_node()
    return run


def clock_msg(ns: int) -> Clock:
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(ns, NS)
    return msg


def diagnostics(probe: Probe, node_name: str) -> dict[str, str]:
    """Key values of the newest /diagnostics status of ``node_name`` ({} if none)."""
    for array in reversed(probe['/diagnostics']):
        for status in array.status:
            if status.name.rsplit('/', 1)[-1] == node_name:
                return {kv.key: kv.value for kv in status.values} | {
                    '_level': str(status.level[0] if isinstance(status.level, bytes)
                                  else status.level), '_message': status.message}
    return {}


def report(ros: Any, probe: Probe, node: Any) -> dict[str, str]:
    """Make ``node`` publish /diagnostics now and return what the probe received."""
    before = len(probe['/diagnostics'])
    node.publish_diagnostics()
    assert ros.spin_until(lambda: len(probe['/diagnostics']) > before, timeout=5.0)
    return diagnostics(probe, node.get_name())


def finite_outputs(probe: Probe) -> bool:
    """No message the probe received carries NaN or infinity."""
    from tiltrov_ros.nodes.conversions import message_is_finite
    return all(message_is_finite(m) for topic, messages in probe.messages.items()
               for m in messages if topic != '/diagnostics')


def installed(name: str) -> Path:
    """The package's installed executable, found as the product finds it (the ament
    index, PATH, the venv's bin: :func:`tiltrov_ros.paths.executable`)."""
    found = executable(name)
    assert found is not None, f'{name} is not installed (ament index, PATH, venv bin)'
    return found


# --------------------------------------------------------------------------- processes


class LaunchProcess:
    """``tiltrov launch`` as a process: its output (read by a thread, so the pipe never
    fills) and its ``--status-file`` (the pids of the nodes it started, its state)."""

    def __init__(self, tmp_path: Path, *args: str) -> None:
        self.status_path = tmp_path / 'launch_status.json'
        self.process = subprocess.Popen(
            [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', *args, '--status-file',
             str(self.status_path)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, cwd=tmp_path)
        self.lines: list[str] = []
        self._reader = threading.Thread(
            target=lambda: self.lines.extend(self.process.stdout or ()), daemon=True)
        self._reader.start()
        self.seen: set[int] = set()      # every pid the status file ever named
        self.cpu = TreeProgress(self.process.pid)

    @property
    def output(self) -> str:
        return ''.join(self.lines)

    def status(self) -> dict[str, Any]:
        try:
            status = json.loads(self.status_path.read_text())
        except (FileNotFoundError, json.JSONDecodeError):
            return {}
        self.seen |= {node['pid'] for node in status['nodes'].values()}
        return status

    def pids(self) -> dict[str, int]:
        return {name: node['pid'] for name, node in self.status().get('nodes', {}).items()}

    def progress(self) -> tuple[int, int]:
        """What the launch has said and the CPU its processes have used: it changes while
        the launch starts, runs or stops, however slowly a loaded machine makes it."""
        return len(self.output), self.cpu()

    def wait_running(self, idle: float = 120.0) -> dict[str, int]:
        """The nodes' pids once every node is started (state ``running``); a launch that
        says nothing new and uses no CPU for ``idle`` wall seconds meanwhile is hung (a
        loaded machine starts the nodes slowly: 80 s once beside two busy loops and
        another stack)."""
        def running() -> bool:
            return self.status().get('state') == 'running'

        progressing_until(lambda: running() or self.process.poll() is not None,
                          self.progress, idle)
        assert running(), self.output       # not ended, not hung
        return self.pids()

    def finish(self, idle: float = 120.0) -> int:
        """The launch's exit code once it has ended, however slowly (AssertionError when
        it said nothing new and used no CPU for ``idle`` wall seconds: a hang)."""
        if not progressing_until(lambda: self.process.poll() is not None, self.progress, idle):
            raise AssertionError(f'tiltrov launch hung (nothing for {idle} s):\n'
                                 + self.output)
        self._reader.join(timeout=5)
        return int(self.process.returncode)

    def cleanup(self) -> None:
        """Whatever a failed test left running: the launcher and the nodes it started."""
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10)
        self.status()
        for pid in self.seen:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)


def ready(ros: Any, names: Sequence[str], launch: LaunchProcess,
          until: Any = None) -> Probe:
    """Spin until every node in ``names`` has published /diagnostics (it is built and
    spinning, its signal handlers installed) and ``until(probe)`` holds, for as long as
    ``launch`` makes progress (:meth:`LaunchProcess.progress`: a loaded machine starts
    the nodes slowly, a hang is what stops)."""
    probe = Probe(ros.node('launch_probe'), ['/diagnostics'])

    def seen() -> int:
        return sum(bool(diagnostics(probe, name)) for name in names)

    assert ros.spin_while_progressing(
        lambda: seen() == len(names) and (until is None or until(probe)),
        lambda: (seen(), launch.progress())), launch.output
    return probe


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def kill_now(pid: int) -> float:
    """SIGKILL ``pid``; the wall time (``time.time()``, the clock of the nodes' log lines)
    once it is dead: gone (perhaps before the kill: a run that ended stops its nodes), or
    a zombie its parent has not reaped yet."""
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        return time.time()
    while True:
        try:
            fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        except (FileNotFoundError, ProcessLookupError):
            break
        if fields[0] in ('Z', 'X'):
            break
        time.sleep(0.001)       # a few ms at most: SIGKILL cannot be caught
    return time.time()


#: Tries of a run whose nodes are killed in it (each four times as long as the one before).
KILL_TRIES = 3
_Duration = TypeVar('_Duration', int, float)


def killed_in_run(tmp_path: Path, duration: _Duration,
                  one: Callable[[Path, _Duration, str], str | None]
                  ) -> tuple[Path, _Duration, str]:
    """``one(run_dir, duration, probe)``: a run whose nodes are killed, its output, or None
    when the kills came after the run had ended (it tested nothing: a loaded machine can
    be that late, a 10 s lockstep run ends about a second after it starts). Made again,
    four times as long, until the kills land in the run: (run_dir, duration, output)."""
    for attempt in range(KILL_TRIES):
        run_dir = tmp_path / f'try{attempt}'
        run_dir.mkdir()
        output = one(run_dir, duration, f'restart_probe{attempt}')
        if output is not None:
            return run_dir, duration, output
        duration = duration * 4
    pytest.fail(f'in {KILL_TRIES} tries the kills came after the run had ended')


#: The plant's log line at the end of a run, with its wall time (rcutils' log format).
_END_LINE = re.compile(r'\[(\d+\.\d+)\] \[plant_simulator\]: reached the end of the run')


def ended_by(output: str, moment: float) -> bool:
    """Whether a launch's ``output`` says its plant reached the run's end at or before the
    wall time ``moment``: a node killed then was killed after the run, not in it."""
    found = _END_LINE.search(output)
    return found is not None and float(found[1]) <= moment


#: The series of a recorded run that equal the headless runner's (``run_scenario``).
RUN_SERIES = ('t', 'position', 'quaternion', 'nu', 'thrust', 'tc', 'wrench_cmd',
              'thrust_cmd', 'tilt_cmd', 'wrench_achieved')


def assert_same_run(recorded: Any, expected: Any, atol: float = 1e-9) -> None:
    """A recorded lockstep run (``read_runlog``) is the headless run: nothing missing,
    every series to ``atol`` (0: to the last bit)."""
    assert recorded.meta['bag']['missing'] == {}
    for name in RUN_SERIES:
        np.testing.assert_allclose(getattr(recorded, name), getattr(expected, name),
                                   rtol=0, atol=atol, err_msg=name)


class SimTime:
    """The newest ``odom`` stamp a probe has taken: the plant's sim time (one sample kept:
    a probe that keeps every one of a lockstep run's falls behind on a loaded machine)."""

    def __init__(self, node: Any) -> None:
        self.ns = -1
        node.create_subscription(Odometry, 'odom', self._take, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE))

    def _take(self, msg: Odometry) -> None:
        self.ns = stamp_ns(msg.header.stamp)

    def reached(self, seconds: float) -> bool:
        return self.ns >= seconds * NS


def joined_sim_time(ros: Any, options: LaunchOptions, name: str = 'sim_time_probe') -> SimTime:
    """A :class:`SimTime` probe that joins the run of ``options`` (whose ``join`` names
    ``name``): the run starts only once the probe has matched it, so a short lockstep run
    cannot end before the probe sees its first ticks."""
    from tiltrov_ros.nodes.handshake import Handshake
    from tiltrov_ros.stack.specs import run_node_names

    assert name in options.join
    node = ros.node(name)
    sim = SimTime(node)
    Handshake(node, run_node_names(options)).start()
    return sim
