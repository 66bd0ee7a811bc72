"""Walk an MCAP file's records front to back, fast, checking every CRC and stopping cleanly at a truncation.

The mcap library's readers parse every record of a chunk into a dataclass
through a dozen small reads; with one order frame and one gating record per
revolution that per-record cost, not decompression, was most of a replay's
reading time, and the message indexes after each chunk (useless to a
front-to-back read) cost as much again. Here records are framed with
``struct`` (opcode, length) against the file size, so a record cut by the
end of the file is recognised without reading it (:class:`Truncated`);
indexes are skipped after a six-byte look that they are indexes, and a
chunk's records are parsed with ``struct.unpack_from`` over the decompressed
buffer, copying only the messages of the wanted topics (a message's record
head and content head in one call on the bytes: the 60 s log's chunk loop,
6500 records, 1.8 -> 1.2 ms of GIL-held Python, its definitions still
parsed by the mcap library's record classes, a handful per file).
``RecordedLog.messages(reference=True)`` reads through the mcap readers
instead; a test checks both agree on whole and cut files.

Damage. Every chunk is checked before its records are read: a known
compression, a declared size within :data:`replay.mcap_records.MAX_CHUNK_BYTES` (a 32 KB zstd
bomb or a chunk declaring 2**40 bytes is refused before anything is
allocated), the decompressed size as declared, and the CRC. A chunk that
fails (:class:`BadChunk`), and a record whose opcode has no business in the
data section (a flipped opcode), are skipped and reported with the stream
times around them (:class:`Skipped`), like the lost tail of a truncated
file; the walk goes on with the next record.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import IO, Any

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Message, Schema

from replay.mcap_records import (
    DATA_OPCODES,
    MESSAGE_HEAD,
    RECORD_HEAD,
    BadChunk,
    chunk_payload,
    ends_data,
    looks_like_index,
    parse_definition,
    read_at,
    records,
)

_MESSAGE = int(Opcode.MESSAGE)
# A record head and a message's content up to its log time, in one struct call: opcode,
# length, channel id, sequence, log time
_HEAD = struct.Struct("<BQHIQ")
_UNKNOWN = ("", "")  # a channel not looked up yet in this walk

# (topic, schema name, log time ns, data: bytes, or a memoryview with ``views=True``)
MessageTuple = tuple[str, str, int, Any]


@dataclass
class Skipped:
    """A damaged part of a recording, skipped.

    Attributes
    ----------
    offset : byte offset of the damaged record.
    reason : one line.
    after_ns : log time (ns) of the last message read before it (None: from the start).
    before_ns : log time (ns) of the first message read after it (None: to the end).
    """

    offset: int
    reason: str
    after_ns: int | None = None
    before_ns: int | None = None


# What reading a damaged or cut file can raise besides McapError (Truncated among
# them): struct (a short field), zstandard (a damaged frame), UnicodeDecodeError ...
READ_ERRORS: tuple[type[Exception], ...] = (
    McapError,
    struct.error,
    zstandard.ZstdError,
    ValueError,
    EOFError,
    OSError,
    IndexError,
    KeyError,
    RuntimeError,
)


_pread = getattr(os, "pread", None)  # POSIX only


class MessageWalk:
    """Messages of ``topics`` in file order (raises on a cut file; see :func:`walk_messages`).

    A damaged chunk or top-level record is skipped and handed to ``on_skip``
    as a :class:`Skipped` whose ``before_ns`` is filled in when the next good
    message is read.

    Parameters
    ----------
    path : the MCAP file.
    topics : wanted topics (others are skipped without being copied).
    on_skip : called once per damaged record.
    chunks : byte offsets and lengths of the chunk records, from a summary whose
        CRC was checked; the walk then reads those records only, so a damaged
        record header between them cannot lose the rest. None: front to back.
    channels : channel id -> (topic, schema name) known before the walk (from the
        summary, or the first chunk), so a damaged first chunk does not lose them.
    check_crcs : check each chunk's CRC (False: the data section's CRC matched).
    views : a chunk's messages as memoryviews of its payload, not copies (each holds the
        chunk's bytes; replay decodes and drops them: 0.46 MB copied per sample block saved).
    """

    def __init__(
        self,
        path: str | Path,
        topics: set[str],
        on_skip: Callable[[Skipped], None] = lambda _: None,
        chunks: list[tuple[int, int]] | None = None,
        channels: dict[int, tuple[str, str]] | None = None,
        check_crcs: bool = True,
        views: bool = False,
    ) -> None:
        self.path = Path(path)
        self.check_crcs = check_crcs
        self.views = views
        self.topics = topics
        self.on_skip = on_skip
        self.chunks = chunks
        self.schemas: dict[int, str] = {}  # schema id -> name
        self.channels: dict[int, tuple[str, int]] = {}  # channel id -> (topic, schema id)
        for cid, (topic, name) in (channels or {}).items():  # negative ids: not the file's
            self.schemas[-cid - 1] = name
            self.channels[cid] = (topic, -cid - 1)
        # channel id -> (topic, schema name), None if not wanted: _wanted's answers until the
        # next definition (asked per chunk, 800 calls a minute of log)
        self._known: dict[int, tuple[str, str] | None] = {}
        self._last_ns: int | None = None  # log time of the last message read
        self._open: list[Skipped] = []  # skipped, waiting for the next message's time

    def __iter__(self) -> Iterator[MessageTuple]:
        zstd = zstandard.ZstdDecompressor()
        with open(self.path, "rb") as fh:
            for opcode, offset, length, read in self._records(fh):
                if ends_data(opcode, length):
                    return  # the summary section repeats what we have seen
                if opcode == Opcode.CHUNK:
                    try:
                        content = read_at(fh, offset, length) if read is None else read
                        payload = chunk_payload(content, self.check_crcs, zstd)
                        # (not held while the chunk's messages are read; read by the summary,
                        # the walk keeps the record until the next chunk's: one chunk)
                        del content, read
                    except BadChunk as err:
                        self._skip(offset - RECORD_HEAD.size, str(err))
                        continue
                    yield from self._chunk(payload, offset - RECORD_HEAD.size)
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    self._define(parse_definition(opcode, read_at(fh, offset, length)))
                elif opcode == Opcode.MESSAGE:
                    msg = Message.read(ReadDataStream(BytesIO(read_at(fh, offset, length))), length)
                    self._seen(msg.log_time)
                    out = self._wanted(msg.channel_id)
                    if out is not None:
                        yield out[0], out[1], msg.log_time, msg.data
                elif opcode not in DATA_OPCODES or (
                    opcode == Opcode.MESSAGE_INDEX
                    and not looks_like_index(read_at(fh, offset, 6), length)
                ):  # a flipped opcode: most likely a chunk
                    self._skip(
                        offset - RECORD_HEAD.size,
                        f"damaged record (opcode {opcode:#04x}, {length} bytes)",
                    )

    def _records(self, fh: IO[bytes]) -> Iterator[tuple[int, int, int, memoryview | None]]:
        """(opcode, content offset, content length, the content when read already)."""
        if self.chunks is None:
            for opcode, offset, length in records(fh):
                yield opcode, offset, length, None
            return
        fd = fh.fileno()
        size = os.fstat(fd).st_size
        for offset, length in self.chunks:  # from the summary's chunk indexes
            if offset + length > size:  # (a summary without CRC may say anything)
                self._skip(offset, f"chunk record of {length} bytes runs past the end of the file")
                continue
            # head and content in one read: each read releases the GIL, and in a replay
            # the processing thread, which holds it most of the time, waits to get it back
            # (a seek, a buffered read of the head and one of the content were three)
            # (os.pread is POSIX: elsewhere a seek and a read)
            record = memoryview(
                _pread(fd, length, offset) if _pread else read_at(fh, offset, length)
            )
            head = record[: RECORD_HEAD.size]
            _, declared = RECORD_HEAD.unpack(head) if len(head) == RECORD_HEAD.size else (0, 0)
            if declared != length - RECORD_HEAD.size:
                self._skip(offset, "damaged chunk record header")
                continue
            # a damaged opcode alone is harmless here: the content's CRC decides
            yield Opcode.CHUNK, offset + RECORD_HEAD.size, declared, record[RECORD_HEAD.size :]

    def _skip(self, offset: int, reason: str) -> None:
        skipped = Skipped(offset, reason, after_ns=self._last_ns)
        self._open.append(skipped)
        self.on_skip(skipped)

    def _seen(self, log_time: int) -> None:
        if self._open:
            for skipped in self._open:
                skipped.before_ns = log_time
            self._open = []
        self._last_ns = log_time

    def _define(self, record: Schema | Channel) -> None:
        self._known.clear()
        if isinstance(record, Schema):
            self.schemas[record.id] = record.name
        else:
            self.channels[record.id] = (record.topic, record.schema_id)

    def _wanted(self, channel_id: int) -> tuple[str, str] | None:
        entry = self.channels.get(channel_id)
        if entry is None:
            raise BadChunk(f"message on channel {channel_id} before its channel record")
        topic, schema_id = entry
        if topic not in self.topics:
            return None
        return topic, self.schemas.get(schema_id, "")

    def _chunk(self, payload: bytes, offset: int) -> Iterator[MessageTuple]:
        """The wanted messages of a chunk. Its records are framed here, with the checks of
        :func:`replay.mcap_records.chunk_records`: most messages of a recording (frames,
        gating) are not the raw stream a replay wants, and skipping each through that
        generator cost about 3 us (items() of a 60 s log: 26 -> 19 ms of CPU). A message's
        record head and the head of its content are one ``struct`` call on the bytes (a
        memoryview's buffer is looked up on every call): 6000 skipped a minute."""
        # the names the loop reads, local (6000 turns a minute of log)
        unpack_head, head_size = _HEAD.unpack_from, _HEAD.size
        record_head, message_head, message = RECORD_HEAD.size, MESSAGE_HEAD.size, _MESSAGE
        wanted, unknown = self._known, _UNKNOWN
        pending = bool(self._open)  # skipped records waiting for the next message's time
        pos, end, last_ns = 0, len(payload), self._last_ns
        view = memoryview(payload) if self.views else None
        try:
            while pos < end:
                if pos + head_size <= end:  # a message's record always is that long
                    opcode, length, channel_id, _, log_ns = unpack_head(payload, pos)
                else:  # then no message fits: its checks below fail
                    channel_id = log_ns = 0
                    if pos + record_head > end:
                        raise BadChunk("chunk ends inside a record header")
                    opcode, length = RECORD_HEAD.unpack_from(payload, pos)
                start = pos + record_head
                pos = start + length
                if pos > end:
                    raise BadChunk(f"chunk record of {length} bytes runs past the chunk's end")
                if opcode == message and length >= message_head:
                    last_ns = log_ns
                    if pending:
                        self._seen(log_ns)
                        pending = False
                    out = wanted.get(channel_id, unknown)
                    if out is unknown:
                        out = wanted[channel_id] = self._wanted(channel_id)
                    if out is not None:
                        data = start + message_head
                        yield (
                            out[0],
                            out[1],
                            last_ns,
                            view[data:pos] if view is not None else payload[data:pos],
                        )
                elif opcode == message:
                    raise BadChunk(f"message record of {length} bytes inside a chunk")
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    self._define(parse_definition(opcode, memoryview(payload)[start:pos]))
                else:
                    raise BadChunk(f"record with opcode {opcode:#04x} inside a chunk")
        except READ_ERRORS as err:  # a CRC-clean chunk that is not ours: crafted
            self._last_ns = last_ns
            self._skip(offset, f"damaged chunk ({type(err).__name__}: {err})")
        self._last_ns = last_ns


def walk_messages(
    path: str | Path,
    topics: set[str],
    on_stop: Callable[[BaseException], None],
    on_skip: Callable[[Skipped], None] = lambda _: None,
    chunks: list[tuple[int, int]] | None = None,
    channels: dict[int, tuple[str, str]] | None = None,
    check_crcs: bool = True,
    views: bool = False,
) -> Iterator[MessageTuple]:
    """:class:`MessageWalk` that hands a read error to ``on_stop`` and ends instead of raising."""
    it = iter(MessageWalk(path, topics, on_skip, chunks, channels, check_crcs, views))
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except READ_ERRORS as err:  # the caller decides whether a cut file is an error
            on_stop(err)
            return
        yield item
