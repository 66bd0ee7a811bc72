"""The file side of :class:`replay.mcapwriter.ThreadedWriter`: records, chunks, summary, footer.

Everything here runs on the writer thread, one job at a time, in the order
the caller submitted them: the magic and the header, metadata and
attachment records, each closed chunk (its records joined, CRC'd,
compressed) followed by its message indexes, and at the end the data end
record, the summary section, the footer and the magic again, as
``mcap.writer.Writer`` (1.6, default options and ``enable_data_crcs=True``)
writes them. The data end record carries the CRC of everything before it, so
a reader can tell damage outside the chunks (the run metadata, a record
header), which no other CRC covers. :class:`McapOutput`
keeps the indexes and statistics the summary needs.
"""

from __future__ import annotations

import io
import os
import struct
from collections.abc import Callable
from itertools import chain
from typing import IO, Any

import lz4.frame
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)

from replay.mcap_records import MAGIC, crc32
from replay.spilled_bytes import SpilledBytes

COMPRESSIONS = ("zstd", "lz4", "")
# os.writev takes at most this many buffers (EINVAL beyond): a chunk is 4 parts and one per
# channel in it, so only a chunk of over a thousand topics is joined instead
_IOV_MAX = os.sysconf("SC_IOV_MAX") if "SC_IOV_MAX" in os.sysconf_names else 1024
# zstandard.compress's (and so mcap's) default level; the recorder chooses its own
# (replay.recorder.ZSTD_LEVEL, docs/recording-format.md)
ZSTD_LEVEL = 3
# zstd's fastest (negative: less search, more literal blocks) to its strongest level
ZSTD_LEVELS = range(-50, 23)


def check_level(level: int) -> int:
    """``level`` if it is a zstd level this writer accepts, else ValueError naming it."""
    if isinstance(level, bool) or not isinstance(level, int) or level not in ZSTD_LEVELS:
        raise ValueError(
            f"zstd level: expected an integer from {ZSTD_LEVELS[0]} to {ZSTD_LEVELS[-1]}, "
            f"got {level!r}"
        )
    return level


OP_MESSAGE = int(Opcode.MESSAGE)
# opcode, record length, channel id, sequence, log time, publish time
MESSAGE_HEADER = struct.Struct("<BQHIQQ")
_MESSAGE_KEY = struct.Struct("<HIQ")  # channel id, sequence, log time (at byte 9 of the header)
# opcode, record length, start time, end time, uncompressed size, crc, compression name length
_CHUNK = struct.Struct("<BQQQQII")


class LateBytes:
    """A message's data whose bytes are made on the writer thread, in its chunk's buffer;
    its length is known when the message is added (the chunk's size bound and the record
    header need it). What a subclass holds must not change until the chunk is written."""

    __slots__ = ("size",)

    def __init__(self, size: int) -> None:
        self.size = size

    def __len__(self) -> int:
        return self.size

    def write_into(self, view: memoryview) -> None:
        """Write the data into ``view`` (``size`` bytes)."""
        raise NotImplementedError


Payload = bytes | LateBytes  # a message's data

# (record header, data) pairs of the open chunk: a message is its header and
# payload, a schema or channel record is its bytes and b""
Records = list[tuple[bytes, Payload]]


class McapOutput:
    """The file side: what the writer thread does, and the indexes it keeps."""

    def __init__(self, stream: IO[bytes], compression: str, level: int = ZSTD_LEVEL) -> None:
        self.stream = stream
        self.compression = compression
        self.level = check_level(level)
        self.pos = 0
        # the chunk index records, serialised as they come and kept on disk until the
        # summary: as objects they held 1.4 KB a chunk (10 MB per hour of 0.5 s chunks), as
        # bytes in memory 0.2 KB (1.4 MB an hour, grown by reallocation)
        self.chunk_index_records = SpilledBytes()
        self.chunk_count = 0
        self._buffer = bytearray()  # the chunk payload's (_payload)
        self.attachment_indexes: list[AttachmentIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.message_counts: dict[int, int] = {}  # per channel, in order of first message
        self.message_count = 0
        self.start_time = 0
        self.end_time = 0
        self._compress: Callable[[Any], bytes] | None = None
        self.data_crc: int | None = 0  # CRC of the data section so far; None after it
        # set by cut(): log time of the last message kept (None: none), and whether the
        # file was closed readable there
        self.cut_at_ns: int | None = None
        self.cut_complete = False

    def write(self, data: bytes | bytearray | memoryview) -> None:
        # an unbuffered file may take part of the bytes per call (a disk filling up)
        view = memoryview(data).cast("B")
        while view:
            n = self.stream.write(view)
            n = len(view) if n is None else n
            self.pos += n
            if self.data_crc is not None:
                self.data_crc = crc32(view[:n], self.data_crc)
            view = view[n:]

    def write_parts(self, parts: list[bytes]) -> None:
        """:meth:`write` of the parts joined; to a plain file (``io.FileIO`` itself, whose
        ``write`` nothing overrides) with ``os.writev``, one system call without the copy:
        joining a chunk's ~0.5 MB into fresh memory held the GIL, page faults included
        (writer thread 0.077-0.082 -> 0.072-0.077 s of CPU a minute, ab_rec.py)."""
        if type(self.stream) is not io.FileIO or len(parts) > _IOV_MAX:
            self.write(b"".join(parts))
            return
        n = os.writev(self.stream.fileno(), parts)
        self.pos += n
        for i, part in enumerate(parts):
            if n >= len(part):
                if self.data_crc is not None:
                    self.data_crc = crc32(part, self.data_crc)
                n -= len(part)
                continue
            view = memoryview(part)  # a short write (a disk filling up): the rest as write's
            if self.data_crc is not None:
                self.data_crc = crc32(view[:n], self.data_crc)
            self.write(view[n:])
            for rest in parts[i + 1 :]:
                self.write(rest)
            return

    def flush(self) -> None:
        self.stream.flush()

    def header(self, profile: str, library: str) -> None:
        self.pos = self.stream.tell()
        self.write(MAGIC)
        self._record(Header(profile, library))
        self.flush()

    def metadata(self, name: str, data: dict[str, str]) -> None:
        offset = self.pos
        length = self._record(Metadata(name=name, metadata=data))
        self.metadata_indexes.append(MetadataIndex(offset=offset, length=length, name=name))

    def attachment(
        self, create_time: int, log_time: int, name: str, media_type: str, data: bytes
    ) -> None:
        offset = self.pos
        record = Attachment(create_time, log_time, name, media_type, data)
        length = self._record(record)
        self.attachment_indexes.append(
            AttachmentIndex(offset, length, log_time, create_time, len(data), name, media_type)
        )

    def chunk(self, records: Records) -> None:
        """Write one chunk record (late data made in :meth:`_payload`), its indexes; flush."""
        index: dict[int, list[int]] = {}  # channel id -> [log time, offset, ...]
        late: list[int] = []  # records whose data is LateBytes
        start, end = None, 0
        offset = 0
        for i, (head, data) in enumerate(records):
            if head[0] == OP_MESSAGE:
                channel_id, _, log_time = _MESSAGE_KEY.unpack_from(head, 9)
                index.setdefault(channel_id, []).extend((log_time, offset))
                start = log_time if start is None else min(start, log_time)
                end = max(end, log_time)
                if type(data) is not bytes:
                    late.append(i)
            offset += len(head) + len(data)
        assert start is not None, "a chunk without messages"
        # (nothing counted before the payload is made: a failure leaves the statistics whole)
        payload = self._payload(records, late, offset)
        counts = self.message_counts
        for channel_id, entries in index.items():
            counts[channel_id] = counts.get(channel_id, 0) + len(entries) // 2
        end_before = self.end_time if self.chunk_count else None
        self.start_time = start if not self.message_count else min(self.start_time, start)
        self.end_time = max(self.end_time, end)
        self.message_count += sum(len(v) for v in index.values()) // 2

        crc = crc32(payload)
        data = self._compressed(payload)
        name = self.compression.encode()
        length = 8 + 8 + 8 + 4 + 4 + len(name) + 8 + len(data)
        head = _CHUNK.pack(int(Opcode.CHUNK), length, start, end, len(payload), crc, len(name))
        chunk_offset = self.pos
        index_start = pos = chunk_offset + 9 + length
        offsets: dict[int, int] = {}
        parts = [head, name, struct.pack("<Q", len(data)), data]
        for channel_id, entries in index.items():
            offsets[channel_id] = pos
            n = len(entries)
            parts.append(
                struct.pack(
                    f"<BQHI{n}Q", int(Opcode.MESSAGE_INDEX), 6 + 8 * n, channel_id, 8 * n, *entries
                )
            )
            pos += len(parts[-1])
        # one write, one system call: each call that releases the GIL costs the caller's
        # thread a GIL hand-over when it takes it back
        crc_before = self.data_crc
        try:
            self.write_parts(parts)
            self.flush()
        except OSError:
            self.cut(chunk_offset, crc_before, end_before)
            raise
        record = RecordBuilder()
        ChunkIndex(
            message_start_time=start,
            message_end_time=end,
            chunk_start_offset=chunk_offset,
            chunk_length=9 + length,
            message_index_offsets=offsets,
            message_index_length=pos - index_start,
            compression=self.compression,
            compressed_size=len(data),
            uncompressed_size=len(payload),
        ).write(record)
        self.chunk_index_records.append(record.end())
        self.chunk_count += 1

    def _payload(self, records: Records, late: list[int], size: int) -> bytes | memoryview:
        """The chunk's records in one buffer reused from chunk to chunk, the late data made
        in place (a sample block cast straight into it): the cast array, the joined payload
        and the fresh 0.5 MB they took each chunk cost page faults, the join's with the GIL
        held (writer thread 0.073-0.077 -> 0.067-0.073 s of CPU a minute, ab_rec.py)."""
        if not late:
            return b"".join(chain.from_iterable(records))  # type: ignore[arg-type]
        if len(self._buffer) < size:
            self._buffer = bytearray(size)
        view = memoryview(self._buffer)[:size]
        pos = begin = 0
        for i in [*late, len(records)]:
            if i > begin:  # the records before it, as they are
                run = b"".join(chain.from_iterable(records[begin:i]))  # type: ignore[arg-type]
                view[pos : pos + len(run)] = run
                pos += len(run)
            if i < len(records):
                head, data = records[i]
                view[pos : pos + len(head)] = head
                pos += len(head)
                assert isinstance(data, LateBytes)
                data.write_into(view[pos : pos + data.size])
                pos += data.size
            begin = i + 1
        return view

    def summary(self, schemas: list[Schema], channels: list[Channel]) -> None:
        """Data end, the summary section (as ``mcap.writer.Writer.finish``), footer, magic."""
        data_crc, self.data_crc = self.data_crc or 0, None
        self._record(DataEnd(data_crc))
        summary_start = self.pos
        builder = RecordBuilder()
        offsets: list[SummaryOffset] = []

        def group(opcode: Opcode, records: list[Any]) -> None:
            begin = builder.count
            for record in records:
                record.write(builder)
            offsets.append(SummaryOffset(opcode, summary_start + begin, builder.count - begin))

        statistics = Statistics(
            attachment_count=len(self.attachment_indexes),
            channel_count=len(channels),
            channel_message_counts=self.message_counts,
            chunk_count=self.chunk_count,
            message_count=self.message_count,
            message_end_time=self.end_time,
            message_start_time=self.start_time,
            metadata_count=len(self.metadata_indexes),
            schema_count=len(schemas),
        )
        group(Opcode.SCHEMA, schemas)
        group(Opcode.CHANNEL, channels)
        group(Opcode.STATISTICS, [statistics])
        begin = builder.count
        builder.write(self.chunk_index_records.getvalue())
        self.chunk_index_records.close()
        offsets.append(
            SummaryOffset(Opcode.CHUNK_INDEX, summary_start + begin, builder.count - begin)
        )
        group(Opcode.ATTACHMENT_INDEX, self.attachment_indexes)
        group(Opcode.METADATA_INDEX, self.metadata_indexes)
        offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        footer_start = summary_start if summary else 0
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, footer_start, offset_start)
        crc = crc32(footer_head, crc32(summary))
        self.write(summary)
        self._record(Footer(footer_start, offset_start, crc))
        self.write(MAGIC)
        self.flush()

    def cut(self, offset: int, data_crc: int | None, end_ns: int | None) -> None:
        """End the file at ``offset`` (after the last complete chunk) as a finished MCAP
        without summary: data end, footer, magic. Readers read it linearly, ``mcap``'s
        included, and lose only the chunk that did not fit.

        For a write that failed (a full disk): cutting frees the failed chunk's bytes, so
        the few bytes of the end fit. When even that fails the file stays an unfinished
        recording, which :mod:`replay.reader` still recovers.
        """
        self.cut_at_ns = end_ns  # the last message kept
        try:
            self.stream.seek(offset)
            self.stream.truncate(offset)
            self.pos, self.data_crc = offset, data_crc
            self._record(DataEnd(data_crc or 0))
            self.data_crc = None
            self._record(Footer(0, 0, 0))  # summary start 0: no summary section
            self.write(MAGIC)
            self.flush()
            self.cut_complete = True
        except OSError:
            pass  # the write's own error is the one reported

    def _record(self, record: Any) -> int:
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        self.write(data)
        return len(data)

    def _compressed(self, payload: bytes | memoryview) -> bytes:
        if self._compress is None:
            if self.compression == "zstd":
                self._compress = zstandard.ZstdCompressor(level=self.level).compress
            elif self.compression == "lz4":
                self._compress = lz4.frame.compress
            else:
                self._compress = bytes
        return self._compress(payload)
