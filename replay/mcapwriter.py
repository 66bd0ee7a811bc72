"""An MCAP writer whose chunks are compressed and written on a background thread.

``mcap.writer.Writer`` builds every message record through half a dozen
small writes into a ``BytesIO`` and compresses each chunk in the caller's
thread: in a profiled 60 s live run (10 channels at 25.6 kHz) that was
about half a second of the processing thread, 0.19 s of it ZSTD. Here the caller's
thread only packs a message's record header and appends ``(header, data)``
to the open chunk (about 1 us); closing a chunk hands that list to one
writer thread, which joins it, computes the CRC, compresses it (zstandard,
lz4 and file writes release the GIL, so this runs beside the caller),
indexes it and writes it (:mod:`replay.mcap_output`, the file side).

The file is the one ``mcap.writer.Writer`` (1.6, default options but
``enable_data_crcs=True``: the data end record carries the data section's
CRC) writes for the same calls, byte for byte: the same records in the same order, the
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
import threading
from collections.abc import Callable, Sequence
from typing import IO, Any

from mcap.data_stream import RecordBuilder
from mcap.records import Channel, Schema

from replay.mcap_output import (
    COMPRESSIONS,
    MESSAGE_HEADER,
    OP_MESSAGE,
    ZSTD_LEVEL,
    LateBytes,
    McapOutput,
    Payload,
    Records,
)


class ThreadedWriter:
    """Write an MCAP file; chunks are finished on a writer thread.

    The calls of ``mcap.writer.Writer`` (``enable_data_crcs=True``): ``start``,
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
    level : int
        The zstd level (3, mcap's default; the recorder passes its own).
    backlog : int
        Jobs (chunks, metadata, ...) queued for the writer thread before the caller waits.
    """

    def __init__(
        self,
        stream: IO[bytes],
        chunk_size: int = 1024 * 1024,
        compression: str = "zstd",
        backlog: int = 16,
        level: int = ZSTD_LEVEL,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise ValueError(f"compression: expected one of {COMPRESSIONS}, got {compression!r}")
        self.chunk_size = int(chunk_size)
        self._out = McapOutput(stream, compression, level)
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
        self._handed = 0  # chunks handed to the writer thread
        self._packed = 0  # chunks made on it (add_chunk)

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
        self,
        channel_id: int,
        log_time: int,
        data: Payload,
        publish_time: int,
        sequence: int = 0,
    ) -> None:
        """Append a message to the open chunk (``data`` as :class:`LateBytes`: its bytes are
        made on the writer thread)."""
        if not isinstance(data, LateBytes):  # (late bytes are made on the writer thread)
            data = bytes(data)  # free for bytes; a bytearray must not change under the writer
        head = MESSAGE_HEADER.pack(
            OP_MESSAGE, 22 + len(data), channel_id, sequence, log_time, publish_time
        )
        self._records.append((head, data))  # one step: a Ctrl-C leaves the chunk whole
        self._messages += 1
        self._size += 31 + len(data)
        if self._size > self.chunk_size:
            self._close_chunk()

    def add_chunk(self, messages: Sequence[tuple[int, int, Payload, int]]) -> None:
        """:meth:`add_message` of each ``(channel id, log time, data, publish time)``, then
        :meth:`flush`; the records are packed on the writer thread (the data is kept as it
        is: bytes or :class:`LateBytes`). The same chunks as those calls, one job: packing
        6554 messages a minute cost the caller about 7 ms."""
        records, size, count = self._records, self._size, self._messages
        self._records, self._size, self._messages = [], 0, 0
        self._submit(self._pack, records, size, count, messages)
        self._raise_error()

    def _pack(
        self, records: Records, size: int, count: int, messages: Sequence[tuple[int, int, Any, int]]
    ) -> None:
        """The writer thread's :meth:`add_message` calls and :meth:`flush` for :meth:`add_chunk`."""
        pack, limit = MESSAGE_HEADER.pack, self.chunk_size
        for channel_id, log_time, data, publish_time in messages:
            records.append(
                (pack(OP_MESSAGE, 22 + len(data), channel_id, 0, log_time, publish_time), data)
            )
            count += 1
            size += 31 + len(data)
            if size > limit:
                self._packed += 1
                self._out.chunk(records)
                records, size, count = [], 0, 0
        if count:
            self._packed += 1
            self._out.chunk(records)

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
    @property
    def chunks(self) -> int:
        """Chunks handed to the writer thread (those :meth:`add_chunk` hands over as they
        are made there)."""
        return self._handed + self._packed

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
        # the summary, if written, read them already; after a failed write it never will
        self._out.chunk_index_records.close()

    def cut_end_ns(self) -> int | None:
        """After a failed chunk write: the log time (ns) of the last message the file now
        ends readable with; None when it was not cut (or holds no message)."""
        return self._out.cut_at_ns if self._out.cut_complete else None

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
        self._handed += 1
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
