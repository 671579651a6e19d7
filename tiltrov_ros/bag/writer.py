"""Writing a rosbag2 directory (``metadata.yaml`` + one ``.mcap``) with rosbags.

:class:`BagWriter` is rosbags' ``Writer`` with its MCAP storage, plus what a
recorder that may be killed needs:

* :meth:`BagWriter.flush` closes the pending MCAP chunk and hands it to the
  operating system, so a killed process loses at most the messages written
  since the last flush (``tiltrov bag repair`` recovers the rest);
* :attr:`BagWriter.flushed_counts` says how many messages of each topic are
  in complete chunks on disk;
* a provisional ``metadata.yaml`` (zero counts) is kept up to date while the
  bag is open: the topics with their type hashes and QoS, and the custom data
  (the run description), which the MCAP file only receives at close.

Chunks are closed when they reach rosbags' chunk size (1 MiB uncompressed)
and at every :meth:`flush`. The payloads are written untouched.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import os
from pathlib import Path
from typing import Any, Literal

from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import Writer, WriterError
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin
from rosbags.rosbag2.metadata import dump_qos_v9
import yaml

from ..core.errors import BagError
from .msgdefs import message_definition

METADATA_VERSION: Literal[9] = 9  # rosbag2 metadata version of ROS 2 Jazzy
COMPRESSIONS = ('none', 'zstd')


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
        if self.path.exists():
            raise BagError(f'{self.path} exists already; choose a new bag directory')
        self._writer: Writer | None = Writer(self.path, version=METADATA_VERSION,
                                             storage_plugin=StoragePlugin.MCAP)
        if compression == 'zstd':
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, value)
        try:
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f'cannot create bag {self.path}: {exc}') from exc
        # rosbags' McapWriter: `chunks` (closed chunks), `chunk.msgs` (pending
        # messages by channel), `close_chunk()`, `bio` (the open file), `path`.
        self._storage: Any = self._writer.storage
        if not all(hasattr(self._storage, name)
                   for name in ('chunks', 'chunk', 'close_chunk', 'bio', 'path')):
            self._writer.abort()
            raise BagError('this rosbags version has no flushable MCAP storage '
                           '(tested with rosbags 0.11)')
        _lock(self._storage.bio, exclusive=True)  # released when closed or killed
        self._chunks_done = 0
        self._topics: dict[int, str] = {}
        self._flushed: dict[int, int] = {}
        self._final_counts: dict[int, int] = {}
        self.closed = False
        self._write_provisional_metadata()

    # -- topics --------------------------------------------------------------

    def add_topic(self, topic: str, msgtype: str, *, qos: Sequence[Qos] = (),
                  msgdef: str | None = None, rihs01: str | None = None) -> Connection:
        """Register a topic; returns the connection to pass to :meth:`write`.

        The message definition and hash come from :mod:`.msgdefs` unless given;
        ``qos`` are the publishers' offered profiles.
        """
        self._check_open()
        if msgdef is None:
            msgdef, known_hash = message_definition(msgtype)
            rihs01 = rihs01 or known_hash
        try:
            connection = self._writer.add_connection(  # type: ignore[union-attr]
                topic, msgtype, msgdef=msgdef, rihs01=rihs01 or None,
                serialization_format='cdr', offered_qos_profiles=list(qos))
        except WriterError as exc:
            raise BagError(f'cannot add topic {topic!r} to {self.path}: {exc}') from exc
        self._topics[connection.id] = topic
        self._flushed[connection.id] = 0
        self._write_provisional_metadata()
        return connection

    def set_custom_data(self, key: str, value: str) -> None:
        """Set one ``custom_data`` entry (written at close; provisional file now)."""
        self._check_open()
        self._writer.set_custom_data(key, value)  # type: ignore[union-attr]
        self._write_provisional_metadata()

    # -- messages ------------------------------------------------------------

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> bool:
        """Append one serialized message with log time ``timestamp`` (ns).

        Returns True when this write completed a chunk, which is then on disk.
        """
        writer = self._writer
        if writer is None:
            raise BagError(f'bag {self.path} is closed')
        writer.write(connection, timestamp, data)
        if len(self._storage.chunks) != self._chunks_done:
            self._sync()
            return True
        return False

    def flush(self) -> bool:
        """Close the pending chunk, if it holds messages, and hand it to the OS.

        Returns True when a chunk was written.
        """
        self._check_open()
        storage = self._storage
        if not storage.chunk.msgs:
            return False
        storage.close_chunk()
        self._sync()
        return True

    def _sync(self) -> None:
        self._storage.bio.flush()
        self._chunks_done = len(self._storage.chunks)
        assert self._writer is not None
        self._flushed = dict(self._writer.counts)

    # -- state ---------------------------------------------------------------

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        counts = self._writer.counts if self._writer is not None else self._final_counts
        return {self._topics[cid]: n for cid, n in counts.items()}

    @property
    def flushed_counts(self) -> dict[str, int]:
        """Messages per topic in complete chunks on disk (all of them after close)."""
        return {self._topics[cid]: n for cid, n in self._flushed.items()}

    def close(self) -> None:
        """Write the summary and ``metadata.yaml``. Safe to call twice."""
        if self._writer is None:
            return
        writer, self._writer = self._writer, None
        self._final_counts = dict(writer.counts)
        try:
            writer.close()
        except (WriterError, OSError) as exc:
            raise BagError(f'cannot close bag {self.path}: {exc}') from exc
        finally:
            self.closed = True
        self._flushed = dict(self._final_counts)

    def _check_open(self) -> None:
        if self._writer is None:
            raise BagError(f'bag {self.path} is closed')

    def _write_provisional_metadata(self) -> None:
        """metadata.yaml while recording: topics, hashes, QoS and custom data."""
        writer = self._writer
        assert writer is not None
        mcap_name = self._storage.path.name
        info: dict[str, Any] = {
            'version': METADATA_VERSION,
            'storage_identifier': 'mcap',
            'relative_file_paths': [mcap_name],
            'duration': {'nanoseconds': 0},
            'starting_time': {'nanoseconds_since_epoch': 0},
            'message_count': 0,
            'topics_with_message_count': [
                {'topic_metadata': {
                    'name': c.topic,
                    'type': c.msgtype,
                    'serialization_format': 'cdr',
                    'offered_qos_profiles': dump_qos_v9(
                        list(c.ext.offered_qos_profiles)),  # type: ignore[union-attr]
                    'type_description_hash': c.digest},
                 'message_count': 0}
                for c in writer.connections],
            'compression_format': '',
            'compression_mode': '',
            'files': [{'path': mcap_name, 'starting_time': {'nanoseconds_since_epoch': 0},
                       'duration': {'nanoseconds': 0}, 'message_count': 0}],
            'custom_data': dict(writer.custom_data) or None,
            'ros_distro': 'rosbags',
        }
        target = self.path / 'metadata.yaml'
        tmp = target.with_suffix('.yaml.tmp')
        tmp.write_text(yaml.safe_dump({'rosbag2_bagfile_information': info},
                                      sort_keys=False), encoding='utf8')
        os.replace(tmp, target)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
