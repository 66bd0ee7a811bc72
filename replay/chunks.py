"""Walk an MCAP file's records front to back, fast, stopping cleanly at a truncation.

The mcap library's readers parse every record of a chunk into a dataclass
through a dozen small reads; with one order frame and one gating record per
revolution that per-record cost, not decompression, was most of a replay's
reading time, and the message indexes after each chunk (useless to a
front-to-back read) cost as much again. Here records are framed with
``struct`` (opcode, length) against the file size, so a record cut by the
end of the file is recognised without reading it (:class:`Truncated`);
indexes are skipped unread, and a chunk's records are parsed with
``struct.unpack_from`` over the decompressed buffer, copying only the
messages of the wanted topics. ``RecordedLog.messages(reference=True)`` reads
through the mcap readers instead; a test checks both agree on whole and cut
files.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable, Iterator
from io import BytesIO
from pathlib import Path
from typing import IO

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Message, Schema

MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")  # opcode, content length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed crc

# (topic, schema name, log time ns, data)
MessageTuple = tuple[str, str, int, bytes]


class Truncated(McapError):
    """The file ends inside a record."""


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


def records(fh: IO[bytes]) -> Iterator[tuple[int, int, int]]:
    """``(opcode, content offset, content length)`` of every top-level record after the magic.

    Ends at the end of the file (a writer killed between two records) and
    raises :class:`Truncated` for a record that runs past it. The caller may
    read from ``fh`` between two steps.
    """
    size = os.fstat(fh.fileno()).st_size
    fh.seek(0)
    if fh.read(len(MAGIC)) != MAGIC:
        raise McapError("not an MCAP file")
    pos = len(MAGIC)
    while True:
        fh.seek(pos)
        head = fh.read(_RECORD.size)
        if not head:
            return
        if len(head) < _RECORD.size:
            raise Truncated(f"file ends inside a record header at byte {pos}")
        opcode, length = _RECORD.unpack(head)
        start = pos + _RECORD.size
        if start + length > size:
            raise Truncated(
                f"file ends inside a record at byte {pos} ({size - start} of {length} bytes)"
            )
        yield opcode, start, length
        pos = start + length


def read_at(fh: IO[bytes], offset: int, length: int) -> bytes:
    fh.seek(offset)
    return fh.read(length)


def chunk_times(fh: IO[bytes], offset: int) -> tuple[int, int]:
    """Log times (ns) of the first and last message of the chunk whose content starts at ``offset``."""
    start, end, _, _ = _CHUNK.unpack(read_at(fh, offset, _CHUNK.size)[: _CHUNK.size])
    return start, end


def chunk_payload(content: bytes) -> bytes:
    """The uncompressed records of a chunk record's content."""
    view = memoryview(content)
    _, _, size, _ = _CHUNK.unpack_from(view, 0)
    pos = _CHUNK.size
    (n,) = struct.unpack_from("<I", view, pos)
    compression = bytes(view[pos + 4 : pos + 4 + n]).decode()
    pos += 4 + n
    (n_data,) = struct.unpack_from("<Q", view, pos)
    data = view[pos + 8 : pos + 8 + n_data]
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        return bytes(lz4.frame.decompress(data))
    if compression == "":
        return bytes(data)
    raise McapError(f"unsupported chunk compression {compression!r}")


def chunk_records(payload: bytes) -> Iterator[tuple[int, memoryview]]:
    """``(opcode, content)`` of each record inside a chunk."""
    view = memoryview(payload)
    pos, end = 0, len(payload)
    while pos < end:
        opcode, length = _RECORD.unpack_from(view, pos)
        pos += _RECORD.size
        if pos + length > end:
            raise McapError(f"chunk record of {length} bytes runs past the chunk's end")
        yield opcode, view[pos : pos + length]
        pos += length


def parse_definition(opcode: int, content: bytes | memoryview) -> Schema | Channel:
    """A Schema or Channel record from its content."""
    stream = ReadDataStream(BytesIO(bytes(content)))
    return Schema.read(stream) if opcode == Opcode.SCHEMA else Channel.read(stream)


class MessageWalk:
    """Messages of ``topics`` in file order (raises on a damaged or cut file; see :func:`walk_messages`).

    Parameters
    ----------
    path : the MCAP file.
    topics : wanted topics (others are skipped without being copied).
    """

    def __init__(self, path: str | Path, topics: set[str]) -> None:
        self.path = Path(path)
        self.topics = topics
        self.schemas: dict[int, str] = {}  # schema id -> name
        self.channels: dict[int, tuple[str, int]] = {}  # channel id -> (topic, schema id)

    def __iter__(self) -> Iterator[MessageTuple]:
        with open(self.path, "rb") as fh:
            for opcode, offset, length in records(fh):
                if opcode in (Opcode.DATA_END, Opcode.FOOTER):
                    return  # the summary section repeats what we have seen
                if opcode == Opcode.CHUNK:
                    yield from self._chunk(chunk_payload(read_at(fh, offset, length)))
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    self._define(parse_definition(opcode, read_at(fh, offset, length)))
                elif opcode == Opcode.MESSAGE:
                    msg = Message.read(ReadDataStream(BytesIO(read_at(fh, offset, length))), length)
                    out = self._wanted(msg.channel_id)
                    if out is not None:
                        yield out[0], out[1], msg.log_time, msg.data

    def _define(self, record: Schema | Channel) -> None:
        if isinstance(record, Schema):
            self.schemas[record.id] = record.name
        else:
            self.channels[record.id] = (record.topic, record.schema_id)

    def _wanted(self, channel_id: int) -> tuple[str, str] | None:
        entry = self.channels.get(channel_id)
        if entry is None:
            raise McapError(f"message on channel {channel_id} before its channel record")
        topic, schema_id = entry
        if topic not in self.topics:
            return None
        return topic, self.schemas.get(schema_id, "")

    def _chunk(self, payload: bytes) -> Iterator[MessageTuple]:
        unpack_message = _MESSAGE.unpack_from
        wanted: dict[int, tuple[str, str] | None] = {}  # per channel, for this chunk
        for opcode, content in chunk_records(payload):
            if opcode == Opcode.MESSAGE:
                channel_id, _, log_time, _ = unpack_message(content, 0)
                if channel_id not in wanted:
                    wanted[channel_id] = self._wanted(channel_id)
                out = wanted[channel_id]
                if out is not None:
                    yield out[0], out[1], log_time, bytes(content[_MESSAGE.size :])
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                self._define(parse_definition(opcode, content))
                wanted.clear()


def walk_messages(
    path: str | Path, topics: set[str], on_stop: Callable[[BaseException], None]
) -> Iterator[MessageTuple]:
    """:class:`MessageWalk` that hands a read error to ``on_stop`` and ends instead of raising."""
    it = iter(MessageWalk(path, topics))
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except READ_ERRORS as err:  # the caller decides whether a cut file is an error
            on_stop(err)
            return
        yield item
