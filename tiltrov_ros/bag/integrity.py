"""The MCAP file's own checks: chunk, data-section and summary CRCs.

An MCAP writer may store (the project's :class:`.writer.BagWriter` does):

* in each Chunk record the CRC-32 of its uncompressed records;
* in the DataEnd record the CRC-32 of every byte before it (the data section,
  the leading magic included);
* in the Footer the CRC-32 of the summary section and the footer's own first
  fields.

A CRC of 0 means "not computed" (the MCAP specification). :func:`check_file`
reads the file once, front to back, and reports every chunk that fails (its
byte offset, log-time range and size) and whether the data section and the
summary match. A file that ends early (a killed recorder) is reported as
truncated at the last complete record, not as damaged. Readers other than
this one either check only the chunks they decode (rosbags, the mcap
library's reader) or nothing at all.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
import struct
from typing import BinaryIO
import zlib

import zstandard

MAGIC = b'\x89MCAP0\r\n'
_CHUNK, _DATA_END, _FOOTER = 0x06, 0x0F, 0x02
#: The Footer record: opcode, length, summary_start, summary_offset_start, summary_crc.
_FOOTER_LENGTH = 1 + 8 + 8 + 8 + 4


@dataclass(frozen=True)
class BadChunk:
    """A chunk whose records do not match their CRC (or cannot be decompressed)."""

    offset: int            # byte offset of the Chunk record
    start_ns: int          # log-time range of its messages
    end_ns: int
    why: str


@dataclass
class Integrity:
    """What :func:`check_file` found."""

    chunks: int = 0                                  # chunks read
    unchecked_chunks: int = 0                        # chunks without a CRC (0)
    bad_chunks: list[BadChunk] = field(default_factory=list)
    data_crc: str = 'absent'       # 'ok', 'mismatch', 'not stored' (0), 'absent' (no DataEnd)
    summary_crc: str = 'absent'    # 'ok', 'mismatch', 'not stored' (0), 'absent' (no footer)
    truncated_at: int | None = None                  # bytes read when the file ended early

    @property
    def damaged(self) -> bool:
        """A stored CRC does not match (a truncated file is not damaged: see repair)."""
        return bool(self.bad_chunks) or 'mismatch' in (self.data_crc, self.summary_crc)

    def summary(self) -> str:
        """One line for ``tiltrov bag info``."""
        if self.bad_chunks:
            return '; '.join(f'chunk at byte {b.offset} (log time {b.start_ns / 1e9:.3f} to '
                             f'{b.end_ns / 1e9:.3f} s) fails its CRC: {b.why}'
                             for b in self.bad_chunks)
        parts = [f'{self.chunks} chunk(s)'
                 + (f', {self.unchecked_chunks} without CRC' if self.unchecked_chunks else
                    ', CRCs ok'),
                 f'data section CRC {self.data_crc}', f'summary CRC {self.summary_crc}']
        if self.truncated_at is not None:
            parts.append(f'file ends at byte {self.truncated_at} without its summary '
                         '(run tiltrov bag repair)')
        return '; '.join(parts)


def chunk_problem(compression: str, records: bytes, size: int, crc: int) -> str | None:
    """Why a chunk's records are not what its CRC says, or None (also when no CRC)."""
    try:
        if compression == 'zstd':
            raw = zstandard.ZstdDecompressor().decompress(records, max_output_size=size)
        elif compression == '':
            raw = records
        else:
            return f'unknown compression {compression!r}'
    except zstandard.ZstdError as exc:
        return f'cannot decompress ({exc})'
    if len(raw) != size:
        return f'{len(raw)} bytes uncompressed, {size} expected'
    if crc and zlib.crc32(raw) != crc:
        return f'CRC {zlib.crc32(raw):#010x}, {crc:#010x} stored'
    return None


def check_file(path: str | Path) -> Integrity:
    """Check every CRC of the MCAP file at ``path`` (see the module docstring).

    Raises OSError when the file cannot be read, ValueError when it is not MCAP.
    """
    with Path(path).open('rb') as stream:
        out = _check_data(stream)
        _check_summary(stream, out)
    return out


def _check_data(stream: BinaryIO) -> Integrity:
    """The chunks and the data-section CRC: the records up to DataEnd, in order."""
    out = Integrity()
    if stream.read(len(MAGIC)) != MAGIC:
        raise ValueError('not an MCAP file (no magic)')
    crc = zlib.crc32(MAGIC)
    offset = len(MAGIC)
    while True:
        head = stream.read(9)
        length = struct.unpack('<BQ', head)[1] if len(head) == 9 else 0
        body = stream.read(length)
        if len(head) < 9 or len(body) < length:
            out.truncated_at = offset      # a killed writer's file ends like this
            return out
        opcode = head[0]
        if opcode == _DATA_END:
            stored = struct.unpack_from('<I', body)[0]
            out.data_crc = ('not stored' if stored == 0 else
                            'ok' if stored == crc else 'mismatch')
            return out
        if opcode == _CHUNK:
            _check_chunk(out, offset, body)
        crc = zlib.crc32(body, zlib.crc32(head, crc))
        offset += 9 + len(body)


def _check_summary(stream: BinaryIO, out: Integrity) -> None:
    """The summary CRC, from the footer at the end of the file (if it is there)."""
    size = stream.seek(0, 2)
    footer_at = size - len(MAGIC) - _FOOTER_LENGTH
    if footer_at < len(MAGIC):
        return
    stream.seek(footer_at)
    tail = stream.read(_FOOTER_LENGTH + len(MAGIC))
    if tail[-len(MAGIC):] != MAGIC or tail[0] != _FOOTER:
        return
    start, _, stored = struct.unpack_from('<QQI', tail, 9)
    if stored == 0:
        out.summary_crc = 'not stored'
        return
    covered = b''
    if 0 < start <= footer_at:
        stream.seek(start)
        covered = stream.read(footer_at - start)
    crc = zlib.crc32(tail[:9 + 16], zlib.crc32(covered))
    out.summary_crc = 'ok' if crc == stored else 'mismatch'


def _check_chunk(out: Integrity, offset: int, body: bytes) -> None:
    start, end, size, crc = struct.unpack_from('<QQQI', body)
    pos = 28
    (n,) = struct.unpack_from('<I', body, pos)
    compression = body[pos + 4:pos + 4 + n].decode(errors='replace')
    pos += 4 + n
    (records_size,) = struct.unpack_from('<Q', body, pos)
    records = body[pos + 8:pos + 8 + records_size]
    out.chunks += 1
    if crc == 0:
        out.unchecked_chunks += 1
    why = chunk_problem(compression, records, size, crc)
    if why is not None:
        out.bad_chunks.append(BadChunk(offset, start, end, why))
