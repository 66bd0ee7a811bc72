"""An MCAP writer whose chunks are compressed and written on a background thread.

``mcap.writer.Writer`` builds every message record through half a dozen
small writes into a ``BytesIO`` and compresses each chunk in the caller's
thread: in a profiled 60 s live run (10 channels at 25.6 kHz) that was
about half a second of the processing thread, 0.19 s of it ZSTD. Here the caller's
thread only packs a message's record header and appends ``(header, data)``
to the open chunk (about 1 us); closing a chunk hands that list to one
writer thread, which joins it, computes the CRC, compresses it (zstandard,
lz4 and file writes release the GIL, so this runs beside the caller),
indexes it and writes it.

The file is the one ``mcap.writer.Writer`` (1.6, default options) writes
for the same calls, byte for byte: the same records in the same order, the
schemas and channels inside the first chunk, message indexes after each
chunk, the same summary section and footer. ``tests/replay/test_mcap_writer.py``
checks it.

Order and bounds. Every write is a job on one FIFO queue drained by the one
thread, so records reach the file in call order. The queue holds at most
``backlog`` jobs: a disk slower than the stream blocks the caller rather
than filling memory. After :meth:`ThreadedWriter.flush` a closed chunk is
in the file within the time it takes to compress it (a few ms for 0.5 MB);
:meth:`ThreadedWriter.sync` waits for that.

Errors. An exception in the writer thread is kept, later jobs are dropped,
and the caller's next ``flush``, ``sync`` or ``finish`` raises it.
"""

from __future__ import annotations

import queue
import struct
import threading
import zlib
from collections.abc import Callable
from itertools import chain
from typing import IO, Any

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

MAGIC = b"\x89MCAP0\r\n"
COMPRESSIONS = ("zstd", "lz4", "")
_OP_MESSAGE = int(Opcode.MESSAGE)
# opcode, record length, channel id, sequence, log time, publish time
_MESSAGE = struct.Struct("<BQHIQQ")
_MESSAGE_KEY = struct.Struct("<HIQ")  # channel id, sequence, log time (at byte 9 of the header)
# opcode, record length, start time, end time, uncompressed size, crc, compression name length
_CHUNK = struct.Struct("<BQQQQII")

# (record header, data) pairs of the open chunk: a message is its header and
# payload, a schema or channel record is its bytes and b""
Records = list[tuple[bytes, bytes]]


class ThreadedWriter:
    """Write an MCAP file; chunks are finished on a writer thread.

    The calls of ``mcap.writer.Writer`` with its default options: ``start``,
    ``add_metadata``, ``add_attachment``, ``register_schema``,
    ``register_channel``, ``add_message``, ``flush``, ``finish``; plus
    :meth:`sync`. One caller thread at a time. Message data is kept, not
    copied, until its chunk is written: ``bytes`` pass as they are, anything
    mutable is copied.

    Parameters
    ----------
    stream : binary file object, written only by the writer thread from ``start`` on.
    chunk_size : int
        A chunk is closed once its records exceed this many bytes.
    compression : ``"zstd"``, ``"lz4"`` or ``""``.
    backlog : int
        Jobs (chunks, metadata, ...) queued for the writer thread before the caller waits.
    """

    def __init__(
        self,
        stream: IO[bytes],
        chunk_size: int = 1024 * 1024,
        compression: str = "zstd",
        backlog: int = 16,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression: expected one of {COMPRESSIONS}, got {compression!r}")
        self.chunk_size = int(chunk_size)
        self._out = _Output(stream, compression)
        self._records: Records = []  # the open chunk
        self._size = 0  # bytes of the open chunk's records
        self._messages = 0  # messages in the open chunk
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._jobs: queue.Queue[tuple[Callable[..., None], tuple[Any, ...]] | None] = queue.Queue(
            maxsize=backlog
        )
        # a daemon: a writer never finished must not hold the interpreter at exit
        self._thread = threading.Thread(target=self._run, name="mcap-writer", daemon=True)
        self._error: BaseException | None = None
        self._started = self._stopped = False
        self.chunks = 0  # chunks handed to the writer thread

    # -- calls of mcap.writer.Writer ---------------------------------------------------------
    def start(self, profile: str = "", library: str = "") -> None:
        """Start the writer thread; write the magic and the header."""
        self._started = True
        self._thread.start()
        self._submit(self._out.header, profile, library)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A metadata record (written before the open chunk, as mcap's writer does)."""
        self._submit(self._out.metadata, name, dict(data))

    def add_attachment(
        self, create_time: int, log_time: int, name: str, media_type: str, data: bytes
    ) -> None:
        self._submit(self._out.attachment, create_time, log_time, name, media_type, bytes(data))

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        schema = Schema(id=len(self._schemas) + 1, data=bytes(data), encoding=encoding, name=name)
        self._schemas[schema.id] = schema
        self._add_record(schema)
        return schema.id

    def register_channel(
        self,
        topic: str,
        message_encoding: str,
        schema_id: int,
        metadata: dict[str, str] | None = None,
    ) -> int:
        channel = Channel(
            id=len(self._channels) + 1,
            topic=topic,
            message_encoding=message_encoding,
            metadata=dict(metadata or {}),
            schema_id=schema_id,
        )
        self._channels[channel.id] = channel
        self._add_record(channel)
        return channel.id

    def add_message(
        self, channel_id: int, log_time: int, data: bytes, publish_time: int, sequence: int = 0
    ) -> None:
        """Append a message to the open chunk."""
        data = bytes(data)  # free for bytes; a bytearray must not change under the writer
        head = _MESSAGE.pack(
            _OP_MESSAGE, 22 + len(data), channel_id, sequence, log_time, publish_time
        )
        self._records.append((head, data))  # one step: a Ctrl-C leaves the chunk whole
        self._messages += 1
        self._size += 31 + len(data)
        if self._size > self.chunk_size:
            self._close_chunk()

    def flush(self) -> None:
        """Close the open chunk (if it has a message) and hand it to the writer thread."""
        self._close_chunk()
        self._raise_error()

    def finish(self) -> None:
        """Close the open chunk, write the summary and the footer, stop the thread.

        Does not close the stream. Idempotent.
        """
        if self._stopped:
            return
        try:
            self._close_chunk()
            schemas, channels = list(self._schemas.values()), list(self._channels.values())
            self._submit(self._out.summary, schemas, channels)
        finally:
            self.stop()
        self._raise_error()

    # -- more ------------------------------------------------------------------------------
    def sync(self) -> None:
        """Wait until everything handed over is written and the stream flushed."""
        self._submit(self._out.flush)
        self._jobs.join()
        self._raise_error()

    def stop(self) -> None:
        """Stop the thread after the jobs already queued; the open chunk is dropped."""
        if self._stopped:
            return
        self._stopped = True
        if self._thread.is_alive():
            self._jobs.put(None)
            self._thread.join()

    # -- internals -------------------------------------------------------------------------
    def _add_record(self, record: Schema | Channel) -> None:
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        self._records.append((data, b""))
        self._size += len(data)
        if self._size > self.chunk_size:
            self._close_chunk()

    def _close_chunk(self) -> None:
        if not self._messages:  # as mcap's writer: schemas and channels wait for a message
            return
        records = self._records
        self._records, self._size, self._messages = [], 0, 0
        self.chunks += 1
        self._submit(self._out.chunk, records)

    def _submit(self, job: Callable[..., None], *args: Any) -> None:
        if not self._started:  # nothing would drain the queue
            raise RuntimeError("ThreadedWriter: start() must come first")
        if self._stopped:
            raise RuntimeError("ThreadedWriter: write after finish() or stop()")
        self._jobs.put((job, args))

    def _raise_error(self) -> None:
        if self._error is not None:
            raise self._error

    def _run(self) -> None:
        while True:
            item = self._jobs.get()
            try:
                if item is None:
                    return
                if self._error is None:  # after an error, drain without writing
                    job, args = item
                    try:
                        job(*args)
                    except BaseException as err:  # kept for the caller's thread
                        self._error = err
            finally:
                self._jobs.task_done()


class _Output:
    """The file side: what the writer thread does, and the indexes it keeps."""

    def __init__(self, stream: IO[bytes], compression: str) -> None:
        self.stream = stream
        self.compression = compression
        self.pos = 0
        self.chunk_indexes: list[ChunkIndex] = []
        self.attachment_indexes: list[AttachmentIndex] = []
        self.metadata_indexes: list[MetadataIndex] = []
        self.message_counts: dict[int, int] = {}  # per channel, in order of first message
        self.message_count = 0
        self.start_time = 0
        self.end_time = 0
        self._compress: Callable[[bytes], bytes] | None = None

    def write(self, data: bytes | bytearray | memoryview) -> None:
        self.stream.write(data)
        self.pos += len(data)

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
        """Write one chunk record and its message indexes; flush the stream."""
        index: dict[int, list[int]] = {}  # channel id -> [log time, offset, ...]
        counts = self.message_counts
        start, end = None, 0
        offset = 0
        for head, data in records:
            if head[0] == _OP_MESSAGE:
                channel_id, _, log_time = _MESSAGE_KEY.unpack_from(head, 9)
                index.setdefault(channel_id, []).extend((log_time, offset))
                counts[channel_id] = counts.get(channel_id, 0) + 1
                start = log_time if start is None else min(start, log_time)
                end = max(end, log_time)
            offset += len(head) + len(data)
        assert start is not None, "a chunk without messages"
        self.start_time = start if not self.message_count else min(self.start_time, start)
        self.end_time = max(self.end_time, end)
        self.message_count += sum(len(v) for v in index.values()) // 2

        payload = b"".join(chain.from_iterable(records))
        crc = zlib.crc32(payload)
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
        # thread a GIL hand-over when it takes it back (the copy of ~0.5 MB costs less)
        self.write(b"".join(parts))
        self.flush()
        self.chunk_indexes.append(
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
            )
        )

    def summary(self, schemas: list[Schema], channels: list[Channel]) -> None:
        """Data end, the summary section (as ``mcap.writer.Writer.finish``), footer, magic."""
        self._record(DataEnd(0))
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
            chunk_count=len(self.chunk_indexes),
            message_count=self.message_count,
            message_end_time=self.end_time,
            message_start_time=self.start_time,
            metadata_count=len(self.metadata_indexes),
            schema_count=len(schemas),
        )
        group(Opcode.SCHEMA, schemas)
        group(Opcode.CHANNEL, channels)
        group(Opcode.STATISTICS, [statistics])
        group(Opcode.CHUNK_INDEX, self.chunk_indexes)
        group(Opcode.ATTACHMENT_INDEX, self.attachment_indexes)
        group(Opcode.METADATA_INDEX, self.metadata_indexes)
        offset_start = summary_start + builder.count
        for offset in offsets:
            offset.write(builder)
        summary = builder.end()
        footer_start = summary_start if summary else 0
        footer_head = struct.pack("<BQQQ", Opcode.FOOTER, 20, footer_start, offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(summary))
        self.write(summary)
        self._record(Footer(footer_start, offset_start, crc))
        self.write(MAGIC)
        self.flush()

    def _record(self, record: Any) -> int:
        builder = RecordBuilder()
        record.write(builder)
        data = builder.end()
        self.write(data)
        return len(data)

    def _compressed(self, payload: bytes) -> bytes:
        if self._compress is None:
            if self.compression == "zstd":
                import zstandard

                # level 3 is zstandard.compress's (and so mcap's) default
                self._compress = zstandard.ZstdCompressor(level=3).compress
            elif self.compression == "lz4":
                import lz4.frame

                self._compress = lz4.frame.compress
            else:
                self._compress = bytes
        return self._compress(payload)
