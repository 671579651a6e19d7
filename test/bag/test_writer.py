"""BagWriter: a rosbag2/MCAP bag that rosbags and the mcap library both read,
flushable chunk by chunk, with provisional metadata while it is open."""

from __future__ import annotations

from pathlib import Path

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
import pytest
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.interfaces import QosTime as T
from rosbags.rosbag2 import Reader
import yaml

from tiltrov_ros.bag.msgdefs import typestore
from tiltrov_ros.bag.writer import BagWriter
from tiltrov_ros.core.errors import BagError

INF = T(9223372036, 854775807)
BEST_EFFORT = Qos(QosHistory.UNKNOWN, 0, QosReliability.BEST_EFFORT, QosDurability.VOLATILE,
                  INF, INF, QosLiveliness.AUTOMATIC, INF, False)


def wrench(i: int) -> bytes:
    store = typestore()
    ns = store.types
    msg = ns['geometry_msgs/msg/WrenchStamped'](
        header=ns['std_msgs/msg/Header'](
            stamp=ns['builtin_interfaces/msg/Time'](sec=i, nanosec=7), frame_id='base_link_frd'),
        wrench=ns['geometry_msgs/msg/Wrench'](
            force=ns['geometry_msgs/msg/Vector3'](x=float(i), y=0.5, z=-1.0),
            torque=ns['geometry_msgs/msg/Vector3'](x=0.0, y=0.25, z=float(-i))))
    return bytes(store.serialize_cdr(msg, 'geometry_msgs/msg/WrenchStamped'))


def clock(i: int) -> bytes:
    store = typestore()
    msg = store.types['rosgraph_msgs/msg/Clock'](
        clock=store.types['builtin_interfaces/msg/Time'](sec=i, nanosec=0))
    return bytes(store.serialize_cdr(msg, 'rosgraph_msgs/msg/Clock'))


def messages_on_disk(mcap: Path) -> int:
    """Messages in the complete records of a (possibly unfinished) MCAP file."""
    count = 0
    with mcap.open('rb') as stream:
        try:
            for record in StreamReader(stream).records:
                count += type(record).__name__ == 'Message'
        except Exception:  # the unfinished tail
            pass
    return count


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_round_trip_with_rosbags_and_mcap(tmp_path: Path, compression: str) -> None:
    path = tmp_path / 'bag'
    with BagWriter(path, compression=compression,
                   custom_data={'tiltrov.run_info': '{"scenario": "s"}'}) as bag:
        w = bag.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
        c = bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock', qos=[BEST_EFFORT])
        for i in range(50):
            bag.write(c, 1000 + i, clock(i))
            bag.write(w, 1000 + i, wrench(i))
        assert bag.counts == {'/wrench_cmd': 50, '/clock': 50}

    with Reader(path) as reader:
        assert reader.message_count == 100
        assert {t: i.msgtype for t, i in reader.topics.items()} == {
            '/wrench_cmd': 'geometry_msgs/msg/WrenchStamped', '/clock': 'rosgraph_msgs/msg/Clock'}
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
        assert qos['/clock'] == [BEST_EFFORT]
        assert reader.storage.metadata.custom == {'tiltrov.run_info': '{"scenario": "s"}'}
        got = [(c.topic, t, bytes(d)) for c, t, d in reader.messages()]
    expected = [m for i in range(50) for m in (('/clock', 1000 + i, clock(i)),
                                               ('/wrench_cmd', 1000 + i, wrench(i)))]
    assert sorted(got) == sorted(expected)

    mcap_file = path / 'bag.mcap'
    with mcap_file.open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == 100
        assert {ci.compression for ci in summary.chunk_indexes} == {
            '' if compression == 'none' else 'zstd'}
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        decoded = [(ch.topic, m) for _, ch, _, m in reader.iter_decoded_messages(
            topics=['/wrench_cmd'])]
    assert [m.wrench.force.x for _, m in decoded] == [float(i) for i in range(50)]
    assert [m.wrench.torque.z for _, m in decoded] == [float(-i) for i in range(50)]
    assert {m.header.frame_id for _, m in decoded} == {'base_link_frd'}


def test_flush_puts_complete_chunks_on_disk(tmp_path: Path) -> None:
    path = tmp_path / 'bag'
    bag = BagWriter(path, custom_data={'tiltrov.run_info': '{"a": 1}'})
    w = bag.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
    mcap_file = path / 'bag.mcap'
    for i in range(10):
        assert not bag.write(w, i, wrench(i))  # far below the 1 MiB chunk size
    assert bag.flushed_counts == {'/wrench_cmd': 0}
    assert messages_on_disk(mcap_file) == 0
    assert bag.flush()
    assert not bag.flush()  # nothing pending
    assert bag.flushed_counts == {'/wrench_cmd': 10}
    assert messages_on_disk(mcap_file) == 10
    bag.write(w, 10, wrench(10))
    assert messages_on_disk(mcap_file) == 10

    # While open, metadata.yaml already names the topics, their hashes and the run.
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    topic = info['topics_with_message_count'][0]['topic_metadata']
    assert topic['name'] == '/wrench_cmd'
    assert topic['type_description_hash'] == typestore().hash_rihs01(
        'geometry_msgs/msg/WrenchStamped')
    assert info['custom_data'] == {'tiltrov.run_info': '{"a": 1}'}

    bag.close()
    bag.close()  # idempotent
    assert bag.flushed_counts == bag.counts == {'/wrench_cmd': 11}
    with pytest.raises(BagError):
        bag.write(w, 11, wrench(11))


def test_a_full_chunk_is_written_by_itself(tmp_path: Path) -> None:
    bag = BagWriter(tmp_path / 'bag')
    w = bag.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
    payload = wrench(1)
    flushed_at = next(i for i in range(100_000) if bag.write(w, i, payload))
    # rosbags closes a chunk once it passes 1 MiB: message records (payload + 31
    # bytes) after the schema and channel records (under 1 KiB here)
    record = len(payload) + 31
    assert flushed_at * record <= 2**20 < (flushed_at + 1) * record + 1024
    assert bag.flushed_counts == {'/wrench_cmd': flushed_at + 1}
    assert messages_on_disk(tmp_path / 'bag' / 'bag.mcap') == flushed_at + 1
    bag.close()


def test_refuses_existing_directory_and_unknown_compression(tmp_path: Path) -> None:
    (tmp_path / 'exists').mkdir()
    with pytest.raises(BagError, match='exists'):
        BagWriter(tmp_path / 'exists')
    with pytest.raises(BagError, match='compression'):
        BagWriter(tmp_path / 'new', compression='lz4')
    assert not (tmp_path / 'new').exists()
