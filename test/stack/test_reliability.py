"""Attacks on a running stack, as a faulty peer makes them: real processes started by
``tiltrov launch``, real DDS, a test node publishing what a buggy simulator, a bad
replay or a stray tool would (docs/reliability.md, "Attacks")."""

from __future__ import annotations

from collections.abc import Callable
import math
import os
from pathlib import Path
import signal
import statistics
import subprocess
import sys
import time
from typing import Any

from geometry_msgs.msg import PoseStamped, TwistStamped, WrenchStamped
from harness import TreeProgress, run_while_progressing
from nav_msgs.msg import Odometry
import pytest
from rclpy.serialization import serialize_message
from ros_stack import (
    HANG_BOUND,
    KEEP_ALL,
    LaunchProcess,
    Probe,
    SimTime,
    alive,
    diagnostics,
    joint_state,
    odometry,
    ready,
    wrench,
)
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from tiltrov_ros.core.names import ALLOCATOR, CONTROLLER, PLANT, REFERENCE
from tiltrov_ros.core.timebase import NS_PER_S
from tiltrov_ros.nodes.conversions import set_stamp, stamp_ns
from tiltrov_ros.paths import config_file

STACK = (ALLOCATOR, CONTROLLER, REFERENCE, PLANT)
#: The nodes on sim time (the plant is the clock).
ON_SIM_TIME = (ALLOCATOR, CONTROLLER, REFERENCE)
TICK = 50_000_000       # ns: the control period


def _count(probe: Probe, node: str, key: str) -> int:
    return int(diagnostics(probe, node).get(key, '0'))


def _stepping(probe: Probe) -> bool:
    """The plant is past t = 0 (every reader of its topics is there)."""
    return float(diagnostics(probe, PLANT).get('sim_time', 0.0)) > 0.0


def _stop(launch: LaunchProcess) -> int:
    launch.process.send_signal(signal.SIGINT)
    return launch.finish()


# --------------------------------------------------------------------------- /clock


@pytest.mark.slow
@pytest.mark.parametrize('single_process', [False, True], ids=['processes', 'single_process'])
@pytest.mark.timeout(HANG_BOUND)
def test_a_clock_sample_with_a_negative_second_is_rejected_by_every_node(
        ros: Any, tmp_path: Path, single_process: bool) -> None:
    """One /clock message with sec = -1 (a bad replay, a buggy simulator): every node on
    sim time rejects and counts it and runs on; the recorder logs it at the last good
    time and closes a bag that opens without repair."""
    from tiltrov_ros.bag.bagfile import bag_info
    from tiltrov_ros.bag.repair import problem

    bag = tmp_path / 'bag'
    launch = LaunchProcess(tmp_path, '--realtime', '--duration', '600', '--record', str(bag),
                           *(['--single-process'] if single_process else []))
    try:
        launch.wait_running()
        probe = ready(ros, STACK, launch, until=_stepping)
        attacker = ros.node('clock_attacker')
        pub = attacker.create_publisher(Clock, '/clock', KEEP_ALL)
        bad = Clock()
        bad.clock.sec, bad.clock.nanosec = -1, 0

        def every_node_rejected_one() -> bool:
            # rclpy's /clock reader keeps one sample, best effort: a sample may be
            # overwritten by the plant's before it is taken; send until counted.
            pub.publish(bad)
            return all(_count(probe, n, 'rejected./clock.bad_stamp') >= 1
                       for n in ON_SIM_TIME)

        assert ros.spin_until(every_node_rejected_one, timeout=30.0), launch.output
        assert ros.spin_until(lambda: _stepping(probe) and all(
            _count(probe, n, 'callback_errors') == 0 for n in STACK))
        assert launch.process.poll() is None, launch.output
        assert _stop(launch) == 130, launch.output
    finally:
        launch.cleanup()
    assert 'died' not in launch.output and 'Traceback' not in launch.output, launch.output
    assert problem(bag) is None
    info = bag_info(bag)
    assert info.topics['/clock'].count > 0 and info.end_ns >= info.start_ns >= 0


# --------------------------------------------------------------------------- rejected input


def _latest_clock(probe: Probe) -> int:
    return stamp_ns(probe['/clock'][-1].clock)


def _thrust_rows(watch: Probe) -> list[tuple[int, float]]:
    """(stamp, total thrust |effort| N) of every joint_states the probe has."""
    return [(stamp_ns(m.header.stamp), sum(abs(e) for e in m.effort[2:]))
            for m in watch['joint_states']]


def _thrusting_for_a_second(watch: Probe) -> bool:
    """The probe has seen the robot hold steadily on its thrusters for a second: the
    total thrust above 1 N and within 30 % (the baseline the attack is judged against;
    right after start-up it is 0, then a transient)."""
    rows = _thrust_rows(watch)
    if not rows or rows[-1][0] - rows[0][0] < NS_PER_S:
        return False
    last = [f for t, f in rows if t >= rows[-1][0] - NS_PER_S]
    return min(last) > 1.0 and max(last) - min(last) <= 0.3 * min(last)


def _assert_thrust_kept(watch: Probe, start: int) -> None:
    """The thrusters kept the real commands' thrust after ``start`` (the attack): the
    median total thrust (sum of |effort|, N) after it is at least half of the least
    over the steady second before. A command standing in for the real ones (zero thrust) takes it to
    about 0 within a few tenths of a second (the robot then sinks: 380 mm in 5 s); the
    depth itself is no test in realtime on a loaded machine, where a late controller
    moves it by centimetres."""
    rows = _thrust_rows(watch)
    before = [f for t, f in rows if start - NS_PER_S <= t <= start]
    during = [f for t, f in rows if t > start]
    assert before and during and min(before) > 1.0, (before[-3:], len(during))
    assert statistics.median(during) > 0.5 * min(before), (
        min(before), statistics.median(during))


#: The plant's odom readers before it starts: the controller, the recorder and the test.
_WAIT_FOR_THE_TEST = ('--param', 'plant_simulator:startup_subscribers:=3')
#: s of sim: the first step after the first tick (every node has answered once).
_FIRST_TICK_ANSWERED = 0.01


def _recorder_stopped(ros: Any, tmp_path: Path, bag: Path, args: tuple[str, ...],
                      stop_at: float, resume_when: Callable[[SimTime, dict[str, int]], bool],
                      *, behind: float = 0.0) -> tuple[int, str]:
    """``tiltrov launch ARGS --record BAG`` with the recorder stopped (SIGSTOP) once
    the sim time reaches ``stop_at`` s and resumed (SIGCONT) ``behind`` s after
    ``resume_when(sim time, pids)`` holds: the launch's exit code and output."""
    sim = SimTime(ros.node('sim_time_probe'))
    launch = LaunchProcess(tmp_path, *args, *_WAIT_FOR_THE_TEST, '--record', str(bag))
    try:
        pids = launch.wait_running()
        assert ros.spin_while_progressing(lambda: sim.reached(stop_at), launch.progress), \
            launch.output
        os.kill(pids['bag_recorder'], signal.SIGSTOP)
        try:
            assert ros.spin_while_progressing(lambda: resume_when(sim, pids),
                                              lambda: (sim.ns, launch.progress())), \
                launch.output
            ros.spin_for(behind)
        finally:
            os.kill(pids['bag_recorder'], signal.SIGCONT)
        code = launch.finish()
    finally:
        launch.cleanup()
    return code, launch.output


def _nan_odom(ns: int) -> Odometry:
    return odometry(ns, [math.nan, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0] * 6)


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_rejected_odometry_stamped_ahead_does_not_take_control(ros: Any,
                                                               tmp_path: Path) -> None:
    """NaN odometry stamped 0.45 s ahead of /clock, every 0.4 s for 5 s (realtime): each
    is rejected, and the robot holds its depth on the real commands (before: the safe
    answer carried the future stamp, the plant dropped the real commands, thrust fell
    to zero and the robot sank 380 mm)."""
    launch = LaunchProcess(tmp_path, '--realtime', '--duration', '600')
    try:
        launch.wait_running()
        probe = ready(ros, STACK, launch, until=_stepping)
        watch = Probe(ros.node('thrust_probe'), ['odom', 'joint_states', '/clock'])
        attacker = ros.node('odom_attacker')
        pub = attacker.create_publisher(Odometry, 'odom', KEEP_ALL)
        assert ros.spin_until(lambda: len(watch['/clock']) > 0 and len(watch['odom']) > 0
                              and pub.get_subscription_count() > 1   # controller, probe
                              and _thrusting_for_a_second(watch), timeout=60.0)
        start = _latest_clock(watch)
        sent = 0
        next_at = start

        def attack() -> bool:
            nonlocal sent, next_at
            now = _latest_clock(watch)
            if now >= next_at and sent < 13:      # a control tick 0.40-0.45 s ahead
                pub.publish(_nan_odom((now + 450_000_000) // TICK * TICK))
                sent += 1
                next_at = now + 400_000_000
            return sent == 13 and now >= start + 5 * NS_PER_S

        assert ros.spin_until(attack, timeout=60.0), launch.output
        # The attack reached the controller and was rejected. Not necessarily all 13: in
        # realtime its odometry reader keeps the latest 5 (sensor data), and a loaded
        # controller may find a NaN sample overwritten by newer odometry (a quiet fresh
        # clone counted fewer than 13); none that is taken takes control.
        assert ros.spin_until(lambda: _count(probe, CONTROLLER, 'rejected_messages') >= 1,
                              timeout=60.0)
        _assert_thrust_kept(watch, start)
        assert _count(probe, CONTROLLER, 'resets') == 0
        assert _count(probe, ALLOCATOR, 'resets') == 0
    finally:
        launch.cleanup()


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_valid_command_stamped_ahead_does_not_shut_out_the_real_ones(ros: Any,
                                                                       tmp_path: Path) -> None:
    """A tool sending a valid thrust_cmd (zero thrust) stamped 0.45 s ahead of the plant,
    every 0.4 s for at least 5 s (realtime): rejected (``future_stamp``: no state it can
    answer has been published), and the robot holds its depth on the real commands
    (before: the plant applies the latest command by stamp, so each one shut out the
    real, earlier-stamped commands and the robot sank).

    The attack goes on until 13 commands have reached the plant ahead of it. "Ahead" is
    judged from the test's view of the plant's time, which a loaded machine can hold back
    by more than the lead: such a command reaches the plant stamped at or before its time,
    is a valid command (the next real one, a tick later, replaces it) and is not counted.
    So the count is a condition, not a share of what was sent."""
    launch = LaunchProcess(tmp_path, '--realtime', '--duration', '600')
    try:
        launch.wait_running()
        probe = ready(ros, STACK, launch, until=_stepping)
        watch = Probe(ros.node('thrust_probe'), ['odom', 'joint_states'])
        pub = ros.node('thrust_attacker').create_publisher(JointState, 'thrust_cmd', KEEP_ALL)
        # The plant's time as fresh as the test can have it (one sample kept): read
        # off the keep-all probe, behind on a loaded machine, a 0.45 s lead once was
        # less than a step at the plant, and the command was taken.
        sim = SimTime(ros.node('sim_time_probe'))
        assert ros.spin_until(lambda: len(watch['odom']) > 0 and sim.ns >= 0
                              and pub.get_subscription_count() > 0
                              and _thrusting_for_a_second(watch), timeout=60.0)
        start = sim.ns
        sent = 0
        next_at = start

        def rejected() -> int:
            return _count(probe, PLANT, 'rejected.thrust_cmd.future_stamp')

        def attack() -> bool:
            nonlocal sent, next_at
            now = sim.ns
            if now >= next_at and rejected() < 13:
                pub.publish(joint_state(now + 450_000_000,
                                        [f'thruster_{i}' for i in range(1, 5)],
                                        effort=[0.0] * 4))
                sent += 1
                next_at = now + 400_000_000
            return rejected() >= 13 and now >= start + 5 * NS_PER_S

        assert ros.spin_until(attack, timeout=300.0), (sent, rejected(), launch.output)
        # Only the attack's commands were ahead: the allocator's real ones never are.
        assert 13 <= rejected() <= sent, (rejected(), sent)
        _assert_thrust_kept(watch, start)
    finally:
        launch.cleanup()


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_rejected_odometry_stamped_back_resets_nothing(ros: Any, tmp_path: Path) -> None:
    """NaN odometry stamped 1 s back (a control tick): rejected before anything acts on
    it (before: the controller reset first, losing the PID integral, and the reset
    cascaded into the allocator)."""
    launch = LaunchProcess(tmp_path, '--realtime', '--duration', '600', '--controller', 'pid')
    try:
        launch.wait_running()
        probe = ready(ros, STACK, launch, until=_stepping)
        watch = Probe(ros.node('clock_probe'), ['/clock'])
        pub = ros.node('odom_attacker').create_publisher(Odometry, 'odom', KEEP_ALL)
        assert ros.spin_until(lambda: len(watch['/clock']) > 0
                              and pub.get_subscription_count() > 0
                              and _latest_clock(watch) > 2 * NS_PER_S)
        back = (_latest_clock(watch) - NS_PER_S) // TICK * TICK

        def rejected() -> bool:
            # Realtime odometry is read best effort, last 5: a sample may be overwritten
            # by the plant's before it is taken; send until one is counted.
            if _count(probe, CONTROLLER, 'rejected.odom.non_finite') == 0:
                pub.publish(_nan_odom(back))
            return _count(probe, CONTROLLER, 'rejected.odom.non_finite') >= 1

        assert ros.spin_until(rejected, timeout=30.0)
        before = len(probe['/diagnostics'])
        assert ros.spin_until(lambda: len(probe['/diagnostics']) > before + 8)
        assert _count(probe, CONTROLLER, 'resets') == 0
        assert _count(probe, ALLOCATOR, 'resets') == 0
        assert 'resetting' not in launch.output and 'forgetting' not in launch.output
    finally:
        launch.cleanup()


#: The topics each node reads (the switching controller's stack: the allocator reads
#: tilt_request too), and the type a sample of each must decode as.
READERS = {
    CONTROLLER: ('odom', 'setpoint', 'setpoint_velocity', '/clock'),
    ALLOCATOR: ('wrench_cmd', 'tilt_request', '/clock'),
    REFERENCE: ('/clock',),
    PLANT: ('thrust_cmd', 'tilt_cmd', 'wrench_cmd', 'wrench_achieved'),   # wrenches: markers
}
TYPES = {'odom': Odometry, 'setpoint': PoseStamped, 'setpoint_velocity': TwistStamped,
         '/clock': Clock, 'wrench_cmd': WrenchStamped, 'tilt_request': JointState,
         'thrust_cmd': JointState, 'tilt_cmd': JointState, 'wrench_achieved': WrenchStamped}


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_truncated_cdr_on_every_topic_a_node_reads_is_rejected_and_counted(
        ros: Any, tmp_path: Path) -> None:
    """Samples cut short (a faulty bridge, a tool writing raw bytes) on every topic the
    nodes read: each node rejects and counts them (``rejected.<topic>.malformed``),
    logs them, and runs on (before: rclpy's typed subscriptions dropped them without
    a count or a log line)."""
    launch = LaunchProcess(tmp_path, '--realtime', '--duration', '600', '--controller',
                           'switching')
    try:
        launch.wait_running()
        probe = ready(ros, STACK, launch, until=_stepping)
        watch = Probe(ros.node('clock_probe'), ['/clock'])
        attacker = ros.node('cdr_attacker')
        pubs = {topic: attacker.create_publisher(msg_type, topic, KEEP_ALL)
                for topic, msg_type in TYPES.items()}
        assert ros.spin_until(lambda: len(watch['/clock']) > 0 and all(
            p.get_subscription_count() > 0 for p in pubs.values()), timeout=30.0)

        def cut(topic: str) -> bytes:
            """A valid sample of ``topic`` stamped at the latest control tick, cut in
            half (odom: also one too short to hold a stamp)."""
            tick = _latest_clock(watch) // TICK * TICK
            msg = TYPES[topic]()
            set_stamp(msg.clock if topic == '/clock' else msg.header.stamp, tick)
            data = serialize_message(msg)
            return data[:len(data) // 2]

        def every_reader_counted() -> bool:
            # Some readers keep only the latest samples, best effort (realtime odometry,
            # rclpy's /clock reader): a sample may be overwritten; send until counted.
            done = True
            for node, topics in READERS.items():
                for topic in topics:
                    if _count(probe, node, f'rejected.{topic}.malformed') == 0:
                        pubs[topic].publish(cut(topic))
                        if topic == 'odom':
                            pubs[topic].publish(b'\x00\x01\x00\x00\x01\x02')
                        done = False
            return done

        assert ros.spin_until(every_reader_counted, timeout=60.0), {
            n: diagnostics(probe, n) for n in STACK}
        assert ros.spin_until(lambda: _stepping(probe) and all(
            _count(probe, n, 'callback_errors') == 0 for n in STACK))
        assert launch.process.poll() is None, launch.output
        assert ros.spin_until(lambda: 'malformed' in launch.output, timeout=10.0)
        assert 'bytes that do not decode as geometry_msgs/msg/WrenchStamped' in launch.output
        assert _stop(launch) == 130, launch.output
    finally:
        launch.cleanup()
    assert 'died' not in launch.output and 'Traceback' not in launch.output, launch.output


# --------------------------------------------------------------------------- tilt_request


def _node_process(node: str, *ros_args: str) -> subprocess.Popen[str]:
    """``node`` started as ``ros2 run`` starts it: the shipped YAML files."""
    return subprocess.Popen(
        [sys.executable, '-m', f'tiltrov_ros.nodes.{node}', '--ros-args',
         '--params-file', str(config_file('robot.yaml')),
         '--params-file', str(config_file(f'{node}.yaml')), *ros_args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _ended(process: subprocess.Popen[str]) -> str:
    """Stop ``process`` (SIGINT) and return its output."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    # To its end, reading what it says meanwhile (a full pipe would block it); a hang
    # is the test's HANG_BOUND's.
    out, _ = process.communicate()
    return out


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_stray_tilt_request_publisher_does_not_silence_the_allocator(ros: Any) -> None:
    """The allocator as shipped (``tilt_request: auto``) under wrenches at 20/s; a stray
    tool creates a tilt_request publisher and sends one request: the wrenches are
    still answered, and /diagnostics names the sender (before: thrust_cmd stopped for
    good, each new wrench replacing the one waiting, diagnostics OK)."""
    process = _node_process(ALLOCATOR)
    try:
        node = ros.node('wrench_source')
        probe = Probe(node, ['thrust_cmd', '/diagnostics'])
        pub = node.create_publisher(WrenchStamped, 'wrench_cmd', KEEP_ALL)
        # The node's start, however slow the machine: up to a hang of its process.
        assert ros.spin_while_progressing(lambda: pub.get_subscription_count() > 0
                                          and bool(diagnostics(probe, ALLOCATOR)),
                                          TreeProgress(process.pid)), process.poll()
        sent: list[int] = []
        next_at = time.monotonic()

        def send(n: int) -> Any:
            """Publish n more wrenches at 20/s (wall), stamped 50 ms apart."""
            goal = len(sent) + n

            def step() -> bool:
                nonlocal next_at
                if len(sent) < goal and time.monotonic() >= next_at:
                    sent.append(len(sent) * TICK)
                    pub.publish(wrench(sent[-1], [0.0, 0.0, 5.0, 0.0, 0.0, 0.0]))
                    next_at += 1.0 / 20
                return len(sent) == goal
            return step

        assert ros.spin_until(send(20), timeout=30.0)
        assert ros.spin_until(lambda: len(probe['thrust_cmd']) == 20)
        stray = ros.node('tilt_stray').create_publisher(JointState, 'tilt_request', KEEP_ALL)
        assert ros.spin_until(lambda: stray.get_subscription_count() > 0)
        stray.publish(joint_state(123 * NS_PER_S, ['tilt_front', 'tilt_rear'],
                                  position=[0.5, 0.5]))
        assert ros.spin_until(send(40), timeout=30.0)
        assert ros.spin_until(lambda: set(probe.stamps('thrust_cmd')) >= set(sent),
                              timeout=10.0), (len(probe['thrust_cmd']), len(sent))

        def says_why() -> bool:
            values = diagnostics(probe, ALLOCATOR)
            return (values.get('tilt_requests_received') == '1'
                    and '/tilt_stray' in values.get('_message', ''))

        assert ros.spin_until(says_why, timeout=10.0)
        values = diagnostics(probe, ALLOCATOR)
        assert values['_level'] == '1' and 'ignored' in values['_message']
        assert values['dropped_wrenches'] == '0' and values['tilt_request_pairing'] == 'free'
    finally:
        out = _ended(process)
    assert 'Traceback' not in out, out


# --------------------------------------------------------------------------- parameter files

#: Files no parameter reader can use, as a user may give them by mistake.
BAD_FILES: dict[str, Any] = {
    'missing': None,
    'not_yaml': 'a: [1, 2\nb: {\n',
    'random_bytes': bytes(range(256)) * 4,
    'top_level_list': '- 1\n- 2\n',
    'alias_bomb': ''.join(f'l{i}: &l{i} [{", ".join([f"*l{i - 1}"] * 9) if i else "x"}]\n'
                          for i in range(9)),
}
NODE_MODULES = ('plant_simulator', 'wrench_controller', 'thrust_allocator',
                'reference_publisher', 'bag_recorder')


def _bad_file(tmp_path: Path, kind: str) -> Path:
    path = tmp_path / f'{kind}.yaml'
    content = BAD_FILES[kind]
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    return path


@pytest.mark.slow
@pytest.mark.parametrize('kind', sorted(BAD_FILES))
@pytest.mark.parametrize('node', NODE_MODULES)
@pytest.mark.timeout(HANG_BOUND)
def test_an_unreadable_parameter_file_stops_a_node_with_one_line(
        tmp_path: Path, node: str, kind: str) -> None:
    path = _bad_file(tmp_path, kind)
    result = run_while_progressing(
        [sys.executable, '-m', f'tiltrov_ros.nodes.{node}', '--ros-args', '--params-file',
         str(path), '-p', f'output:={tmp_path / "bag"}'], cwd=tmp_path)
    assert result.returncode == 1
    assert result.stdout == ''
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f'{node}: cannot read parameter file {path}: '), result.stderr


@pytest.mark.slow
@pytest.mark.parametrize(('args', 'message', 'code'), [
    (('--scenario', '{random_bytes}'), 'cannot read {random_bytes}: not UTF-8 text', 2),
    (('--scenario', '{not_yaml}'), 'cannot read {not_yaml}: not valid YAML: ', 2),
    (('--param', 'wrench_controller:gains.kp:=[1,'),
     '--param wrench_controller:gains.kp:=[1,: the value is not YAML', 2),
], ids=['scenario_random_bytes', 'scenario_not_yaml', 'param_not_yaml'])
@pytest.mark.timeout(HANG_BOUND)
def test_tiltrov_launch_names_an_unreadable_input_in_one_line(
        tmp_path: Path, args: tuple[str, ...], message: str, code: int) -> None:
    files = {kind: _bad_file(tmp_path, kind) for kind in ('random_bytes', 'not_yaml')}
    result = run_while_progressing(
        [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', '--duration', '1',
         *(a.format(**files) for a in args)], cwd=tmp_path)
    assert result.returncode == code
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f'tiltrov launch: {message.format(**files)}'), result.stderr


# --------------------------------------------------------------------------- data loss


@pytest.fixture
def small_disk(tmp_path: Path) -> Any:
    """A 2 MiB tmpfs (the recording outgrows it); skipped where mounting is not allowed."""
    mount = tmp_path / 'small_disk'
    mount.mkdir()
    result = subprocess.run(['mount', '-t', 'tmpfs', '-o', 'size=2m', 'tmpfs', str(mount)],
                            capture_output=True, text=True)
    if result.returncode != 0:
        pytest.skip(f'cannot mount a tmpfs here: {result.stderr.strip()}')
    try:
        yield mount
    finally:
        subprocess.run(['umount', '-l', str(mount)], check=False)


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_recording_into_a_full_disk_fails_the_launch_and_says_what_was_lost(
        tmp_path: Path, small_disk: Path) -> None:
    """``tiltrov launch --record`` into a 2 MiB disk: the stack runs to the end, the
    launch exits 1 saying the recording lost data (before: exit code 0)."""
    bag = small_disk / 'bag'
    result = run_while_progressing(
        [sys.executable, '-m', 'tiltrov_ros.cli', 'launch', '--duration', '30',
         '--record', str(bag)], cwd=tmp_path)
    assert result.returncode == 1, result.stdout + result.stderr
    assert 'reached the end of the run at 30.000 s' in result.stdout
    assert 'bag_recorder: data lost in' in result.stdout
    assert 'No space left on device' in result.stdout
    assert 'tiltrov launch: failed: the recording lost data' in result.stderr
    assert 'Traceback' not in result.stdout + result.stderr


def _bag_info(bag: Path) -> str:
    result = run_while_progressing([sys.executable, '-m', 'tiltrov_ros.cli', 'bag', 'info',
                                    str(bag)])
    assert result.returncode == 0, result.stdout + result.stderr
    return result.stdout


def _stamps(bag: Path) -> dict[str, set[int]]:
    """The stamps (ms) recorded on each topic that has them."""
    from tiltrov_ros.bag.bagfile import iter_raw
    from tiltrov_ros.bag.cdr import leading_stamp_ns

    stamps: dict[str, set[int]] = {}
    for raw in iter_raw(bag):
        stamp = leading_stamp_ns(raw.data, raw.msgtype)
        if stamp is not None:
            stamps.setdefault(raw.topic, set()).add(stamp // 1_000_000)
    return stamps


def _loss_report(bag: Path, output: str, info: str) -> list[str]:
    """What the bag's own evidence says it lost (:func:`tiltrov_ros.bag.losses.losses`),
    after checking that the launch and ``tiltrov bag info`` say exactly that."""
    from tiltrov_ros.bag.losses import losses

    found = [line.strip() for line in losses(bag).lines()]
    printed = output.split('tiltrov launch: failed: the recording lost data', 1)[-1]
    said = [line.strip() for line in printed.splitlines()[1:] if line.startswith('  ')]
    assert said == found, (said, found)
    assert all(line in info for line in found), (found, info)
    return found


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_recorder_that_falls_behind_fails_the_launch_and_bag_info_says_what_was_lost(
        ros: Any, tmp_path: Path) -> None:
    """The recorder stopped (SIGSTOP) for 135 s of a realtime run at x10: more samples
    go by than the writers keep for a reader that does not acknowledge (10000 steps of
    the plant's state, 1000 ticks) and than a transport buffers for it (the plant alone
    sends some 150 kB per second of sim; a socket here buffers at most 4 MB), so the
    recording loses them for real, as an overloaded recorder does. The launch exits 1
    saying what was lost, and ``tiltrov bag info`` says the same (before: exit code 0;
    an unrelated flood of 147 000 msg/s made the recorder lose 1 874 odom and the
    launch exited 0 too). What the report
    holds (topics short, nodes whose final counts never came, samples DDS reported
    lost) depends on what the transport delivered once the recorder resumed, and
    varied from run to run: it is checked against the bag's own evidence."""
    bag = tmp_path / 'bag'
    code, output = _recorder_stopped(
        ros, tmp_path, bag, ('--realtime', '--real-time-factor', '10', '--duration', '150'),
        5, lambda sim, _: sim.reached(140))
    assert code == 1, output
    assert _loss_report(bag, output, _bag_info(bag))
    assert 'Traceback' not in output


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_stopped_recorder_holds_a_paced_run_and_nothing_is_lost(ros: Any,
                                                                  tmp_path: Path) -> None:
    """The recorder stopped (SIGSTOP) from the first tick of a recorded 60 s lockstep run
    (a recorder starved on a loaded machine): the plant, paced by it, stops at most
    ``recorder_window`` of sim time ahead of what the bag has and says it waits for it
    (``waiting_for_recorder``, not a stall); resumed (SIGCONT), the run goes on, the bag
    has every step and tick and the launch exits 0 (before: nothing waited for the
    recorder, which lost what overflowed the writers' histories)."""
    bag = tmp_path / 'bag'
    sim = SimTime(ros.node('sim_time_probe'))
    # 60 s: the stop must land before the recorder has written all but the last window
    # (an 8 s run went by unpaced in 0.85 s wall while a loaded test was still reacting).
    launch = LaunchProcess(tmp_path, '--duration', '60', *_WAIT_FOR_THE_TEST,
                           '--record', str(bag))
    try:
        pids = launch.wait_running()
        probe = ready(ros, (PLANT,), launch)
        assert ros.spin_while_progressing(lambda: sim.reached(_FIRST_TICK_ANSWERED),
                                          launch.progress), launch.output
        os.kill(pids['bag_recorder'], signal.SIGSTOP)
        try:
            def held() -> bool:
                plant = diagnostics(probe, PLANT)
                return plant.get('waiting_for_recorder') == 'True'

            assert ros.spin_until(held, timeout=60.0), launch.output
            plant = diagnostics(probe, PLANT)
            # recorder_window (1 s) ahead of its progress at most, and not a stall
            assert float(plant['sim_time']) <= 1.0 + 0.05 + float(plant['recorder_progress'] or 0)
            assert plant['waiting_for'] == 'bag_recorder (paced)'
        finally:
            os.kill(pids['bag_recorder'], signal.SIGCONT)
        code = launch.finish()
    finally:
        launch.cleanup()
    assert code == 0, launch.output
    stamps = _stamps(bag)
    steps = set(range(0, 60_001, 10))
    ticks = set(range(0, 60_000, 50))
    for topic in ('/odom', '/joint_states', '/clock'):
        assert stamps[topic] == steps, (topic, len(stamps[topic]))
    for topic in ('/setpoint', '/setpoint_velocity', '/wrench_cmd', '/thrust_cmd',
                  '/tilt_cmd', '/wrench_achieved'):
        assert stamps[topic] == ticks, (topic, len(stamps[topic]))
    assert "lost:      nothing (the nodes' counts and the recorder agree)" in _bag_info(bag)


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_killed_recorder_ends_the_run_with_exit_1_naming_it(ros: Any,
                                                               tmp_path: Path) -> None:
    """kill -9 of the recorder mid-run (lockstep, paced by it): nothing waits for it any
    more; the launch ends, exit 1, naming it (the bag is not whole)."""
    bag = tmp_path / 'bag'
    sim = SimTime(ros.node('sim_time_probe'))
    launch = LaunchProcess(tmp_path, '--duration', '600', *_WAIT_FOR_THE_TEST,
                           '--record', str(bag))
    try:
        pids = launch.wait_running()
        assert ros.spin_while_progressing(lambda: sim.reached(1.0), launch.progress), \
            launch.output
        os.kill(pids['bag_recorder'], signal.SIGKILL)
        code = launch.finish()
    finally:
        launch.cleanup()
    assert code == 1, launch.output
    assert f'bag_recorder died (exit code {-signal.SIGKILL})' in launch.output
    assert not any(alive(pid) for pid in pids.values())


# --------------------------------------------------------------------------- smaller ones


@pytest.mark.timeout(HANG_BOUND)
def test_bag_repair_of_a_garbage_metadata_file_is_one_line(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    result = run_while_progressing([sys.executable, '-m', 'tiltrov_ros.cli', 'launch',
                                    '--duration', '0.5', '--record', str(bag)], cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    (bag / 'metadata.yaml').write_bytes(bytes(range(256)) * 8)
    repaired = run_while_progressing([sys.executable, '-m', 'tiltrov_ros.cli', 'bag',
                                      'repair', str(bag)])
    assert repaired.returncode == 0, repaired.stdout + repaired.stderr
    assert 'Traceback' not in repaired.stdout + repaired.stderr
    assert 'recovered' in repaired.stdout


@pytest.mark.slow
@pytest.mark.timeout(HANG_BOUND)
def test_a_huge_frame_id_is_cut_in_the_log_and_a_second_plant_is_named(ros: Any) -> None:
    """Odometry with a 1 MB frame_id: the controller's log grows by a few kB, not
    megabytes. Two nodes publishing odom (a second simulator): the controller's
    /diagnostics names both."""
    process = _node_process(CONTROLLER)
    try:
        probe = Probe(ros.node('diagnostics_probe'), ['/diagnostics'])
        pubs = [ros.node(name).create_publisher(Odometry, 'odom', KEEP_ALL)
                for name in ('first_plant', 'second_plant')]
        # The node's start, however slow the machine: up to a hang of its process.
        assert ros.spin_while_progressing(lambda: all(p.get_subscription_count() > 0
                                                      for p in pubs)
                                          and bool(diagnostics(probe, CONTROLLER)),
                                          TreeProgress(process.pid)), process.poll()
        sent = 0
        last_sent = -1.0

        def named() -> bool:
            nonlocal sent, last_sent
            values = diagnostics(probe, CONTROLLER)
            # Best effort (realtime odometry): a 1 MB sample is some 16 datagrams and
            # a burst of them overflows a loaded reader's socket, so one goes every
            # 0.5 s until the controller has rejected one.
            if (not values.get('rejected.odom.wrong_frame')
                    and time.monotonic() - last_sent > 0.5):
                msg = odometry(sent * TICK, [0.0] * 3, [1.0, 0.0, 0.0, 0.0], [0.0] * 6)
                msg.header.frame_id = 'x' * 1_000_000
                pubs[1].publish(msg)
                sent += 1
                last_sent = time.monotonic()
            return (int(values.get('rejected.odom.wrong_frame', '0')) >= 1
                    and '/first_plant' in values.get('publishers./odom', '')
                    and '/second_plant' in values.get('publishers./odom', ''))

        assert ros.spin_until(named, timeout=30.0), diagnostics(probe, CONTROLLER)
        assert '2 publishers of /odom' in diagnostics(probe, CONTROLLER)['_message']
    finally:
        out = _ended(process)
    assert 'Traceback' not in out
    assert len(out) < 10_000, len(out)
    assert '(1000000 characters)' in out
