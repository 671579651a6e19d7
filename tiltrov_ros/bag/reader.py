"""Reading a tiltrov bag into a :class:`~tiltrov_ros.core.runlog.RunLog`.

Two layers, so the analysis (``tiltrov analyze``) and re-running parts of the
stack on recorded inputs can plug in at either:

* :func:`read_series` decodes chosen topics in one pass over the bag (rosbags'
  pure Python CDR decoder, no rclpy) into :class:`Series`: header stamps (int
  ns) and named float columns, sorted by stamp;
* :func:`read_runlog` builds the two grids of ARCHITECTURE.md from them by the
  stamp contract:

  - plant grid: one row per ``odom`` stamp; ``joint_states`` with the same
    stamp gives the tilt angles and rates and the thrusts;
  - control grid: one row per ``wrench_cmd`` stamp (the control ticks);
    ``thrust_cmd``, ``tilt_cmd`` and ``wrench_achieved`` with the same stamp
    (they answer that ``wrench_cmd``); ``setpoint`` and ``setpoint_velocity``
    in force at the tick: the latest with a stamp at or before it (equal in
    lockstep, the latest in realtime mode).

  A value the bag lacks is NaN (a killed recorder loses the tail, say), and
  ``meta['bag']['missing']`` counts them; ``setpoint_velocity`` is optional
  and reads as zero when the bag has no such topic at all. Repeated stamps
  (e.g. a looped replay) keep the last message recorded.

Times are the header stamps converted by :func:`core.timebase.seconds`, never
the log times. Quaternions are converted from ROS (x, y, z, w) to (w, x, y, z).
``RunLog.meta`` is the recorder's ``run_info`` plus ``meta['bag']``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..core.errors import BagError
from ..core.runlog import CONTROL_FIELDS, PLANT_FIELDS, FloatArray, RunLog
from ..core.timebase import seconds, stamp_to_ns
from ..progress import ProgressBar
from .bagfile import bag_info, open_reader
from .msgdefs import typestore
from .topics import join_namespace

NAN = math.nan
THRUSTERS = ('thruster_1', 'thruster_2', 'thruster_3', 'thruster_4')
TILTS = ('tilt_front', 'tilt_rear')

Row = Sequence[float]


@dataclass(frozen=True)
class Decoder:
    """How to turn one message type into a row of named float columns."""

    msgtype: str
    columns: dict[str, int]             # column name -> width
    extract: Callable[[Any], Row]       # decoded message -> flat row

    @property
    def width(self) -> int:
        return sum(self.columns.values())


def _vec(v: Any) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


def _quat_wxyz(q: Any) -> tuple[float, float, float, float]:
    return (q.w, q.x, q.y, q.z)


def _odometry(m: Any) -> Row:
    pose, twist = m.pose.pose, m.twist.twist
    return (*_vec(pose.position), *_quat_wxyz(pose.orientation),
            *_vec(twist.linear), *_vec(twist.angular))


def _joint_values(m: Any, names: Sequence[str], attribute: str) -> list[float]:
    """Values of ``attribute`` (position/velocity/effort) of joints ``names``, NaN if absent."""
    index = {name: i for i, name in enumerate(m.name)}
    values = getattr(m, attribute)
    out = []
    for name in names:
        i = index.get(name)
        out.append(float(values[i]) if i is not None and i < len(values) else NAN)
    return out


def _plant_joints(m: Any) -> Row:
    return (_joint_values(m, TILTS, 'position') + _joint_values(m, TILTS, 'velocity')
            + _joint_values(m, THRUSTERS, 'effort'))


def _pose(m: Any) -> Row:
    return (*_vec(m.pose.position), *_quat_wxyz(m.pose.orientation))


def _twist(m: Any) -> Row:
    return (*_vec(m.twist.linear), *_vec(m.twist.angular))


def _wrench(m: Any) -> Row:
    return (*_vec(m.wrench.force), *_vec(m.wrench.torque))


ODOMETRY = Decoder('nav_msgs/msg/Odometry', {'position': 3, 'quaternion': 4, 'nu': 6},
                   _odometry)
PLANT_JOINTS = Decoder('sensor_msgs/msg/JointState',
                       {'tilt_position': 2, 'tilt_velocity': 2, 'thrust': 4}, _plant_joints)
SETPOINT = Decoder('geometry_msgs/msg/PoseStamped', {'position': 3, 'quaternion': 4}, _pose)
SETPOINT_VELOCITY = Decoder('geometry_msgs/msg/TwistStamped', {'velocity': 6}, _twist)
WRENCH = Decoder('geometry_msgs/msg/WrenchStamped', {'wrench': 6}, _wrench)
THRUST_CMD = Decoder('sensor_msgs/msg/JointState', {'thrust': 4},
                     lambda m: _joint_values(m, THRUSTERS, 'effort'))
TILT_CMD = Decoder('sensor_msgs/msg/JointState', {'tilt': 2},
                   lambda m: _joint_values(m, TILTS, 'position'))

# relative topic name -> decoder, for the RunLog
RUNLOG_TOPICS: dict[str, Decoder] = {
    'odom': ODOMETRY,
    'joint_states': PLANT_JOINTS,
    'setpoint': SETPOINT,
    'setpoint_velocity': SETPOINT_VELOCITY,
    'wrench_cmd': WRENCH,
    'thrust_cmd': THRUST_CMD,
    'tilt_cmd': TILT_CMD,
    'wrench_achieved': WRENCH,
}


@dataclass
class Series:
    """One topic decoded: rows sorted by header stamp, one row per stamp."""

    topic: str
    stamps: NDArray[np.int64]           # header stamps, ns
    log_times: NDArray[np.int64]        # log times, ns
    columns: dict[str, FloatArray]      # name -> (n,) or (n, width)
    duplicates: int = 0                 # messages dropped for a repeated stamp

    def __len__(self) -> int:
        return len(self.stamps)


def _series(topic: str, decoder: Decoder, stamps: list[int], log_times: list[int],
            rows: list[Row]) -> Series:
    stamp_arr = np.asarray(stamps, dtype=np.int64)
    log_arr = np.asarray(log_times, dtype=np.int64)
    table = np.asarray(rows, dtype=float).reshape(len(rows), decoder.width)
    order = np.argsort(stamp_arr, kind='stable')
    stamp_arr, log_arr, table = stamp_arr[order], log_arr[order], table[order]
    # keep the last message of each stamp (in recording order)
    keep = np.ones(len(stamp_arr), dtype=bool)
    keep[:-1] = stamp_arr[1:] != stamp_arr[:-1]
    duplicates = int(len(keep) - keep.sum())
    stamp_arr, log_arr, table = stamp_arr[keep], log_arr[keep], table[keep]
    columns: dict[str, FloatArray] = {}
    start = 0
    for name, width in decoder.columns.items():
        columns[name] = table[:, start:start + width]
        start += width
    return Series(topic, stamp_arr, log_arr, columns, duplicates)


def read_series(path: str | Path, decoders: Mapping[str, Decoder], *,
                progress: bool | None = None) -> dict[str, Series]:
    """Decode the topics named in ``decoders`` (absolute names) in one pass.

    Topics absent from the bag are absent from the result. ``progress``:
    True/False to force the stderr progress bar on or off, None for automatic.

    Raises:
        BagError: unreadable bag, a topic of another type than its decoder's,
            or a message without a header.

    """
    store = typestore()
    with open_reader(path) as reader:
        connections = [c for c in reader.connections if c.topic in decoders]
        for conn in connections:
            if conn.msgtype != decoders[conn.topic].msgtype:
                raise BagError(f'{conn.topic} is {conn.msgtype} in {path}, '
                               f'expected {decoders[conn.topic].msgtype}')
        collected: dict[str, tuple[list[int], list[int], list[Row]]] = {
            c.topic: ([], [], []) for c in connections}
        total = sum(c.msgcount for c in connections)
        # None: a bar only if the read takes over a second; True: at once.
        with ProgressBar(f'reading {Path(path).name}',
                         delay=0.0 if progress else 1.0) as bar:
            show = progress is not False and total > 0
            for i, (conn, log_time, data) in enumerate(
                    reader.messages(connections=connections) if connections else ()):
                msg: Any = store.deserialize_cdr(data, conn.msgtype)
                stamps, logs, rows = collected[conn.topic]
                stamp = msg.header.stamp
                stamps.append(stamp_to_ns(stamp.sec, stamp.nanosec))
                logs.append(log_time)
                rows.append(decoders[conn.topic].extract(msg))
                if show and i % 1024 == 0:
                    bar(i / total)
            if show:
                bar(1.0)
    return {topic: _series(topic, decoders[topic], *parts)
            for topic, parts in collected.items()}


def _times(stamps: NDArray[np.int64]) -> FloatArray:
    return np.array([seconds(int(ns)) for ns in stamps], dtype=float)


def rows_at(ticks: NDArray[np.int64], series: Series | None, column: str,
           width: int) -> tuple[FloatArray, int]:
    """Rows of ``series`` stamped exactly at ``ticks``; NaN rows where absent."""
    out = np.full((len(ticks), width), NAN)
    if series is None or not len(series):
        return out, len(ticks)
    idx = np.clip(np.searchsorted(series.stamps, ticks), 0, len(series) - 1)
    hit = series.stamps[idx] == ticks
    out[hit] = series.columns[column][idx[hit]]
    return out, int(len(ticks) - hit.sum())


def rows_as_of(ticks: NDArray[np.int64], series: Series | None, column: str,
           width: int) -> tuple[FloatArray, int]:
    """Rows of ``series`` with the latest stamp at or before each tick; NaN before the first."""
    out = np.full((len(ticks), width), NAN)
    if series is None or not len(series):
        return out, len(ticks)
    idx = np.searchsorted(series.stamps, ticks, side='right') - 1
    hit = idx >= 0
    out[hit] = series.columns[column][idx[hit]]
    return out, int(len(ticks) - hit.sum())


def find_namespace(topics: Mapping[str, str], relative: str = 'odom',
                   msgtype: str = ODOMETRY.msgtype) -> str:
    """The namespace of the one ``relative`` topic of type ``msgtype`` among ``topics``
    (name -> type); by default the stack's ``odom`` (nav_msgs/Odometry)."""
    suffix = f'/{relative}'
    found = sorted(name[:-len(suffix)] for name, kind in topics.items()
                   if name.endswith(suffix) and kind == msgtype)
    if len(found) == 1:
        return found[0]
    if not found:
        raise BagError(f'the bag has no {relative} topic ({msgtype})')
    raise BagError(f'the bag has several {relative} topics '
                   f'({", ".join(n + suffix for n in found)}); pass the namespace')


def read_runlog(path: str | Path, *, namespace: str | None = None,
                progress: bool | None = None) -> RunLog:
    """Read a tiltrov bag into a :class:`RunLog` (see the module docstring).

    Args:
        path: the bag directory or its ``.mcap`` file.
        namespace: the stack's namespace in the bag (``''`` for none); None
            finds it from the bag's single ``odom`` topic.
        progress: force the stderr progress bar on or off (None: automatic).

    Raises:
        BagError: unreadable bag, no (or several) ``odom`` topics, wrong types.

    """
    info = bag_info(path)
    if namespace is None:
        namespace = find_namespace({n: t.msgtype for n, t in info.topics.items()})
    names = {rel: join_namespace(namespace, rel) for rel in RUNLOG_TOPICS}
    series = read_series(path, {names[rel]: dec for rel, dec in RUNLOG_TOPICS.items()},
                         progress=progress)

    def get(rel: str) -> Series | None:
        return series.get(names[rel])

    missing: dict[str, int] = {}
    odom = get('odom')
    if odom is None:
        raise BagError(f'{path} has no {names["odom"]} messages')
    ticks = odom.stamps
    arrays: dict[str, FloatArray] = {
        't': _times(ticks),
        'position': odom.columns['position'],
        'quaternion': odom.columns['quaternion'],
        'nu': odom.columns['nu'],
    }
    for name in ('tilt_position', 'tilt_velocity', 'thrust'):
        arrays[name], missing[name] = rows_at(ticks, get('joint_states'), name,
                                             PLANT_FIELDS[name])

    wrench_cmd = get('wrench_cmd')
    control = wrench_cmd.stamps if wrench_cmd is not None else np.zeros(0, dtype=np.int64)
    arrays['tc'] = _times(control)
    control_sources: dict[str, tuple[str, str, Callable[..., tuple[FloatArray, int]]]] = {
        'setpoint_position': ('setpoint', 'position', rows_as_of),
        'setpoint_quaternion': ('setpoint', 'quaternion', rows_as_of),
        'setpoint_velocity': ('setpoint_velocity', 'velocity', rows_as_of),
        'wrench_cmd': ('wrench_cmd', 'wrench', rows_at),
        'thrust_cmd': ('thrust_cmd', 'thrust', rows_at),
        'tilt_cmd': ('tilt_cmd', 'tilt', rows_at),
        'wrench_achieved': ('wrench_achieved', 'wrench', rows_at),
    }
    for name, (rel, column, join) in control_sources.items():
        if name == 'setpoint_velocity' and names[rel] not in info.topics:
            arrays[name] = np.zeros((len(control), CONTROL_FIELDS[name]))
            continue
        arrays[name], missing[name] = join(control, get(rel), column, CONTROL_FIELDS[name])

    meta = dict(info.run_info)
    meta['bag'] = {
        'path': str(info.path),
        'namespace': namespace,
        'message_counts': {name: t.count for name, t in sorted(info.topics.items())},
        'missing': {k: v for k, v in missing.items() if v},
        'duplicate_stamps': {s.topic: s.duplicates for s in series.values() if s.duplicates},
        'log_start_ns': info.start_ns,
        'log_duration_ns': info.duration_ns,
    }
    return RunLog(**arrays, meta=meta)
