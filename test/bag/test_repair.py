"""tiltrov bag repair: a recorder killed with SIGKILL, and bags cut at any byte."""

from __future__ import annotations

import json
import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import threading
import time
from typing import Any

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import pytest
from rclpy.qos import HistoryPolicy, QoSProfile
from rclpy.serialization import serialize_message
from ros_stack import HANG_BOUND, installed
from rosbags.rosbag2 import Reader
from stack_messages import RUN_INFO, STACK, canonical, wait_matched
import yaml

from tiltrov_ros.bag.bagfile import RUN_INFO_KEY, bag_info
from tiltrov_ros.bag.repair import REPAIRED_KEY, problem, repair
from tiltrov_ros.bag.writer import BagWriter
from tiltrov_ros.cli import main as tiltrov
from tiltrov_ros.core.errors import BagError
from tiltrov_ros.nodes.recorder_config import recorder_command

FLUSHED = re.compile(r'\[bag_recorder\.stats\]: flushed (\d+) (\{.*\})')
TOPICS = ('odom', 'joint_states')


def read_back(bag: Path) -> tuple[dict[str, list[bytes]], dict[str, Any]]:
    """Messages per topic (rosbags) and the metadata.yaml of a bag."""
    with Reader(bag) as reader:
        got: dict[str, list[bytes]] = {}
        for conn, _, data in reader.messages():
            got.setdefault(conn.topic, []).append(bytes(data))
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    return got, meta


@pytest.mark.timeout(HANG_BOUND)
def test_repair_recovers_what_a_killed_recorder_had_flushed(ros: Any, tmp_path: Path) -> None:
    bag = tmp_path / 'killed'
    argv = recorder_command(str(bag), run_info=RUN_INFO,
                            params={'topics': list(TOPICS), 'flush_period': 0.0})
    argv[0] = str(installed('bag_recorder'))
    argv += ['--log-level', 'bag_recorder.stats:=debug']
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stderr.readline, '')),
                              daemon=True)
    reader.start()
    try:
        plant = ros.node('plant')
        keep_all = QoSProfile(history=HistoryPolicy.KEEP_ALL)
        pubs = {t: plant.create_publisher(STACK[t][0], t, keep_all) for t in TOPICS}
        wait_matched(ros, list(pubs.values()), process=proc)
        sent: dict[str, list[Any]] = {f'/{t}': [] for t in TOPICS}
        for i in range(2500):  # about 2.5 MB: two full 1 MiB chunks and a partial one
            for topic in TOPICS:
                msg = STACK[topic][1](i)
                pubs[topic].publish(msg)
                sent[f'/{topic}'].append(msg)

        def flushes() -> list[str]:
            return [line for line in lines if FLUSHED.search(line)]

        # Wait until the recorder is idle (no new chunk for 1 s), then kill it.
        deadline, seen, quiet_since = time.monotonic() + 30.0, -1, time.monotonic()
        while time.monotonic() < deadline:
            if len(flushes()) != seen:
                seen, quiet_since = len(flushes()), time.monotonic()
            elif seen >= 2 and time.monotonic() - quiet_since > 1.0:
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=10) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=5)
    assert len(flushes()) >= 2, ''.join(lines)
    match = FLUSHED.search(flushes()[-1])
    assert match is not None
    flushed = json.loads(match[2])
    assert sum(flushed.values()) == int(match[1])
    assert 0 < sum(flushed.values()) < 2 * 2500  # the unflushed tail is lost

    assert problem(bag) is not None
    with pytest.raises(BagError, match='repair'):
        bag_info(bag)
    original_size = (bag / 'killed.mcap').stat().st_size
    assert tiltrov(['bag', 'repair', str(bag)]) == 0
    assert problem(bag) is None
    assert (bag / 'killed.mcap.bak').stat().st_size == original_size
    assert (bag / 'metadata.yaml.bak').is_file()

    got, meta = read_back(bag)
    assert {t: len(m) for t, m in got.items()} == flushed
    for topic, msgs in got.items():  # the first messages, byte for byte
        msgtype = 'nav_msgs/msg/Odometry' if topic == '/odom' else 'sensor_msgs/msg/JointState'
        assert msgs == [canonical(serialize_message(m), msgtype)
                        for m in sent[topic][:len(msgs)]]
    assert meta['message_count'] == sum(flushed.values())
    topics = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    assert {n: t['message_count'] for n, t in topics.items()} == flushed
    for t in topics.values():
        assert t['topic_metadata']['serialization_format'] == 'cdr'
        assert t['topic_metadata']['type_description_hash'].startswith('RIHS01_')
        assert [q['reliability'] for q in t['topic_metadata']['offered_qos_profiles']] == [
            'reliable']
    assert json.loads(meta['custom_data'][RUN_INFO_KEY]) == RUN_INFO
    assert 'messages recovered' in meta['custom_data'][REPAIRED_KEY]

    with (bag / 'killed.mcap').open('rb') as stream:
        mcap = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = mcap.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == sum(flushed.values())
        by_topic = {summary.channels[cid].topic: n
                    for cid, n in summary.statistics.channel_message_counts.items()}
        assert by_topic == flushed
        log_times = [m.log_time for _, _, m in mcap.iter_messages()]
        assert meta['duration']['nanoseconds'] == max(log_times) - min(log_times)
        first = next(m for _, c, _, m in mcap.iter_decoded_messages(topics=['/odom']))
        assert first.header.frame_id == 'odom_ned'

    # Repairing again finds nothing to do.
    assert repair(bag).backups == []


def wrench_bytes(i: int) -> bytes:
    return canonical(serialize_message(STACK['wrench_cmd'][1](i)),
                     'geometry_msgs/msg/WrenchStamped')


@pytest.fixture(scope='module')
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A killed bag written in four chunks (10, 15, 20, 5 messages), and a snapshot
    of its directory after the second chunk (what a kill at that moment leaves)."""
    root = tmp_path_factory.mktemp('chunks')
    bag_dir = root / 'bag'
    snapshot = root / 'snapshot'
    bag = BagWriter(bag_dir, compression='zstd',
                    custom_data={RUN_INFO_KEY: json.dumps(RUN_INFO)})
    conn = bag.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
    i = 0
    for n in (10, 15, 20, 5):
        for _ in range(n):
            bag.write(conn, 1_000 + i, wrench_bytes(i))
            i += 1
        bag.flush()
        if i == 25:
            shutil.copytree(bag_dir, snapshot)
    bag.abort()                 # as if killed: no summary, no footer
    return {'dir': bag_dir, 'snapshot': snapshot}


def test_a_kill_between_chunks_keeps_every_flushed_message(recorded: dict[str, Any],
                                                          tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    shutil.copytree(recorded['snapshot'], bag)
    result = repair(bag)
    assert result.counts == {'/wrench_cmd': 25}
    got, meta = read_back(bag)
    assert got['/wrench_cmd'] == [wrench_bytes(i) for i in range(25)]
    assert json.loads(meta['custom_data'][RUN_INFO_KEY]) == RUN_INFO
    with (bag / 'bag.mcap').open('rb') as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    assert {c.compression for c in summary.chunk_indexes} == {'zstd'}  # kept


def chunk_ends(mcap: Path) -> list[int]:
    """Offsets where each chunk record ends, from the file itself."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    ends = []
    with mcap.open('rb') as stream:
        try:
            for record in StreamReader(stream, emit_chunks=True).records:
                if isinstance(record, Chunk):
                    ends.append(stream.tell())
        except Exception:
            pass
    return ends


@pytest.mark.parametrize('where', ['empty', 'header', 'chunk', 'index', 'last'])
def test_cut_anywhere(recorded: dict[str, Any], tmp_path: Path, where: str) -> None:
    """Cut the killed bag's file at a byte offset; repair keeps the complete chunks."""
    bag = tmp_path / 'bag'
    shutil.copytree(recorded['dir'], bag)
    mcap = bag / 'bag.mcap'
    ends = chunk_ends(mcap)
    assert len(ends) == 4
    per_chunk = [10, 15, 20, 5]
    cut, chunks = {
        'empty': (0, 0),                 # killed before the first flush
        'header': (20, 0),               # inside the header record
        'chunk': (ends[2] - 100, 2),     # inside the third chunk
        'index': (ends[2] + 5, 3),       # inside the third chunk's message index
        'last': (os.path.getsize(mcap), 4),
    }[where]
    os.truncate(mcap, cut)
    result = repair(bag)
    expected = sum(per_chunk[:chunks])
    # A topic with no complete chunk is still listed (from the provisional metadata).
    assert result.counts == {'/wrench_cmd': expected}
    got, meta = read_back(bag)
    assert got.get('/wrench_cmd', []) == [wrench_bytes(i) for i in range(expected)]
    assert meta['message_count'] == expected
    assert meta['topics_with_message_count'][0]['topic_metadata']['name'] == '/wrench_cmd'
    assert json.loads(meta['custom_data'][RUN_INFO_KEY]) == RUN_INFO


def test_intact_bags_are_left_alone_unless_forced(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    with BagWriter(bag) as writer:
        conn = writer.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
        for i in range(5):
            writer.write(conn, i, wrench_bytes(i))
    before = (bag / 'bag.mcap').read_bytes()
    assert repair(bag).backups == []
    assert (bag / 'bag.mcap').read_bytes() == before
    result = repair(bag / 'bag.mcap', force=True)
    assert [p.name for p in result.backups] == ['bag.mcap.bak', 'metadata.yaml.bak']
    got, _ = read_back(bag)
    assert got['/wrench_cmd'] == [wrench_bytes(i) for i in range(5)]
    assert repair(bag, force=True).backups[0].name == 'bag.mcap.bak.1'  # never overwritten


def test_a_bag_still_being_recorded_is_not_touched(tmp_path: Path) -> None:
    bag = BagWriter(tmp_path / 'live')
    conn = bag.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
    bag.write(conn, 1, wrench_bytes(1))
    bag.flush()
    with pytest.raises(BagError, match='still being recorded'):
        repair(tmp_path / 'live')
    assert not list((tmp_path / 'live').glob('*.bak'))
    bag.close()
    assert repair(tmp_path / 'live').backups == []  # closed properly: intact


def test_bag_info_command(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with BagWriter(tmp_path / 'bag', custom_data={RUN_INFO_KEY: json.dumps(RUN_INFO)}) as bag:
        conn = bag.add_topic('/wrench_cmd', 'geometry_msgs/msg/WrenchStamped')
        for i in range(3):
            bag.write(conn, 1_000_000_000 + i * 250_000_000, wrench_bytes(i))
    assert tiltrov(['bag', 'info', str(tmp_path / 'bag')]) == 0
    out = capsys.readouterr().out
    assert 'messages:  3' in out and 'duration:  0.500 s' in out
    assert '/wrench_cmd         3  geometry_msgs/msg/WrenchStamped' in out
    assert json.dumps(RUN_INFO, sort_keys=True) in out
    assert tiltrov(['bag', 'info', str(tmp_path / 'nothing')]) == 1


def test_not_an_mcap_file_is_an_error(tmp_path: Path) -> None:
    bag = tmp_path / 'bag'
    bag.mkdir()
    (bag / 'bag.mcap').write_bytes(b'this is not a bag at all' * 10)
    with pytest.raises(BagError, match='not an MCAP'):
        repair(bag)
    assert (bag / 'bag.mcap').read_bytes().startswith(b'this is not')
