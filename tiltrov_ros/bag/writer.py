"""Writing a rosbag2 directory (``metadata.yaml`` + one ``.mcap``).

:class:`BagWriter` writes the MCAP file with the mcap library's writer, as
rosbag2's MCAP storage plugin (ROS 2 Jazzy) lays it out, plus what a recorder
that may be killed needs:

* integrity: every chunk carries the CRC-32 of its uncompressed records, the
  data-section end the CRC of everything before it, and the footer the CRC of
  the summary (:mod:`.integrity` checks them; ``tiltrov bag info`` and
  ``repair`` report a chunk that fails);
* channels as rosbag2's plugin writes them: ``cdr`` messages, a ``ros2msg``
  schema per type, channel metadata ``offered_qos_profiles`` (YAML) and
  ``topic_type_hash`` (the type's RIHS01 hash, as ``metadata.yaml``'s
  ``type_description_hash``); the ``rosbag2`` metadata record at close;
* :meth:`BagWriter.flush` closes the pending chunk and hands it to the
  operating system, so a killed process loses at most the messages written
  since the last flush (``tiltrov bag repair`` recovers the rest);
  :attr:`BagWriter.flushed_counts` says how many messages of each topic are in
  complete chunks on disk;
* a provisional ``metadata.yaml`` (zero counts) is kept up to date while the
  bag is open: the topics with their type hashes and QoS, and the custom data
  (the run description), which the MCAP file only receives at close.

Chunks are closed when they reach :data:`CHUNK_SIZE` (1 MiB of records, as
rosbags' and rosbag2's default) and at every :meth:`flush`. The payloads are
written untouched.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO, Literal

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag2,
    MessageDefinition,
    MessageDefinitionFormat,
    Qos,
)
from rosbags.rosbag2.metadata import dump_qos_v9
import yaml

from .. import __version__
from ..core.atomic import replace_text
from ..core.errors import BagError
from .msgdefs import message_definition

METADATA_VERSION: Literal[9] = 9  # rosbag2 metadata version of ROS 2 Jazzy
COMPRESSIONS = ('none', 'zstd')
#: Bytes of records after which the pending chunk is closed.
CHUNK_SIZE = 1 << 20
#: Record overhead of one message in a chunk: opcode, length, channel, sequence, times.
_MESSAGE_OVERHEAD = 1 + 8 + 2 + 4 + 8 + 8


def _lock(stream: Any, *, exclusive: bool) -> bool:
    """Advisory lock on an open file: the writer holds it exclusively while the bag
    is open (the kernel drops it when the process dies), so ``tiltrov bag repair``
    can tell a bag still being recorded. False when another process holds it."""
    try:
        import fcntl
    except ImportError:  # not POSIX: no check
        return True
    try:
        fcntl.flock(stream.fileno(), (fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
                    | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def is_being_written(mcap: Path) -> bool:
    """True when a live :class:`BagWriter` (in any process) has ``mcap`` open."""
    with mcap.open('rb') as stream:
        return not _lock(stream, exclusive=False)


class BagWriter:
    """One rosbag2 bag with MCAP storage, open for writing.

    Args:
        path: the bag directory to create (must not exist).
        compression: ``'none'`` or ``'zstd'`` (zstd-compressed MCAP chunks).
        custom_data: string key/value pairs for ``metadata.yaml``'s
            ``custom_data`` (and the MCAP ``rosbag2`` metadata record).

    Raises:
        BagError: the directory exists or cannot be created, or a bad option.

    """

    def __init__(self, path: str | Path, *, compression: str = 'none',
                 custom_data: Mapping[str, str] | None = None) -> None:
        if compression not in COMPRESSIONS:
            raise BagError(f'compression must be one of {COMPRESSIONS}, not {compression!r}')
        self.path = Path(path)
        self.compression = compression
        self.mcap_path = self.path / f'{self.path.name}.mcap'
        try:
            self.path.mkdir(mode=0o755, parents=True)
            stream: BinaryIO = self.mcap_path.open('xb')
        except FileExistsError:
            raise BagError(f'{self.path} exists already; choose a new bag directory') from None
        except OSError as exc:
            raise BagError(f'cannot create bag {self.path}: {exc}') from exc
        self._stream = stream
        _lock(stream, exclusive=True)  # released when closed or killed
        self._mcap: McapWriter | None = McapWriter(
            stream, chunk_size=1 << 62,     # chunks are closed here (see write)
            compression=CompressionType.ZSTD if compression == 'zstd' else CompressionType.NONE,
            enable_crcs=True, enable_data_crcs=True)
        self._mcap.start(profile='ros2', library=f'tiltrov_ros {__version__}')
        self._custom = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._connections: list[Connection] = []
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}         # connection id -> MCAP channel id
        self._counts: dict[int, int] = {}
        self._flushed: dict[int, int] = {}
        self._pending = 0                            # bytes of records in the open chunk
        self._start = 2**63 - 1
        self._end = 0
        self.closed = False
        self._write_metadata_yaml(provisional=True)

    # -- topics --------------------------------------------------------------

    def add_topic(self, topic: str, msgtype: str, *, qos: Sequence[Qos] = (),
                  msgdef: str | None = None, rihs01: str | None = None) -> Connection:
        """Register a topic; returns the connection to pass to :meth:`write`.

        The message definition and hash come from :mod:`.msgdefs` unless given;
        ``qos`` are the publishers' offered profiles.
        """
        writer = self._open()
        if msgdef is None:
            msgdef, known_hash = message_definition(msgtype)
            rihs01 = rihs01 or known_hash
        if not rihs01:
            raise BagError(f'cannot add topic {topic!r} to {self.path}: no type hash')
        if any(c.topic == topic and c.msgtype == msgtype for c in self._connections):
            raise BagError(f'cannot add topic {topic!r} to {self.path}: added already')
        fmt = 'ros2idl' if msgdef.startswith('=' * 80 + '\nIDL: ') else 'ros2msg'
        if msgtype not in self._schemas:
            self._schemas[msgtype] = writer.register_schema(msgtype, fmt, msgdef.encode())
        connection = Connection(
            id=len(self._connections) + 1, topic=topic, msgtype=msgtype,
            msgdef=MessageDefinition(MessageDefinitionFormat.MSG if fmt == 'ros2msg'
                                     else MessageDefinitionFormat.IDL, msgdef),
            digest=rihs01, msgcount=0,
            ext=ConnectionExtRosbag2(serialization_format='cdr',
                                     offered_qos_profiles=list(qos)),
            owner=self)
        self._channels[connection.id] = writer.register_channel(
            topic, 'cdr', self._schemas[msgtype],
            {'offered_qos_profiles': _qos_text(qos), 'topic_type_hash': rihs01})
        self._connections.append(connection)
        self._counts[connection.id] = 0
        self._flushed[connection.id] = 0
        self._write_metadata_yaml(provisional=True)
        return connection

    def set_custom_data(self, key: str, value: str) -> None:
        """Set one ``custom_data`` entry (written at close; provisional file now)."""
        self._open()
        self._custom[str(key)] = str(value)
        self._write_metadata_yaml(provisional=True)

    # -- messages ------------------------------------------------------------

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> bool:
        """Append one serialized message with log time ``timestamp`` (ns).

        Returns True when this write completed a chunk, which is then on disk.
        """
        writer = self._open()
        payload = bytes(data)
        writer.add_message(self._channels[connection.id], log_time=timestamp, data=payload,
                           publish_time=timestamp)
        self._counts[connection.id] += 1
        self._start = min(self._start, timestamp)
        self._end = max(self._end, timestamp)
        self._pending += len(payload) + _MESSAGE_OVERHEAD
        if self._pending > CHUNK_SIZE:
            self._sync()
            return True
        return False

    def flush(self) -> bool:
        """Close the pending chunk, if it holds messages, and hand it to the OS.

        Returns True when a chunk was written.
        """
        self._open()
        if not self._pending:
            return False
        self._sync()
        return True

    def _sync(self) -> None:
        assert self._mcap is not None
        self._mcap.flush()          # closes the chunk (CRC, index) and flushes the stream
        self._pending = 0
        self._flushed = dict(self._counts)

    # -- state ---------------------------------------------------------------

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        return {c.topic: self._counts[c.id] for c in self._connections}

    @property
    def flushed_counts(self) -> dict[str, int]:
        """Messages per topic in complete chunks on disk (all of them after close)."""
        return {c.topic: self._flushed[c.id] for c in self._connections}

    def close(self) -> None:
        """Write the summary and ``metadata.yaml``. Safe to call twice."""
        if self._mcap is None:
            return
        writer, self._mcap = self._mcap, None
        try:
            writer.flush()
            writer.add_metadata('rosbag2', {'serialized_metadata': yaml.safe_dump(
                self._info(provisional=False), sort_keys=False).strip()})
            writer.finish()
            self._stream.close()
        except OSError as exc:
            raise BagError(f'cannot close bag {self.path}: {exc}') from exc
        finally:
            self.closed = True
        self._pending = 0
        self._flushed = dict(self._counts)
        self._write_metadata_yaml(provisional=False)

    def abort(self) -> None:
        """Close the file as a killed process leaves it: the chunks flushed so far, no
        summary, no footer (``tiltrov bag repair`` recovers them)."""
        if self._mcap is None:
            return
        self._mcap = None
        self._stream.close()
        self.closed = True

    def _open(self) -> McapWriter:
        if self._mcap is None:
            raise BagError(f'bag {self.path} is closed')
        return self._mcap

    def _info(self, *, provisional: bool) -> dict[str, Any]:
        """``rosbag2_bagfile_information``: while recording, the topics, hashes, QoS
        and custom data with zero counts; at close, the counts and times too."""
        name = self.mcap_path.name
        total = 0 if provisional else sum(self._counts.values())
        start = 0 if provisional or not total else self._start
        duration = 0 if provisional or not total else self._end - self._start
        return {
            'version': METADATA_VERSION,
            'storage_identifier': 'mcap',
            'relative_file_paths': [name],
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': total,
            'topics_with_message_count': [
                {'topic_metadata': {
                    'name': c.topic,
                    'type': c.msgtype,
                    'serialization_format': 'cdr',
                    'offered_qos_profiles': dump_qos_v9(
                        list(c.ext.offered_qos_profiles)),  # type: ignore[union-attr]
                    'type_description_hash': c.digest},
                 'message_count': 0 if provisional else self._counts[c.id]}
                for c in self._connections],
            'compression_format': '',
            'compression_mode': '',
            'files': [{'path': name, 'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration}, 'message_count': total}],
            'custom_data': dict(self._custom) or None,
            'ros_distro': 'jazzy',
        }

    def _write_metadata_yaml(self, *, provisional: bool) -> None:
        replace_text(self.path / 'metadata.yaml', yaml.safe_dump(
            {'rosbag2_bagfile_information': self._info(provisional=provisional)},
            sort_keys=False))

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _qos_text(qos: Sequence[Qos]) -> str:
    """The publishers' QoS as rosbag2 stores them in a channel's metadata (YAML)."""
    return yaml.safe_dump(dump_qos_v9(list(qos)), sort_keys=False).strip()
