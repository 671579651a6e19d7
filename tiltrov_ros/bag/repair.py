"""Repairing a bag whose recorder died (SIGKILL, power cut): ``tiltrov bag repair``.

What a killed recorder leaves: the MCAP file without its summary and footer,
ending somewhere after the last chunk it wrote out, and the provisional
``metadata.yaml`` (topics, type hashes, QoS, custom data; zero counts).

Strategy: read the MCAP file front to back with the mcap library's stream
reader and keep every record up to the first one that is incomplete or
malformed. A chunk is only used whole, so the recovered messages are exactly
those of the complete chunks: everything up to the last chunk written. They
are written, bytes untouched and with their log times, to a new bag by the
same writer the recorder uses (same chunk compression), with a full summary
and a ``metadata.yaml`` computed from what was recovered (message counts,
duration, topics with types, QoS and serialization format). Type hashes and
custom data (the run description) come from the provisional metadata, else
from the MCAP's own records, else are recomputed; topics the provisional
metadata lists but no complete chunk reached are kept with zero messages.
The original files are kept next to the result as ``*.bak``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
import itertools
import os
from pathlib import Path
import shutil
from typing import Any, BinaryIO

from mcap.exceptions import InvalidMagic
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import StreamReader, breakup_chunk
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader
from rosbags.rosbag2.metadata import parse_qos
import yaml

from ..core.errors import BagError
from .msgdefs import hash_of_definition, message_definition
from .writer import BagWriter, is_being_written

REPAIRED_KEY = 'tiltrov.repaired'


@dataclass
class RepairResult:
    """What :func:`repair` did."""

    path: Path                                  # the bag directory
    counts: dict[str, int]                      # recovered messages per topic
    backups: list[Path] = field(default_factory=list)
    stopped_at: int = 0                         # bytes of the original file used
    file_size: int = 0
    reason: str = ''                            # why the original was not readable

    @property
    def total(self) -> int:
        return sum(self.counts.values())


def find_mcap(path: str | Path) -> tuple[Path, Path]:
    """``(bag directory, its .mcap file)`` for a bag directory or an .mcap path."""
    path = Path(path)
    if path.is_file():
        return path.parent, path
    if not path.is_dir():
        raise BagError(f'no bag at {path}')
    mcaps = sorted(path.glob('*.mcap'))
    if len(mcaps) != 1:
        raise BagError(f'{path} holds {len(mcaps)} .mcap files; expected one '
                       f'(pass the .mcap file to repair)')
    return path, mcaps[0]


def problem(path: str | Path) -> str | None:
    """Why the bag cannot be read as it is, or None when it is intact."""
    directory, mcap = find_mcap(path)
    if not (directory / 'metadata.yaml').is_file():
        return 'metadata.yaml is missing'
    try:
        with Reader(directory) as reader:
            listed = reader.message_count
        with mcap.open('rb') as stream:
            summary = make_reader(stream).get_summary()
    except Exception as exc:  # rosbags and mcap raise many kinds on damaged files
        return f'{type(exc).__name__}: {exc}'
    if summary is None or summary.statistics is None:
        return 'the MCAP file has no summary'
    if summary.statistics.message_count != listed:
        return (f'metadata.yaml lists {listed} messages, the MCAP summary '
                f'{summary.statistics.message_count}')
    return None


def _provisional(directory: Path) -> dict[str, Any]:
    """The bag's metadata.yaml, if it can be parsed (the recorder keeps it current)."""
    try:
        data = yaml.safe_load((directory / 'metadata.yaml').read_text(encoding='utf8'))
        info = data['rosbag2_bagfile_information']
        return info if isinstance(info, dict) else {}
    except (OSError, ValueError, yaml.YAMLError, KeyError, TypeError):  # ValueError: not UTF-8
        return {}


@dataclass
class _Scan:
    """What reading a damaged MCAP file found besides its records."""

    compression: str = ''
    stopped_at: int = 0                  # end of the last complete record
    error: BaseException | None = None   # what stopped the reading
    custom_data: dict[str, str] = field(default_factory=dict)


def _records(stream: BinaryIO, size: int,
             scan: _Scan) -> Iterator[Schema | Channel | Message]:
    """Schemas, channels and messages of every complete record, then stop."""
    # No record is longer than the file: a corrupt length stops the reading.
    reader = StreamReader(stream, emit_chunks=True, record_size_limit=max(size, 1))
    try:
        for record in reader.records:
            if isinstance(record, Chunk):
                scan.compression = scan.compression or record.compression
                inner = breakup_chunk(record, validate_crc=True)
                scan.stopped_at = stream.tell()
                yield from (r for r in inner if isinstance(r, (Schema, Channel, Message)))
                continue
            scan.stopped_at = stream.tell()
            if isinstance(record, (Schema, Channel, Message)):
                yield record
            elif isinstance(record, Metadata) and record.name == 'rosbag2':
                meta = yaml.safe_load(record.metadata.get('serialized_metadata', '')) or {}
                scan.custom_data = {str(k): str(v)
                                    for k, v in (meta.get('custom_data') or {}).items()}
    except Exception as exc:  # the damaged tail: truncated or malformed record
        scan.error = exc


def _backup_name(path: Path) -> Path:
    candidate = path.with_name(path.name + '.bak')
    n = 1
    while candidate.exists():
        candidate = path.with_name(f'{path.name}.bak.{n}')
        n += 1
    return candidate


def repair(path: str | Path, *, force: bool = False) -> RepairResult:
    """Rewrite a damaged bag from its readable part (see the module docstring).

    Args:
        path: the bag directory (or its .mcap file).
        force: rewrite even an intact bag (e.g. to regenerate metadata.yaml).

    Returns:
        The recovered counts; ``backups`` is empty when the bag was intact.

    Raises:
        BagError: not a bag, a file that is not MCAP at all, or a bag a live
            recorder is still writing.

    """
    directory, mcap = find_mcap(path)
    if is_being_written(mcap):
        raise BagError(f'{mcap} is still being recorded; stop the recorder first')
    reason = problem(directory)
    size = mcap.stat().st_size
    if reason is None and not force:
        return RepairResult(directory, counts={}, stopped_at=size, file_size=size)
    reason = reason or 'forced'
    work = directory / '.repair'
    shutil.rmtree(work, ignore_errors=True)
    staging = work / mcap.stem  # the writer names the .mcap after its directory
    try:
        scan, counts = _rewrite(mcap, staging, _provisional(directory), reason)
        backups = []
        for original, new in ((mcap, staging / mcap.name),
                              (directory / 'metadata.yaml', staging / 'metadata.yaml')):
            if original.exists():
                backup = _backup_name(original)
                os.replace(original, backup)
                backups.append(backup)
            os.replace(new, original)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return RepairResult(directory, counts, backups, scan.stopped_at, size, reason)


def _rewrite(mcap: Path, staging: Path, provisional: dict[str, Any],
             reason: str) -> tuple[_Scan, dict[str, int]]:
    """Copy the readable records of ``mcap`` into a new bag at ``staging``."""
    known = {t['topic_metadata']['name']: t['topic_metadata']
             for t in provisional.get('topics_with_message_count') or []
             if isinstance(t, dict) and 'topic_metadata' in t}
    size = mcap.stat().st_size
    scan = _Scan()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Connection] = {}
    with mcap.open('rb') as stream:
        records = _records(stream, size, scan)
        first = next(records, None)  # reads the first chunk, which tells the compression
        if isinstance(scan.error, InvalidMagic) and size > 0:
            raise BagError(f'{mcap} is not an MCAP file')
        compression = 'zstd' if scan.compression == 'zstd' else 'none'
        with BagWriter(staging, compression=compression) as bag:
            for record in itertools.chain([first] if first is not None else [], records):
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel) and record.id not in channels:
                    channels[record.id] = _add_channel(bag, record, schemas, known)
                elif isinstance(record, Message) and record.channel_id in channels:
                    bag.write(channels[record.channel_id], record.log_time, record.data)
            recovered = {c.topic for c in channels.values()}
            for name, meta in known.items():
                if name not in recovered:
                    _add_known_topic(bag, name, meta)
            custom = dict(provisional.get('custom_data') or {}) or scan.custom_data
            for key, value in custom.items():
                bag.set_custom_data(str(key), str(value))
            bag.set_custom_data(REPAIRED_KEY, (
                f'{datetime.now(UTC).isoformat(timespec="seconds")}: '
                f'{sum(bag.counts.values())} messages recovered from the first '
                f'{scan.stopped_at} of {size} bytes ({reason})'))
            counts = bag.counts
    return scan, counts


def _add_channel(bag: BagWriter, channel: Channel, schemas: dict[int, Schema],
                 known: dict[str, Any]) -> Connection:
    schema = schemas.get(channel.schema_id)
    if schema is None:
        raise BagError(f'channel {channel.topic} refers to a missing schema')
    msgdef = schema.data.decode()
    meta = known.get(channel.topic, {})
    type_hash = meta.get('type_description_hash') or hash_of_definition(schema.name, msgdef)
    qos_text = channel.metadata.get('offered_qos_profiles', '')
    return bag.add_topic(channel.topic, schema.name, qos=parse_qos(qos_text),
                         msgdef=msgdef, rihs01=type_hash)


def _add_known_topic(bag: BagWriter, name: str, meta: dict[str, Any]) -> None:
    """A topic the provisional metadata names but no complete chunk reached."""
    try:
        msgdef, type_hash = message_definition(meta['type'])
    except (BagError, KeyError):
        return
    bag.add_topic(name, meta['type'], qos=parse_qos(meta.get('offered_qos_profiles') or []),
                  msgdef=msgdef, rihs01=meta.get('type_description_hash') or type_hash)
