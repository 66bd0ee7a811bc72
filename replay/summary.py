"""A finished recording's summary section, read from its bytes.

The summary (chunk indexes, schemas, channels, statistics, metadata and
attachment indexes) is read once when a log is opened, before a replay
starts. The mcap library's ``SeekingReader.get_summary`` parses each of its
records through a stream of small reads: a chunk index alone (one per chunk,
with the offsets of its message indexes for every channel) was about 30 of
them, 3400 for a 60 s log, 1.5 ms of the replay's set-up holding the GIL.
Here the records are framed with ``struct`` over the bytes
:func:`replay.integrity.check_summary_crc` read and checked, a chunk index is
read up to the five numbers a replay uses (its time range, its chunk's
offset and length, and the length of the message indexes after the chunk,
with which :func:`untiled` checks a summary without CRC), and the few other records go through the mcap library's
record classes, as before. A test checks both readers agree on our files and on
the mcap writer's.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from io import BytesIO
from typing import IO

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    AttachmentIndex,
    Channel,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)

from replay.mcap_records import RECORD_HEAD, read_at

# message start time, message end time, chunk start offset, chunk length
_CHUNK_INDEX = struct.Struct("<QQQQ")
# Records MCAP puts in the data section only: one in a summary is damage (a chunk index
# 0x08 flipped to an attachment 0x09, a metadata index 0x0D to metadata 0x0C), not a
# record to skip, or a summary without CRC loses the index without a word.
_DATA_ONLY = frozenset(
    int(op)
    for op in (
        Opcode.HEADER,
        Opcode.FOOTER,
        Opcode.MESSAGE,
        Opcode.CHUNK,
        Opcode.MESSAGE_INDEX,
        Opcode.ATTACHMENT,
        Opcode.METADATA,
        Opcode.DATA_END,
    )
)


@dataclass(frozen=True)
class ChunkSpan:
    """A chunk index's numbers a replay reads: log times (ns), the chunk record's place, and
    the length of the message index records that follow it (bytes; -1: unreadable)."""

    message_start_time: int
    message_end_time: int
    chunk_start_offset: int
    chunk_length: int
    message_index_length: int


@dataclass
class SummaryRecords:
    """The records of a summary section, as ``mcap.reader.Summary`` holds them."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunk_indexes: list[ChunkSpan] = field(default_factory=list)
    attachment_indexes: list[AttachmentIndex] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    statistics: Statistics | None = None


def _records(summary: bytes) -> Iterator[tuple[int, memoryview]]:
    """``(opcode, content)`` of each record of a summary section (footer excluded)."""
    view = memoryview(summary)
    pos, end = 0, len(view)
    while pos < end:
        if pos + RECORD_HEAD.size > end:
            raise McapError(f"summary ends inside a record header at byte {pos}")
        opcode, length = RECORD_HEAD.unpack_from(view, pos)
        pos += RECORD_HEAD.size
        if pos + length > end:
            raise McapError(f"summary record of {length} bytes runs past the footer")
        yield opcode, view[pos : pos + length]
        pos += length


def _stream(content: memoryview) -> ReadDataStream:
    return ReadDataStream(BytesIO(bytes(content)))


def read_summary(summary: bytes) -> SummaryRecords:
    """The records of a summary section's bytes (its CRC checked by the caller); raises
    McapError or ``struct.error`` on a record that does not parse or has no place in a
    summary. Unknown records and summary offsets are skipped, as the mcap reader does."""
    out = SummaryRecords()
    for opcode, content in _records(summary):
        if opcode in _DATA_ONLY:
            raise McapError(f"a record with opcode {opcode:#04x} in the summary section")
        if opcode == Opcode.CHUNK_INDEX:
            start, end, offset, length = _CHUNK_INDEX.unpack_from(content, 0)
            # the message index offsets (a map of its own byte length) lie between; a
            # damaged map length leaves the span unknown (untiled: -1), not the summary
            (map_bytes,) = struct.unpack_from("<I", content, _CHUNK_INDEX.size)
            at = _CHUNK_INDEX.size + 4 + map_bytes
            indexes = struct.unpack_from("<Q", content, at)[0] if at + 8 <= len(content) else -1
            out.chunk_indexes.append(ChunkSpan(start, end, offset, length, indexes))
        elif opcode == Opcode.SCHEMA:
            schema = Schema.read(_stream(content))
            out.schemas[schema.id] = schema
        elif opcode == Opcode.CHANNEL:
            channel = Channel.read(_stream(content))
            out.channels[channel.id] = channel
        elif opcode == Opcode.STATISTICS:
            out.statistics = Statistics.read(_stream(content))
        elif opcode == Opcode.METADATA_INDEX:
            out.metadata_indexes.append(MetadataIndex.read(_stream(content)))
        elif opcode == Opcode.ATTACHMENT_INDEX:
            out.attachment_indexes.append(AttachmentIndex.read(_stream(content)))
    return out


def omission(summary: SummaryRecords, checked: bool) -> str | None:
    """What the summary leaves out (None: it indexes every chunk, metadata record and
    attachment and repeats every schema and channel), judged by its statistics when it
    has them.

    mcap's ``Writer`` writes a valid file without chunk indexes (``use_chunking=False``, or
    ``index_types`` without ``CHUNK``), without metadata or attachment indexes, or without
    the schemas and channels (``repeat_channels=False``); a file read by its summary alone
    would then lose its messages or its run metadata without a word. In a summary without
    CRC, a count that disagrees is a record lost to damage.
    """
    stats = summary.statistics
    chunks, metas = len(summary.chunk_indexes), len(summary.metadata_indexes)
    empty = checked and stats is not None and stats.message_count == 0 == stats.chunk_count
    if chunks == 0 and not empty:  # (a file without a message needs none: its statistics
        return "no chunk index"  # say so, trusted when the summary's CRC was checked)
    if not summary.channels:
        return "no channel"
    lost = {c.schema_id for c in summary.channels.values()} - {0, *summary.schemas}
    if lost:
        return f"a channel refers to schema {min(lost)}, which it does not hold"
    if stats is None:
        return "no metadata index" if metas == 0 else None
    for what, held, counted in (
        ("chunk index(es)", chunks, stats.chunk_count),
        ("metadata index(es)", metas, stats.metadata_count),
        ("attachment index(es)", len(summary.attachment_indexes), stats.attachment_count),
        ("channel(s)", len(summary.channels), stats.channel_count),
        ("schema(s)", len(summary.schemas), stats.schema_count),
    ):
        if held != counted:
            return f"{held} {what}, its statistics count {counted}"
    unknown = set(stats.channel_message_counts) - set(summary.channels)
    if unknown:
        return f"its statistics count messages on channel {min(unknown)}, which it does not hold"
    return None


def untiled(summary: SummaryRecords, data_start: int, data_end: int) -> str | None:
    """Which bytes of the data section (``data_start`` to ``data_end``, the data end record)
    no index of the summary covers, or None when its chunks (with their message indexes),
    metadata and attachments follow each other from the header to the data end.

    Only for a summary without CRC: an index lost to damage that the statistics cannot
    count (they may be absent, or the index an attachment's) leaves a gap, and an index
    pointing elsewhere leaves one where its record is. (Our recorder and mcap's ``Writer``
    index every record of the data section; a writer that put channels outside chunks
    would have its files read front to back: slower, the same data.)
    """
    if any(c.message_index_length < 0 for c in summary.chunk_indexes):
        return "a chunk index's message index map is damaged"
    spans = sorted(
        [
            (c.chunk_start_offset, c.chunk_length + c.message_index_length)
            for c in summary.chunk_indexes
        ]
        + [(m.offset, m.length) for m in summary.metadata_indexes]
        + [(a.offset, a.length) for a in summary.attachment_indexes]
    )
    at = data_start
    for start, length in spans:
        if start != at:
            return (
                f"bytes {at} to {start} not indexed"
                if start > at
                else f"indexes overlap at byte {start}"
            )
        at = start + length
    return None if at == data_end else f"bytes {at} to {data_end} not indexed"


def read_metadata(fh: IO[bytes], index: MetadataIndex) -> Metadata:
    """The metadata record a metadata index points at; raises McapError when the record's
    header disagrees with the index (a damaged length is not read: it may say 2**35 bytes)."""
    content = read_indexed(fh, index.offset, index.length, Opcode.METADATA, "metadata")
    return Metadata.read(ReadDataStream(BytesIO(content)))


def read_indexed(fh: IO[bytes], offset: int, length: int, opcode: int, what: str) -> bytes:
    """The content of the ``opcode`` record an index puts at ``offset``, ``length`` bytes
    with its header; raises McapError when the record's header disagrees with the index or
    the record does not fit in the file (a summary without CRC may say 2**60 bytes)."""
    size = fh.seek(0, 2)
    head = read_at(fh, offset, RECORD_HEAD.size)
    if len(head) < RECORD_HEAD.size:
        raise McapError(f"{what} index points past the end of the file ({offset})")
    found, declared = RECORD_HEAD.unpack(head)
    if found != opcode:
        raise McapError(f"expected a {what} record at byte {offset}, got {found:#04x}")
    if declared != length - RECORD_HEAD.size or offset + length > size:
        raise McapError(
            f"{what} record at byte {offset}: {declared} bytes, its index says "
            f"{length - RECORD_HEAD.size} ({size} bytes in the file)"
        )
    return read_at(fh, offset + RECORD_HEAD.size, declared)
