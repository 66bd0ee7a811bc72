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
buffer, copying only the messages of the wanted topics.
``RecordedLog.messages(reference=True)`` reads through the mcap readers
instead; a test checks both agree on whole and cut files.

Damage. Every chunk is checked before its records are read: a known
compression, a declared size within :data:`MAX_CHUNK_BYTES` (a 32 KB zstd
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
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import IO

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Message, Schema

MAGIC = b"\x89MCAP0\r\n"
_RECORD = struct.Struct("<BQ")  # opcode, content length
_MESSAGE = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed crc

# (topic, schema name, log time ns, data)
MessageTuple = tuple[str, str, int, bytes]


# The largest chunk a reader decompresses (bytes): the recorder closes a chunk
# past 1 MB, so only the largest single message (a sample block) can make one
# larger; this bound is what keeps a crafted size from exhausting memory.
MAX_CHUNK_BYTES = 256 * 1024 * 1024
# What the data section of a recording may hold at its top level (and its end, see
# :func:`ends_data`).
DATA_OPCODES = frozenset(
    int(op)
    for op in (
        Opcode.HEADER,
        Opcode.METADATA,
        Opcode.ATTACHMENT,
        Opcode.SCHEMA,
        Opcode.CHANNEL,
        Opcode.MESSAGE,
        Opcode.CHUNK,
        Opcode.MESSAGE_INDEX,
    )
)
CHUNK_OPCODES = frozenset(int(op) for op in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE))


class Truncated(McapError):
    """The file ends inside a record."""


class BadChunk(McapError):
    """A chunk (or a top-level record) is damaged: its messages cannot be trusted."""


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


def chunk_payload(content: bytes, check_crc: bool = True) -> bytes:
    """The uncompressed records of a chunk record's content, checked; raises :class:`BadChunk`.

    The declared uncompressed size bounds the decompression (and may not
    exceed :data:`MAX_CHUNK_BYTES`), the result must have that size, and its
    CRC (when the writer wrote one, non-zero) must match, unless ``check_crc``
    is False (a data section CRC vouched for the bytes already).
    """
    view = memoryview(content)
    try:
        _, _, size, crc = _CHUNK.unpack_from(view, 0)
        pos = _CHUNK.size
        (n,) = struct.unpack_from("<I", view, pos)
        compression = bytes(view[pos + 4 : pos + 4 + n]).decode("ascii", errors="replace")
        pos += 4 + n
        (n_data,) = struct.unpack_from("<Q", view, pos)
    except struct.error:
        raise BadChunk("chunk header runs past the chunk record") from None
    pos += 8
    if pos + n_data != len(view):
        raise BadChunk(
            f"chunk declares {n_data} compressed bytes, its record holds {len(view) - pos}"
        )
    if size > MAX_CHUNK_BYTES:
        raise BadChunk(f"chunk declares {size} uncompressed bytes (at most {MAX_CHUNK_BYTES} read)")
    data = view[pos:]
    try:
        if compression == "zstd":
            # max_output_size binds only frames without a content size: check that first
            declared = zstandard.frame_content_size(data)
            if declared not in (-1, size):
                raise BadChunk(f"zstd frame holds {declared} bytes, the chunk declares {size}")
            payload = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        elif compression == "lz4":
            payload = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
        elif compression == "":
            payload = bytes(data)
        else:
            raise BadChunk(f"unsupported chunk compression {compression!r}")
    except (zstandard.ZstdError, RuntimeError, ValueError) as err:
        raise BadChunk(f"chunk does not decompress ({type(err).__name__}: {err})") from None
    if len(payload) != size:
        raise BadChunk(f"chunk decompresses to {len(payload)} bytes, declares {size}")
    if check_crc and crc and zlib.crc32(payload) != crc:
        raise BadChunk(f"chunk CRC mismatch ({zlib.crc32(payload):#010x}, recorded {crc:#010x})")
    return payload


def chunk_records(payload: bytes) -> Iterator[tuple[int, memoryview]]:
    """``(opcode, content)`` of each record inside a chunk."""
    view = memoryview(payload)
    pos, end = 0, len(payload)
    while pos < end:
        if pos + _RECORD.size > end:
            raise BadChunk("chunk ends inside a record header")
        opcode, length = _RECORD.unpack_from(view, pos)
        pos += _RECORD.size
        if pos + length > end:
            raise BadChunk(f"chunk record of {length} bytes runs past the chunk's end")
        if opcode not in CHUNK_OPCODES:
            raise BadChunk(f"record with opcode {opcode:#04x} inside a chunk")
        if opcode == Opcode.MESSAGE and length < _MESSAGE.size:
            raise BadChunk(f"message record of {length} bytes inside a chunk")
        yield opcode, view[pos : pos + length]
        pos += length


def read_attachment(content: bytes) -> Attachment:
    """An attachment record from its content, its CRC checked; raises :class:`BadChunk`."""
    attachment = Attachment.read(ReadDataStream(BytesIO(content)))
    (crc,) = struct.unpack_from("<I", content, len(content) - 4)
    if crc and zlib.crc32(memoryview(content)[:-4]) != crc:
        raise BadChunk(f"attachment {attachment.name!r}: CRC mismatch")
    return attachment


def looks_like_index(head: bytes, length: int) -> bool:
    """Whether a record of ``length`` bytes starting ``head`` (6 bytes) is a message index:
    a channel id, then its entries' byte count (16 each), filling the record."""
    if len(head) < 6:
        return False
    _, n = struct.unpack_from("<HI", head, 0)
    return 6 + n == length and n % 16 == 0


def ends_data(opcode: int, length: int) -> bool:
    """Whether a top-level record ends the data section: a data end record (4 bytes) or
    a footer (20 bytes). A damaged opcode that reads as one has another length."""
    return (opcode == Opcode.DATA_END and length == 4) or (opcode == Opcode.FOOTER and length == 20)


def parse_definition(opcode: int, content: bytes | memoryview) -> Schema | Channel:
    """A Schema or Channel record from its content."""
    stream = ReadDataStream(BytesIO(bytes(content)))
    return Schema.read(stream) if opcode == Opcode.SCHEMA else Channel.read(stream)


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
    """

    def __init__(
        self,
        path: str | Path,
        topics: set[str],
        on_skip: Callable[[Skipped], None] = lambda _: None,
        chunks: list[tuple[int, int]] | None = None,
        channels: dict[int, tuple[str, str]] | None = None,
        check_crcs: bool = True,
    ) -> None:
        self.path = Path(path)
        self.check_crcs = check_crcs
        self.topics = topics
        self.on_skip = on_skip
        self.chunks = chunks
        self.schemas: dict[int, str] = {}  # schema id -> name
        self.channels: dict[int, tuple[str, int]] = {}  # channel id -> (topic, schema id)
        for cid, (topic, name) in (channels or {}).items():  # negative ids: not the file's
            self.schemas[-cid - 1] = name
            self.channels[cid] = (topic, -cid - 1)
        self._last_ns: int | None = None  # log time of the last message read
        self._open: list[Skipped] = []  # skipped, waiting for the next message's time

    def __iter__(self) -> Iterator[MessageTuple]:
        with open(self.path, "rb") as fh:
            for opcode, offset, length in self._records(fh):
                if ends_data(opcode, length):
                    return  # the summary section repeats what we have seen
                if opcode == Opcode.CHUNK:
                    try:
                        payload = chunk_payload(read_at(fh, offset, length), self.check_crcs)
                    except BadChunk as err:
                        self._skip(offset - _RECORD.size, str(err))
                        continue
                    yield from self._chunk(payload, offset - _RECORD.size)
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
                        offset - _RECORD.size,
                        f"damaged record (opcode {opcode:#04x}, {length} bytes)",
                    )

    def _records(self, fh: IO[bytes]) -> Iterator[tuple[int, int, int]]:
        if self.chunks is None:
            yield from records(fh)
            return
        for offset, length in self.chunks:  # from the summary's chunk indexes
            head = read_at(fh, offset, _RECORD.size)
            _, declared = _RECORD.unpack(head) if len(head) == _RECORD.size else (0, 0)
            if declared != length - _RECORD.size:
                self._skip(offset, "damaged chunk record header")
                continue
            # a damaged opcode alone is harmless here: the content's CRC decides
            yield Opcode.CHUNK, offset + _RECORD.size, declared

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
        unpack_message = _MESSAGE.unpack_from
        wanted: dict[int, tuple[str, str] | None] = {}  # per channel, for this chunk
        try:
            for opcode, content in chunk_records(payload):
                if opcode == Opcode.MESSAGE:
                    channel_id, _, log_time, _ = unpack_message(content, 0)
                    self._seen(log_time)
                    if channel_id not in wanted:
                        wanted[channel_id] = self._wanted(channel_id)
                    out = wanted[channel_id]
                    if out is not None:
                        yield out[0], out[1], log_time, bytes(content[_MESSAGE.size :])
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    self._define(parse_definition(opcode, content))
                    wanted.clear()
        except READ_ERRORS as err:  # a CRC-clean chunk that is not ours: crafted
            self._skip(offset, f"damaged chunk ({type(err).__name__}: {err})")


def walk_messages(
    path: str | Path,
    topics: set[str],
    on_stop: Callable[[BaseException], None],
    on_skip: Callable[[Skipped], None] = lambda _: None,
    chunks: list[tuple[int, int]] | None = None,
    channels: dict[int, tuple[str, str]] | None = None,
    check_crcs: bool = True,
) -> Iterator[MessageTuple]:
    """:class:`MessageWalk` that hands a read error to ``on_stop`` and ends instead of raising."""
    it = iter(MessageWalk(path, topics, on_skip, chunks, channels, check_crcs))
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except READ_ERRORS as err:  # the caller decides whether a cut file is an error
            on_stop(err)
            return
        yield item
