"""Reading a tiltrov bag into a :class:`~tiltrov_ros.core.runlog.RunLog`.

Two layers, so the analysis (``tiltrov analyze``) and re-running parts of the
stack on recorded inputs can plug in at either:

* :func:`read_series` decodes chosen topics in one pass over the bag into
  :class:`Series`: header stamps (int ns) and named float columns, sorted by
  stamp. No rclpy: batches of messages that share a CDR layout are read with
  numpy at the fields' offsets (:mod:`.cdr`), each layout checked against
  rosbags' decoding of one message; the rest is decoded by rosbags one by one;
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
from functools import cache
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from tiltrov_ros.core.errors import BagError
from tiltrov_ros.core.names import (
    JOINT_STATES,
    ODOM,
    SETPOINT,
    SETPOINT_VELOCITY,
    THRUST_CMD,
    THRUSTERS,
    TILT_CMD,
    TILTS,
    WRENCH_ACHIEVED,
    WRENCH_CMD,
    join_namespace,
)
from tiltrov_ros.core.runlog import CONTROL_FIELDS, PLANT_FIELDS, FloatArray, RunLog
from tiltrov_ros.core.timebase import seconds, stamp_to_ns
from tiltrov_ros.progress import ProgressBar

from . import cdr
from .bagfile import bag_info, open_reader
from .msgdefs import typestore

NAN = math.nan

Row = Sequence[float]


Paths = Sequence[str | None]


@dataclass(frozen=True)
class Decoder:
    """How to turn one message type into a row of named float columns.

    ``paths(msg)`` names, for a decoded message, the field holding each value
    of the row (``pose.pose.position.x``, ``effort[3]``; None: NaN, e.g. a joint
    the message does not list). The reader applies it to one message of each
    layout and reads whole batches at those fields (:mod:`.cdr`).
    """

    msgtype: str
    columns: dict[str, int]             # column name -> width
    paths: Callable[[Any], Paths]       # decoded message -> field path of each value

    @property
    def width(self) -> int:
        return sum(self.columns.values())

    def extract(self, msg: Any) -> Row:
        """The row of one decoded message."""
        return [NAN if path is None else float(_follow(msg, path)) for path in self.paths(msg)]


@cache
def _steps(path: str) -> tuple[str | int, ...]:
    steps: list[str | int] = []
    for part in path.split('.'):
        name, _, index = part.partition('[')
        steps.append(name)
        if index:
            steps.append(int(index.rstrip(']')))
    return tuple(steps)


def _follow(msg: Any, path: str) -> Any:
    value = msg
    for step in _steps(path):
        value = value[step] if isinstance(step, int) else getattr(value, step)
    return value


def _fixed(*paths: str) -> Callable[[Any], Paths]:
    return lambda msg: paths


def _vector(prefix: str) -> tuple[str, str, str]:
    return (f'{prefix}.x', f'{prefix}.y', f'{prefix}.z')


def _quaternion_wxyz(prefix: str) -> tuple[str, str, str, str]:
    return (f'{prefix}.w', f'{prefix}.x', f'{prefix}.y', f'{prefix}.z')


def _joint_paths(m: Any, names: Sequence[str], attribute: str) -> list[str | None]:
    """Paths of ``attribute`` (position/velocity/effort) of joints ``names``; None if absent."""
    index = {name: i for i, name in enumerate(m.name)}
    size = len(getattr(m, attribute))
    out: list[str | None] = []
    for name in names:
        i = index.get(name)
        out.append(f'{attribute}[{i}]' if i is not None and i < size else None)
    return out


def _joints(*parts: tuple[Sequence[str], str]) -> Callable[[Any], Paths]:
    return lambda m: [p for names, attribute in parts for p in _joint_paths(m, names, attribute)]


ODOMETRY = Decoder('nav_msgs/msg/Odometry', {'position': 3, 'quaternion': 4, 'nu': 6}, _fixed(
    *_vector('pose.pose.position'), *_quaternion_wxyz('pose.pose.orientation'),
    *_vector('twist.twist.linear'), *_vector('twist.twist.angular')))
PLANT_JOINTS = Decoder('sensor_msgs/msg/JointState',
                       {'tilt_position': 2, 'tilt_velocity': 2, 'thrust': 4},
                       _joints((TILTS, 'position'), (TILTS, 'velocity'), (THRUSTERS, 'effort')))
POSE = Decoder('geometry_msgs/msg/PoseStamped', {'position': 3, 'quaternion': 4}, _fixed(
    *_vector('pose.position'), *_quaternion_wxyz('pose.orientation')))
TWIST = Decoder('geometry_msgs/msg/TwistStamped', {'velocity': 6}, _fixed(
    *_vector('twist.linear'), *_vector('twist.angular')))
WRENCH = Decoder('geometry_msgs/msg/WrenchStamped', {'wrench': 6}, _fixed(
    *_vector('wrench.force'), *_vector('wrench.torque')))
THRUSTS = Decoder('sensor_msgs/msg/JointState', {'thrust': 4},
                     _joints((THRUSTERS, 'effort')))
TILT_POSITIONS = Decoder('sensor_msgs/msg/JointState', {'tilt': 2}, _joints((TILTS, 'position')))

# relative topic name -> decoder, for the RunLog
RUNLOG_TOPICS: dict[str, Decoder] = {
    ODOM: ODOMETRY,
    JOINT_STATES: PLANT_JOINTS,
    SETPOINT: POSE,
    SETPOINT_VELOCITY: TWIST,
    WRENCH_CMD: WRENCH,
    THRUST_CMD: THRUSTS,
    TILT_CMD: TILT_POSITIONS,
    WRENCH_ACHIEVED: WRENCH,
}


@dataclass
class Series:
    """One topic decoded: rows sorted by header stamp, one row per stamp."""

    topic: str
    stamps: NDArray[np.int64]           # header stamps, ns
    log_times: NDArray[np.int64]        # log times, ns
    columns: dict[str, FloatArray]      # name -> (n,) or (n, width)
    duplicates: int = 0                 # messages dropped for a repeated stamp
    one_by_one: int = 0                 # messages deserialized singly (not by layout)

    def __len__(self) -> int:
        return len(self.stamps)


#: Messages of one topic decoded together (bounds the memory a read holds).
BATCH = 16384
#: Layouts tried on one batch before its remaining messages are decoded one by one.
MAX_LAYOUTS = 8


class _TopicBatches:
    """The messages of one topic, decoded in batches of :data:`BATCH`.

    A batch is decoded layout by layout (:func:`.cdr.walk` of its first
    undecoded message): the messages with that layout's size and structure bytes
    are read with numpy at the decoder's paths. Each layout is checked first
    against rosbags' decoding of the message it came from (stamp and every
    value, to the bit); a message whose layout cannot be walked or fails the
    check, and what remains after :data:`MAX_LAYOUTS` layouts, goes through
    rosbags' deserializer one by one. Both ways give the same floats.
    """

    def __init__(self, topic: str, decoder: Decoder) -> None:
        self.topic = topic
        self.decoder = decoder
        self.store = typestore()
        self.payloads: list[bytes] = []
        self.log_times: list[int] = []
        self.stamp_parts: list[NDArray[np.int64]] = []
        self.log_parts: list[NDArray[np.int64]] = []
        self.row_parts: list[FloatArray] = []
        self.fast = 0                   # messages read through a layout
        self.slow = 0                   # messages deserialized one by one

    def add(self, data: bytes, log_time: int) -> None:
        self.payloads.append(data)
        self.log_times.append(log_time)
        if len(self.payloads) >= BATCH:
            self.flush()

    def flush(self) -> None:
        payloads, self.payloads = self.payloads, []
        if not payloads:
            return
        n = len(payloads)
        stamps = np.zeros(n, dtype=np.int64)
        rows = np.full((n, self.decoder.width), NAN)
        sizes = np.fromiter((len(p) for p in payloads), dtype=np.int64, count=n)
        for size in np.unique(sizes):
            remaining = np.flatnonzero(sizes == size)
            for _ in range(MAX_LAYOUTS):
                if not remaining.size:
                    break
                layout_paths = self._layout(payloads[remaining[0]])
                if layout_paths is None:
                    self._slow(payloads, remaining[:1], stamps, rows)
                    remaining = remaining[1:]
                    continue
                layout, paths = layout_paths
                buffer = b''.join(payloads[i] for i in remaining)
                same = cdr.same_structure(buffer, len(remaining), layout)
                chosen = remaining[same]
                if not same.all():
                    buffer = b''.join(payloads[i] for i in chosen)
                stamps[chosen] = cdr.read_stamps(buffer, len(chosen), layout)
                rows[chosen] = cdr.read_leaves(buffer, len(chosen), layout, paths)
                self.fast += len(chosen)
                remaining = remaining[~same]
            self._slow(payloads, remaining, stamps, rows)
        self.stamp_parts.append(stamps)
        self.row_parts.append(rows)
        self.log_parts.append(np.asarray(self.log_times, dtype=np.int64))
        self.log_times = []

    def _layout(self, data: bytes) -> tuple[cdr.Layout, Paths] | None:
        """The layout of ``data`` and the decoder's paths in it, checked against
        rosbags' decoding of ``data``; None when it cannot be used."""
        try:
            layout = cdr.walk(data, self.decoder.msgtype)
        except cdr.LayoutError:
            return None
        msg: Any = self.store.deserialize_cdr(data, self.decoder.msgtype)
        paths = list(self.decoder.paths(msg))
        if any(p is not None and p not in layout.leaves for p in paths):
            return None
        expected_row = np.array(self.decoder.extract(msg), dtype=float)
        expected_stamp = stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec)
        row = cdr.read_leaves(data, 1, layout, paths)[0]
        stamp = int(cdr.read_stamps(data, 1, layout)[0])
        if stamp != expected_stamp or row.tobytes() != expected_row.tobytes():
            return None
        return layout, paths

    def _slow(self, payloads: list[bytes], indices: NDArray[np.intp],
              stamps: NDArray[np.int64], rows: FloatArray) -> None:
        for i in indices:
            msg: Any = self.store.deserialize_cdr(payloads[i], self.decoder.msgtype)
            stamps[i] = stamp_to_ns(msg.header.stamp.sec, msg.header.stamp.nanosec)
            rows[i] = self.decoder.extract(msg)
        self.slow += len(indices)

    def series(self) -> Series:
        """Every message added, sorted by stamp, the last of each stamp kept."""
        self.flush()
        width = self.decoder.width
        stamp_arr = np.concatenate(self.stamp_parts) if self.stamp_parts else np.zeros(
            0, dtype=np.int64)
        log_arr = np.concatenate(self.log_parts) if self.log_parts else np.zeros(
            0, dtype=np.int64)
        table = np.concatenate(self.row_parts) if self.row_parts else np.zeros((0, width))
        order = np.argsort(stamp_arr, kind='stable')
        stamp_arr, log_arr, table = stamp_arr[order], log_arr[order], table[order]
        # keep the last message of each stamp (in recording order)
        keep = np.ones(len(stamp_arr), dtype=bool)
        keep[:-1] = stamp_arr[1:] != stamp_arr[:-1]
        duplicates = int(len(keep) - keep.sum())
        stamp_arr, log_arr, table = stamp_arr[keep], log_arr[keep], table[keep]
        columns: dict[str, FloatArray] = {}
        start = 0
        for name, cols in self.decoder.columns.items():
            columns[name] = table[:, start:start + cols]
            start += cols
        return Series(self.topic, stamp_arr, log_arr, columns, duplicates, self.slow)


def read_series(path: str | Path, decoders: Mapping[str, Decoder], *,
                progress: bool | None = None) -> dict[str, Series]:
    """Decode the topics named in ``decoders`` (absolute names) in one pass.

    Topics absent from the bag are absent from the result. ``progress``:
    True/False to force the stderr progress bar on or off, None for automatic.
    Messages are decoded in batches, straight from their CDR bytes where they
    share a layout (see :class:`_TopicBatches`).

    Raises:
        BagError: unreadable bag, or a topic of another type than its decoder's.

    """
    with open_reader(path) as reader:
        connections = [c for c in reader.connections if c.topic in decoders]
        for conn in connections:
            if conn.msgtype != decoders[conn.topic].msgtype:
                raise BagError(f'{conn.topic} is {conn.msgtype} in {path}, '
                               f'expected {decoders[conn.topic].msgtype}')
        batches = {c.topic: _TopicBatches(c.topic, decoders[c.topic]) for c in connections}
        total = sum(c.msgcount for c in connections)
        # None: a bar only if the read takes over a second; True: at once.
        with ProgressBar(f'reading {Path(path).name}',
                         delay=0.0 if progress else 1.0) as bar:
            show = progress is not False and total > 0
            for i, (conn, log_time, data) in enumerate(
                    reader.messages(connections=connections) if connections else ()):
                batches[conn.topic].add(data, log_time)
                if show and i % 4096 == 0:
                    bar(i / total)
            result = {topic: batch.series() for topic, batch in batches.items()}
            if show:
                bar(1.0)
    return result


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


def find_namespace(topics: Mapping[str, str], relative: str = ODOM,
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
    odom = get(ODOM)
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
        arrays[name], missing[name] = rows_at(ticks, get(JOINT_STATES), name,
                                             PLANT_FIELDS[name])

    wrench_cmd = get(WRENCH_CMD)
    control = wrench_cmd.stamps if wrench_cmd is not None else np.zeros(0, dtype=np.int64)
    arrays['tc'] = _times(control)
    control_sources: dict[str, tuple[str, str, Callable[..., tuple[FloatArray, int]]]] = {
        'setpoint_position': (SETPOINT, 'position', rows_as_of),
        'setpoint_quaternion': (SETPOINT, 'quaternion', rows_as_of),
        'setpoint_velocity': (SETPOINT_VELOCITY, 'velocity', rows_as_of),
        'wrench_cmd': (WRENCH_CMD, 'wrench', rows_at),
        'thrust_cmd': (THRUST_CMD, 'thrust', rows_at),
        'tilt_cmd': (TILT_CMD, 'tilt', rows_at),
        'wrench_achieved': (WRENCH_ACHIEVED, 'wrench', rows_at),
    }
    for name, (rel, column, join) in control_sources.items():
        if rel == SETPOINT_VELOCITY and names[rel] not in info.topics:
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
        'decoded_one_by_one': {s.topic: s.one_by_one for s in series.values() if s.one_by_one},
        'log_start_ns': info.start_ns,
        'log_duration_ns': info.duration_ns,
    }
    return RunLog(**arrays, meta=meta)
