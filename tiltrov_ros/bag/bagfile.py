"""Opening a recorded bag: where its files are, what it holds, its raw messages.

A bag is given either as the rosbag2 directory (``metadata.yaml`` + ``.mcap``)
or as the ``.mcap`` file itself. Reading goes through rosbags, which returns
messages in log-time order and never deserializes them here.
"""

from __future__ import annotations

from collections.abc import Collection, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
import json
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection, ConnectionExtRosbag2, Qos
from rosbags.rosbag2 import Reader, ReaderError
import yaml

from ..core.errors import BagError

RUN_INFO_KEY = 'tiltrov.run_info'


@dataclass(frozen=True)
class TopicInfo:
    """One recorded topic."""

    name: str
    msgtype: str
    count: int
    qos: tuple[Qos, ...] = ()
    type_hash: str = ''


@dataclass(frozen=True)
class BagInfo:
    """What a bag holds (from its metadata and MCAP summary)."""

    path: Path
    message_count: int
    start_ns: int       # log time of the first message
    end_ns: int         # log time of the last message
    topics: dict[str, TopicInfo]
    custom_data: dict[str, str] = field(default_factory=dict)

    @property
    def duration_ns(self) -> int:
        return max(0, self.end_ns - self.start_ns)

    @property
    def run_info(self) -> dict[str, Any]:
        """The run description the recorder stored (``run_info`` parameter)."""
        return parse_run_info(self.custom_data.get(RUN_INFO_KEY, '{}'))


def parse_run_info(text: str) -> dict[str, Any]:
    """Parse a ``run_info`` JSON object; :class:`BagError` when it is not one."""
    try:
        value = json.loads(text or '{}')
    except json.JSONDecodeError as exc:
        raise BagError(f'run_info is not valid JSON: {exc}') from None
    if not isinstance(value, dict):
        raise BagError(f'run_info must be a JSON object, not {type(value).__name__}')
    return value


def resolve(path: str | Path) -> Path:
    """The path rosbags should open: the bag directory, or a lone ``.mcap`` file."""
    path = Path(path)
    if path.is_dir():
        if not (path / 'metadata.yaml').is_file():
            mcaps = sorted(path.glob('*.mcap'))
            if len(mcaps) == 1:
                return mcaps[0]
            raise BagError(f'{path} has no metadata.yaml (run `tiltrov bag repair {path}`)')
        return path
    if path.is_file():
        if path.suffix != '.mcap':
            raise BagError(f'{path} is not a bag directory or an .mcap file')
        meta = path.parent / 'metadata.yaml'
        if meta.is_file() and path.name in meta.read_text(encoding='utf8'):
            return path.parent
        return path
    raise BagError(f'no bag at {path}')


@contextmanager
def open_reader(path: str | Path) -> Iterator[Reader]:
    """``with open_reader(bag) as reader:`` an opened rosbags :class:`Reader`."""
    reader = Reader(resolve(path))
    try:
        reader.open()
    except (ReaderError, OSError, KeyError, ValueError) as exc:
        raise BagError(f'cannot open bag {path}: {exc} '
                       f'(if the recorder was killed, run `tiltrov bag repair {path}`)') from exc
    try:
        yield reader
    finally:
        reader.close()


def _custom_data(reader: Reader, path: Path) -> dict[str, str]:
    """custom_data from metadata.yaml, or from the MCAP's ``rosbag2`` record."""
    meta = getattr(reader.storage, 'metadata', None)
    custom = getattr(meta, 'custom', None)
    if custom:
        return {str(k): str(v) for k, v in custom.items()}
    if path.suffix == '.mcap':
        from mcap.reader import make_reader

        with path.open('rb') as stream:
            for record in make_reader(stream).iter_metadata():
                if record.name == 'rosbag2' and 'serialized_metadata' in record.metadata:
                    info = yaml.safe_load(record.metadata['serialized_metadata']) or {}
                    return {str(k): str(v) for k, v in (info.get('custom_data') or {}).items()}
    return {}


def _qos(connection: Connection) -> tuple[Qos, ...]:
    ext = connection.ext
    return tuple(ext.offered_qos_profiles) if isinstance(ext, ConnectionExtRosbag2) else ()


def bag_info(path: str | Path) -> BagInfo:
    """Topics, counts, times and custom data of a bag."""
    resolved = resolve(path)
    with open_reader(resolved) as reader:
        topics: dict[str, TopicInfo] = {}
        for conn in reader.connections:
            old = topics.get(conn.topic)
            if old is not None and old.msgtype != conn.msgtype:
                raise BagError(f'topic {conn.topic} has two types: {old.msgtype}, {conn.msgtype}')
            count = conn.msgcount + (old.count if old else 0)
            topics[conn.topic] = TopicInfo(conn.topic, conn.msgtype, count,
                                           _qos(conn), conn.digest)
        count = reader.message_count
        return BagInfo(
            path=resolved, message_count=count,
            start_ns=reader.start_time if count else 0,
            end_ns=reader.end_time - 1 if count else 0,
            topics=topics, custom_data=_custom_data(reader, resolved))


def read_messages(reader: Reader, path: str | Path,
                  connections: Collection[Connection]) -> Iterator[tuple[Connection, int, Any]]:
    """``reader.messages(connections=...)``, with a chunk that fails its CRC (or cannot
    be decompressed) reported as a :class:`BagError` naming the bag."""
    try:
        yield from reader.messages(connections=list(connections))
    except Exception as exc:  # rosbags raises ReaderError, its decompressors their own
        raise BagError(f'cannot read {path}: {type(exc).__name__}: {exc} (`tiltrov bag info '
                       f'{path}` shows where; `tiltrov bag repair {path}` keeps the rest)'
                       ) from None


@dataclass(frozen=True)
class RawMessage:
    """One recorded message, undecoded."""

    topic: str
    msgtype: str
    log_time: int     # ns
    data: bytes


def iter_raw(path: str | Path, topics: Collection[str] | None = None) -> Iterator[RawMessage]:
    """Every message of ``topics`` (all when None) in log-time order."""
    with open_reader(path) as reader:
        connections = [c for c in reader.connections if topics is None or c.topic in topics]
        if not connections:
            return
        for conn, log_time, data in read_messages(reader, path, connections):
            yield RawMessage(conn.topic, conn.msgtype, log_time, bytes(data))
