"""The bag reader's batched decoding (CDR layouts read with numpy) gives exactly what
rosbags' per-message deserializer gives, whatever the layouts, byte orders and padding."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from tiltrov_ros.bag import cdr
from tiltrov_ros.bag import reader as bag_reader
from tiltrov_ros.bag.export import _Messages
from tiltrov_ros.bag.reader import ODOMETRY, PLANT_JOINTS, WRENCH, Decoder, _TopicBatches
from tiltrov_ros.core import names
from tiltrov_ros.core.names import STACK_TOPICS

M = _Messages()
STORE = M.store
ODOM = STACK_TOPICS[names.ODOM]
JOINTS = 'sensor_msgs/msg/JointState'


def serialize(msg: Any, msgtype: str, *, big_endian: bool = False) -> bytes:
    return bytes(STORE.serialize_cdr(msg, msgtype, little_endian=not big_endian))


def odom(k: int, frame: str = 'odom_ned') -> Any:
    msg = M.odom(k * 10_000_000, [0.1 * k, -0.2, 1e-300 * k], [0.5, 0.5, -0.5, 0.5 + k],
                 [k, -k, 0.5, math.inf, -0.0, math.nan])
    msg.header.frame_id = frame
    msg.pose.covariance = np.arange(36.0) * k
    return msg


def joints(k: int, names: tuple[str, ...], effort: bool = True) -> Any:
    n = len(names)
    return M.joints(k * 10_000_000, names, position=np.arange(n) + 0.1 * k,
                    velocity=np.arange(n) - 0.5 * k,
                    effort=np.arange(n) * 10.0 + k if effort else ())


def expected(decoder: Decoder, payloads: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Stamps and rows the slow way: rosbags' deserializer, message by message."""
    msgs = [STORE.deserialize_cdr(p, decoder.msgtype) for p in payloads]
    stamps = np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                       for m in msgs], dtype=np.int64)
    rows = np.array([decoder.extract(m) for m in msgs], dtype=float).reshape(len(msgs), -1)
    return stamps, rows


def decode(decoder: Decoder, payloads: list[bytes]) -> tuple[_TopicBatches, Any]:
    batches = _TopicBatches('/t', decoder)
    for i, data in enumerate(payloads):
        batches.add(data, 1000 + i)
    return batches, batches.series()


def assert_same(series: Any, decoder: Decoder, payloads: list[bytes]) -> None:
    stamps, rows = expected(decoder, payloads)
    order = np.argsort(stamps, kind='stable')
    keep = np.ones(len(order), dtype=bool)
    keep[:-1] = stamps[order][1:] != stamps[order][:-1]
    np.testing.assert_array_equal(series.stamps, stamps[order][keep])
    table = np.hstack([series.columns[name] for name in decoder.columns])
    assert table.tobytes() == rows[order][keep].tobytes()       # bit for bit, NaN and -0.0


def test_one_layout_is_read_in_batches() -> None:
    payloads = [serialize(odom(k), ODOM) for k in range(300)]
    batches, series = decode(ODOMETRY, payloads)
    assert (batches.fast, batches.slow) == (300, 0)
    assert_same(series, ODOMETRY, payloads)
    np.testing.assert_array_equal(series.log_times, 1000 + np.arange(300))


def test_several_layouts_byte_orders_and_padding() -> None:
    """Joint states listing their joints in different orders, one without efforts,
    big-endian ones, and garbage in the padding bytes (rclpy leaves them uninitialized)."""
    orders = [('tilt_front', 'tilt_rear', 'thruster_1', 'thruster_2', 'thruster_3', 'thruster_4'),
              ('thruster_4', 'tilt_rear', 'thruster_2', 'tilt_front', 'thruster_1'),
              ('tilt_front', 'tilt_rear')]
    payloads = []
    for k in range(240):
        names = orders[k % 3]
        data = bytearray(serialize(joints(k, names, effort=k % 5 != 0), JOINTS,
                                   big_endian=k % 4 == 0))
        layout = cdr.walk(bytes(data), JOINTS)
        used = np.zeros(len(data), dtype=bool)
        used[layout.structure_index()] = True
        for offset, dtype in layout.leaves.values():
            used[offset:offset + int(dtype[-1])] = True
        data[4:] = bytes(b if used[4 + i] else 0xAB for i, b in enumerate(data[4:]))
        payloads.append(bytes(data))
    batches, series = decode(PLANT_JOINTS, payloads)
    assert batches.slow == 0 and batches.fast == 240
    assert_same(series, PLANT_JOINTS, payloads)
    thrust = series.columns['thrust']
    assert np.isnan(thrust[0]).all()                        # k = 0: no efforts
    assert not np.isnan(thrust[3]).any()                    # k = 3: all four
    assert np.isnan(thrust[1, 2]) and not np.isnan(thrust[1, [0, 1, 3]]).any()  # no thruster_3


def test_many_layouts_of_one_size_fall_back_to_rosbags() -> None:
    """Frame ids of equal length but different text: a layout each; past MAX_LAYOUTS
    the rest is deserialized one by one, with the same result."""
    frames = [f'frame_{i:02d}' for i in range(20)]
    payloads = [serialize(odom(k, frames[k % 20]), ODOM) for k in range(60)]
    batches, series = decode(ODOMETRY, payloads)
    assert batches.fast == 3 * bag_reader.MAX_LAYOUTS and batches.slow == 60 - batches.fast
    assert_same(series, ODOMETRY, payloads)


def test_batches_keep_order_and_the_last_of_a_repeated_stamp(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bag_reader, 'BATCH', 7)
    rng = np.random.default_rng(3)
    ks = [*rng.permutation(50), 10, 20]                      # out of order; two repeats
    payloads = []
    for i, k in enumerate(ks):
        msg = M.wrench(int(k) * 50_000_000, [float(k), i, 0, 0, 0, -float(k)])
        payloads.append(serialize(msg, 'geometry_msgs/msg/WrenchStamped'))
    batches, series = decode(WRENCH, payloads)
    assert len(batches.stamp_parts) == math.ceil(52 / 7)
    assert series.duplicates == 2 and len(series) == 50
    np.testing.assert_array_equal(series.stamps, np.arange(50) * 50_000_000)
    assert series.columns['wrench'][10, 1] == 50 and series.columns['wrench'][20, 1] == 51
    np.testing.assert_array_equal(series.log_times[[10, 20]], [1050, 1051])


def test_walk_refuses_what_it_cannot_read() -> None:
    data = serialize(odom(1), ODOM)
    with pytest.raises(cdr.LayoutError, match='ends at byte'):
        cdr.walk(data[:100], ODOM)
    with pytest.raises(cdr.LayoutError, match='not in the type store'):
        cdr.walk(data, 'my_pkg/msg/Unknown')
    with pytest.raises(cdr.LayoutError, match='encapsulation'):
        cdr.walk(b'\x07\x07' + data[2:], ODOM)
    # A truncated message among good ones is decoded by rosbags, which refuses it.
    batches = _TopicBatches('/odom', ODOMETRY)
    batches.add(data, 0)
    batches.add(data[:-40], 1)
    with pytest.raises(Exception):  # noqa: B017 - rosbags' own error for a truncated message
        batches.series()


@pytest.mark.parametrize('msgtype', sorted({*STACK_TOPICS.values(), *names.TF_TOPICS.values()}))
def test_the_python_classes_give_the_type_stores_layout(msgtype: str) -> None:
    """walk() with the fields of the generated Python classes (what the nodes use, no type
    store to load) finds the layout the type store's fields give."""
    data = serialize(M.store.types[msgtype](**_defaults(msgtype)), msgtype)
    assert cdr.walk(data, msgtype, cdr.python_fields) == cdr.walk(data, msgtype)
    assert [name for name, _ in cdr.python_fields(msgtype)] == [
        name for name, _ in STORE.fielddefs[msgtype][1]]


def test_the_python_classes_fields_of_stamped_odometry_and_joints() -> None:
    for data, msgtype in ((serialize(odom(3, 'a_frame'), ODOM), ODOM),
                          (serialize(joints(2, ('tilt_front', 'thruster_1')), JOINTS), JOINTS),
                          (serialize(joints(1, ('x',), effort=False), JOINTS, big_endian=True),
                           JOINTS)):
        assert cdr.walk(data, msgtype, cdr.python_fields) == cdr.walk(data, msgtype)
    with pytest.raises(cdr.LayoutError, match='my_pkg'):
        cdr.walk(serialize(odom(1), ODOM), 'my_pkg/msg/Unknown', cdr.python_fields)


def _defaults(msgtype: str) -> dict[str, Any]:
    """Every field of ``msgtype`` at a default value, as rosbags' classes want them."""
    out: dict[str, Any] = {}
    for name, (kind, detail) in STORE.fielddefs[msgtype][1]:
        if kind == 1:       # base type
            out[name] = '' if detail[0] == 'string' else (
                False if detail[0] == 'bool' else 0)
        elif kind == 2:     # nested message
            out[name] = STORE.types[detail](**_defaults(detail))
        elif kind == 3:     # fixed-size array
            out[name] = np.zeros(detail[1], dtype=np.float64)
        else:               # sequence: empty
            sub = detail[0]
            out[name] = ([] if sub[0] != 1 or sub[1][0] in ('string',)
                         else np.zeros(0, dtype=_NUMPY.get(sub[1][0], np.float64)))
    return out


_NUMPY = {'float64': np.float64, 'float32': np.float32, 'int32': np.int32, 'uint32': np.uint32,
          'uint8': np.uint8, 'int8': np.int8, 'uint16': np.uint16, 'int16': np.int16,
          'int64': np.int64, 'uint64': np.uint64, 'bool': np.bool_, 'byte': np.uint8,
          'char': np.uint8}
