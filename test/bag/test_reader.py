"""read_runlog: a synthetic bag with known values gives exactly the expected RunLog."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
from numpy.testing import assert_array_equal
import pytest

from tiltrov_ros.bag.bagfile import RUN_INFO_KEY
from tiltrov_ros.bag.msgdefs import typestore
from tiltrov_ros.bag.reader import POSE, WRENCH, read_runlog, read_series
from tiltrov_ros.bag.writer import BagWriter
from tiltrov_ros.core.errors import BagError

STORE = typestore()
T = STORE.types
N = 26                # plant steps, h = 10 ms
H = 10_000_000        # ns
EVERY = 5             # control period T = 5 h
TICKS = list(range(0, N, EVERY))
RUN_INFO = {'scenario': 'positioning', 'controller': 'pd', 'tilt_rate_limit': 2.618}
# joint_states lists the joints in this (unusual) order: the reader goes by name
JOINT_ORDER = ['tilt_rear', 'thruster_3', 'thruster_1', 'tilt_front', 'thruster_4', 'thruster_2']


def header(ns: int, frame: str = 'odom_ned') -> Any:
    sec, nanosec = divmod(ns, 1_000_000_000)
    time = T['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)
    return T['std_msgs/msg/Header'](stamp=time, frame_id=frame)


def vec(x: float, y: float, z: float) -> Any:
    return T['geometry_msgs/msg/Vector3'](x=x, y=y, z=z)


def quat_xyzw(i: float) -> tuple[float, float, float, float]:
    x, y, z = 0.01 * i, -0.02 * i, 0.03
    return x, y, z, float(np.sqrt(1.0 - x * x - y * y - z * z))


def pose(position: tuple[float, float, float], q: tuple[float, float, float, float]) -> Any:
    return T['geometry_msgs/msg/Pose'](
        position=T['geometry_msgs/msg/Point'](x=position[0], y=position[1], z=position[2]),
        orientation=T['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2], w=q[3]))


def odom(i: int) -> Any:
    cov = np.zeros(36)
    return T['nav_msgs/msg/Odometry'](
        header=header(i * H), child_frame_id='base_link_frd',
        pose=T['geometry_msgs/msg/PoseWithCovariance'](
            pose=pose((1.0 * i, 2.0 * i, -0.5 * i), quat_xyzw(i)), covariance=cov),
        twist=T['geometry_msgs/msg/TwistWithCovariance'](
            twist=T['geometry_msgs/msg/Twist'](linear=vec(0.1 * i, 0.2, -0.3),
                                               angular=vec(0.01, -0.02 * i, 0.5)),
            covariance=cov))


def joint_values(i: int) -> dict[str, tuple[float, float, float]]:
    """name -> (position, velocity, effort) at step i."""
    return {'tilt_front': (0.1 * i, 0.5, 0.0), 'tilt_rear': (-0.1 * i, -0.5, 0.0),
            **{f'thruster_{k}': (0.0, 0.0, 10.0 * k + i) for k in range(1, 5)}}


def joint_state(ns: int, names: list[str], values: dict[str, tuple[float, float, float]],
                fields: str = 'pve') -> Any:
    def column(k: int, letter: str) -> np.ndarray:
        return np.array([values[n][k] for n in names] if letter in fields else [], dtype=float)
    return T['sensor_msgs/msg/JointState'](
        header=header(ns, ''), name=names, position=column(0, 'p'),
        velocity=column(1, 'v'), effort=column(2, 'e'))


def wrench(ns: int, values: list[float]) -> Any:
    return T['geometry_msgs/msg/WrenchStamped'](
        header=header(ns, 'base_link_frd'), wrench=T['geometry_msgs/msg/Wrench'](
            force=vec(*values[:3]), torque=vec(*values[3:])))


def setpoint(tick: int) -> Any:
    return T['geometry_msgs/msg/PoseStamped'](
        header=header(tick * H), pose=pose((5.0 + tick, -1.0, 2.0), quat_xyzw(-tick)))


def setpoint_velocity(tick: int) -> Any:
    return T['geometry_msgs/msg/TwistStamped'](
        header=header(tick * H), twist=T['geometry_msgs/msg/Twist'](
            linear=vec(0.25, 0.0, -0.1 * tick), angular=vec(0.0, 0.0, 0.02)))


def wrench_cmd_values(tick: int) -> list[float]:
    return [1.0 * tick, -2.0, 3.0, 0.1, -0.2 * tick, 0.3]


def write_bag(path: Path, ns: str = '/rov1', *, with_velocity: bool = True,
              extra_namespace: str | None = None) -> None:
    """The synthetic run (see the module's expected values below)."""
    types = {'odom': 'nav_msgs/msg/Odometry', 'joint_states': 'sensor_msgs/msg/JointState',
             'setpoint': 'geometry_msgs/msg/PoseStamped',
             'setpoint_velocity': 'geometry_msgs/msg/TwistStamped',
             'wrench_cmd': 'geometry_msgs/msg/WrenchStamped',
             'thrust_cmd': 'sensor_msgs/msg/JointState',
             'tilt_cmd': 'sensor_msgs/msg/JointState',
             'wrench_achieved': 'geometry_msgs/msg/WrenchStamped'}
    if not with_velocity:
        del types['setpoint_velocity']
    log: list[tuple[int, str, Any]] = []   # (log time, relative topic, message)
    for i in range(N):
        t = 1_000 * H + i * H  # log times: unrelated to the stamps
        log.append((t, 'odom', odom(i)))
        if i != N - 1:  # the last joint_states never made it into the bag
            # step 3's joint_states is logged after step 4's: order is by stamp
            log.append((t + (H + 1 if i == 3 else 1), 'joint_states',
                        joint_state(i * H, JOINT_ORDER, joint_values(i))))
        if i in TICKS:
            tick = i
            if tick != 15:  # no new setpoint at this tick: the one of tick 10 holds
                log.append((t + 2, 'setpoint', setpoint(tick)))
                if with_velocity:
                    log.append((t + 2, 'setpoint_velocity', setpoint_velocity(tick)))
            log.append((t + 3, 'wrench_cmd', wrench(tick * H, wrench_cmd_values(tick))))
            thr = {f'thruster_{k}': (0.0, 0.0, -5.0 * k + tick) for k in range(1, 5)}
            log.append((t + 4, 'thrust_cmd', joint_state(
                tick * H, ['thruster_4', 'thruster_3', 'thruster_2', 'thruster_1'], thr, 'e')))
            tilt = {'tilt_front': (0.02 * tick, 0.0, 0.0), 'tilt_rear': (-0.03 * tick, 0.0, 0.0)}
            log.append((t + 4, 'tilt_cmd', joint_state(tick * H, ['tilt_front', 'tilt_rear'],
                                                       tilt, 'p')))
            log.append((t + 5, 'wrench_achieved',
                        wrench(tick * H, [v * 0.5 for v in wrench_cmd_values(tick)])))
    # A second wrench_cmd for tick 5, recorded later (a replayed duplicate): the last wins.
    log.append((2_000 * H, 'wrench_cmd', wrench(5 * H, [9.0, 9.0, 9.0, 9.0, 9.0, 9.0])))
    log.sort(key=lambda item: item[0])
    with BagWriter(path, custom_data={RUN_INFO_KEY: json.dumps(RUN_INFO)}) as bag:
        namespaces = [ns] + ([extra_namespace] if extra_namespace is not None else [])
        for space in namespaces:
            conns = {rel: bag.add_topic(f'{space}/{rel}', msgtype)
                     for rel, msgtype in types.items()}
            for log_time, rel, msg in log:
                if rel in conns:
                    bag.write(conns[rel], log_time, STORE.serialize_cdr(msg, types[rel]))


def wxyz(q: tuple[float, float, float, float]) -> list[float]:
    return [q[3], q[0], q[1], q[2]]


def test_runlog_has_exactly_the_recorded_values(tmp_path: Path) -> None:
    write_bag(tmp_path / 'bag')
    log = read_runlog(tmp_path / 'bag', progress=False)
    steps = np.arange(N)

    assert_array_equal(log.t, steps * H / 1e9)
    assert_array_equal(log.position, [[1.0 * i, 2.0 * i, -0.5 * i] for i in steps])
    assert_array_equal(log.quaternion, [wxyz(quat_xyzw(i)) for i in steps])
    assert_array_equal(log.nu, [[0.1 * i, 0.2, -0.3, 0.01, -0.02 * i, 0.5] for i in steps])
    expected_tilt = [[0.1 * i, -0.1 * i] for i in steps[:-1]] + [[np.nan, np.nan]]
    assert_array_equal(log.tilt_position, expected_tilt)
    assert_array_equal(log.tilt_velocity, [[0.5, -0.5]] * (N - 1) + [[np.nan, np.nan]])
    assert_array_equal(log.thrust, [[10.0 + i, 20.0 + i, 30.0 + i, 40.0 + i]
                                    for i in steps[:-1]] + [[np.nan] * 4])

    ticks = np.array(TICKS)
    assert_array_equal(log.tc, ticks * H / 1e9)
    held = [10 if k == 15 else k for k in TICKS]  # tick 15 uses the setpoint of tick 10
    assert_array_equal(log.setpoint_position, [[5.0 + k, -1.0, 2.0] for k in held])
    assert_array_equal(log.setpoint_quaternion, [wxyz(quat_xyzw(-k)) for k in held])
    assert_array_equal(log.setpoint_velocity, [[0.25, 0.0, -0.1 * k, 0.0, 0.0, 0.02]
                                               for k in held])
    expected_cmd = [wrench_cmd_values(k) for k in TICKS]
    expected_cmd[1] = [9.0] * 6  # the duplicate recorded last
    assert_array_equal(log.wrench_cmd, expected_cmd)
    assert_array_equal(log.thrust_cmd, [[-5.0 * j + k for j in range(1, 5)] for k in TICKS])
    assert_array_equal(log.tilt_cmd, [[0.02 * k, -0.03 * k] for k in TICKS])
    assert_array_equal(log.wrench_achieved, [[v * 0.5 for v in wrench_cmd_values(k)]
                                             for k in TICKS])

    assert {k: log.meta[k] for k in RUN_INFO} == RUN_INFO
    bag = log.meta['bag']
    assert bag['namespace'] == '/rov1'
    assert bag['missing'] == {'tilt_position': 1, 'tilt_velocity': 1, 'thrust': 1}
    assert bag['duplicate_stamps'] == {'/rov1/wrench_cmd': 1}
    assert bag['message_counts']['/rov1/odom'] == N


def test_reading_the_mcap_file_and_a_namespace_given(tmp_path: Path) -> None:
    write_bag(tmp_path / 'bag', ns='')
    log = read_runlog(tmp_path / 'bag' / 'bag.mcap', namespace='', progress=False)
    assert len(log.t) == N and len(log.tc) == len(TICKS)
    assert log.meta['bag']['namespace'] == ''
    assert json.loads(json.dumps(log.meta)) == log.meta  # JSON-serialisable, as RunLog wants
    log.save_npz(tmp_path / 'log.npz')
    assert_array_equal(type(log).load_npz(tmp_path / 'log.npz').wrench_cmd, log.wrench_cmd)


def test_setpoint_velocity_is_optional(tmp_path: Path) -> None:
    write_bag(tmp_path / 'bag', with_velocity=False)
    log = read_runlog(tmp_path / 'bag', progress=False)
    assert_array_equal(log.setpoint_velocity, np.zeros((len(TICKS), 6)))


def test_namespace_must_be_unambiguous(tmp_path: Path) -> None:
    write_bag(tmp_path / 'two', extra_namespace='/rov2')
    with pytest.raises(BagError, match='several odom'):
        read_runlog(tmp_path / 'two', progress=False)
    assert read_runlog(tmp_path / 'two', namespace='/rov2', progress=False).meta['bag'][
        'namespace'] == '/rov2'
    with BagWriter(tmp_path / 'none') as bag:
        bag.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
    with pytest.raises(BagError, match='no odom'):
        read_runlog(tmp_path / 'none', progress=False)


def test_read_series_checks_types_and_sorts_by_stamp(tmp_path: Path) -> None:
    write_bag(tmp_path / 'bag')
    series = read_series(tmp_path / 'bag', {'/rov1/wrench_cmd': WRENCH,
                                            '/rov1/no_such_topic': WRENCH}, progress=False)
    assert list(series) == ['/rov1/wrench_cmd']
    wrench_series = series['/rov1/wrench_cmd']
    assert_array_equal(wrench_series.stamps, np.array(TICKS) * H)
    assert (np.diff(wrench_series.stamps) > 0).all()
    with pytest.raises(BagError, match='expected geometry_msgs/msg/PoseStamped'):
        read_series(tmp_path / 'bag', {'/rov1/wrench_cmd': POSE}, progress=False)


def test_progress_bar_on_request(tmp_path, capsys) -> None:
    """progress=True shows the shared stderr bar at once; False shows nothing."""
    write_bag(tmp_path / 'bag')
    read_series(tmp_path / 'bag', {'/rov1/wrench_cmd': WRENCH}, progress=True)
    assert 'reading bag' in capsys.readouterr().err
    read_series(tmp_path / 'bag', {'/rov1/wrench_cmd': WRENCH}, progress=False)
    assert capsys.readouterr().err == ''
