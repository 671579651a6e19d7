"""Bags with integrity: CRCs written, a damaged chunk found by `tiltrov bag info`, skipped
by `tiltrov bag repair`, refused by the readers; channel metadata as rosbag2 writes it."""

from __future__ import annotations

from pathlib import Path
import zlib

from mcap.reader import make_reader
from mcap.records import Chunk, DataEnd, Footer
from mcap.stream_reader import StreamReader
import pytest
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import Reader
from stack_messages import STACK, canonical
import yaml

from tiltrov_ros import cli
from tiltrov_ros.bag.bagfile import iter_raw
from tiltrov_ros.bag.integrity import check_file
from tiltrov_ros.bag.repair import repair
from tiltrov_ros.bag.writer import BagWriter
from tiltrov_ros.core.errors import BagError
from tiltrov_ros.core.names import STACK_TOPICS


def _data(topic: str, i: int) -> bytes:
    return canonical(serialize_message(STACK[topic][1](i)), STACK_TOPICS[topic])


def _bag(tmp_path: Path, compression: str, chunks: int = 3, per_chunk: int = 50) -> Path:
    path = tmp_path / f'bag_{compression}'
    with BagWriter(path, compression=compression) as bag:
        w = bag.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
        c = bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        i = 0
        for _ in range(chunks):
            for _ in range(per_chunk):
                bag.write(c, i * 10_000_000, _data('/clock', i))
                bag.write(w, i * 10_000_000, _data('wrench_cmd', i))
                i += 1
            bag.flush()
    return path


def _records(mcap: Path) -> list[object]:
    with mcap.open('rb') as stream:
        return list(StreamReader(stream, emit_chunks=True).records)


def _flip(mcap: Path, at: int) -> None:
    data = bytearray(mcap.read_bytes())
    data[at] ^= 0x20
    mcap.write_bytes(bytes(data))


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_every_crc_is_written_and_matches(tmp_path: Path, compression: str) -> None:
    mcap = _bag(tmp_path, compression) / f'bag_{compression}.mcap'
    records = _records(mcap)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert len(chunks) == 3 and all(c.uncompressed_crc != 0 for c in chunks)
    (data_end,) = [r for r in records if isinstance(r, DataEnd)]
    (footer,) = [r for r in records if isinstance(r, Footer)]
    assert data_end.data_section_crc != 0 and footer.summary_crc != 0
    result = check_file(mcap)
    assert (result.chunks, result.bad_chunks, result.data_crc, result.summary_crc,
            result.truncated_at) == (3, [], 'ok', 'ok', None)
    # The data-section CRC is the one the MCAP specification defines (every byte before
    # the DataEnd record), computed here independently of the checker.
    raw = mcap.read_bytes()
    end = raw.rindex(b'\x0f\x04\x00\x00\x00\x00\x00\x00\x00')
    assert zlib.crc32(raw[:end]) == data_end.data_section_crc
    with mcap.open('rb') as stream:      # the mcap library checks them too
        assert sum(1 for _ in make_reader(stream, validate_crcs=True).iter_messages()) == 300


def test_channels_carry_the_qos_and_type_hash_rosbag2_writes(tmp_path: Path, ros) -> None:
    """topic_type_hash is the RIHS01 string ROS itself reports for the type (what
    rosbag2's recorder takes from the graph), and metadata.yaml's type_description_hash."""
    from geometry_msgs.msg import WrenchStamped

    path = _bag(tmp_path, 'none', chunks=1)
    with (path / 'bag_none.mcap').open('rb') as stream:
        channels = {c.topic: c for c in make_reader(stream).get_summary().channels.values()}
    node = ros.node('type_hash_probe')
    node.create_publisher(WrenchStamped, '/wrench_cmd', 10)
    (info,) = node.get_publishers_info_by_topic('/wrench_cmd')
    assert channels['/wrench_cmd'].metadata['topic_type_hash'] == str(info.topic_type_hash)
    assert str(info.topic_type_hash).startswith('RIHS01_')
    assert yaml.safe_load(channels['/wrench_cmd'].metadata['offered_qos_profiles']) == []
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    hashes = {t['topic_metadata']['name']: t['topic_metadata']['type_description_hash']
              for t in meta['topics_with_message_count']}
    assert {t: c.metadata['topic_type_hash'] for t, c in channels.items()} == hashes
    with Reader(path) as reader:         # rosbags reads the hash back as rosbag2 would
        assert {c.topic: c.digest for c in reader.connections} == hashes


@pytest.mark.parametrize('compression', ['none', 'zstd'])
def test_a_flipped_byte_in_a_chunk_is_found_reported_and_skipped(
        tmp_path: Path, compression: str, capsys: pytest.CaptureFixture[str]) -> None:
    path = _bag(tmp_path, compression)
    mcap = path / f'bag_{compression}.mcap'
    second = [r for r in _records(mcap) if isinstance(r, Chunk)][1]
    offsets = []
    with mcap.open('rb') as stream:
        reader = StreamReader(stream, emit_chunks=True)
        for record in reader.records:
            if isinstance(record, Chunk):
                offsets.append(stream.tell() - len(record.data) // 2)
    _flip(mcap, offsets[1])                      # inside the second chunk's records
    result = check_file(mcap)
    assert [b.start_ns for b in result.bad_chunks] == [second.message_start_time]
    assert result.damaged and result.data_crc == 'mismatch'

    assert cli.main(['bag', 'info', str(path)]) == 1
    assert 'fails its CRC' in capsys.readouterr().out
    with pytest.raises(BagError, match='tiltrov bag repair'):   # never silently decoded
        list(iter_raw(path))

    fixed = repair(path)
    assert 'fails its CRC' in fixed.reason
    assert fixed.counts == {'/wrench_cmd': 100, '/clock': 100}   # chunks 1 and 3
    assert len(fixed.skipped) == 1 and '100 message(s) lost' in fixed.skipped[0]
    assert not check_file(mcap).damaged
    stamps = sorted({m.log_time for m in iter_raw(path)})
    assert stamps == [i * 10_000_000 for i in (*range(50), *range(100, 150))]


def test_a_damaged_summary_is_reported_and_repair_keeps_every_message(tmp_path: Path) -> None:
    path = _bag(tmp_path, 'none')
    mcap = path / 'bag_none.mcap'
    _flip(mcap, len(mcap.read_bytes()) - 60)      # inside the summary section
    assert check_file(mcap).summary_crc == 'mismatch'
    fixed = repair(path)
    assert fixed.total == 300 and fixed.skipped == []
    assert check_file(mcap).summary_crc == 'ok'
