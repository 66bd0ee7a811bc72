"""MCAP records framed by hand: the primitives :mod:`replay.chunks` walks a recording with.

The record walk against the file size, a chunk checked (compression, declared size, CRC)
and decompressed, its records, attachments and schema/channel definitions.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Callable, Iterator
from io import BytesIO
from typing import IO

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Attachment, Channel, Schema

crc32_combine: Callable[[int, int, int], int] | None
try:  # CRC-32 (MCAP's, zlib's): ISA-L's is the same function, 7x faster (asammdf installs it)
    from isal.isal_zlib import crc32, crc32_combine
except ImportError:  # pragma: no cover - a platform without isal wheels
    from zlib import crc32

    crc32_combine = None  # (Python's zlib does not offer zlib's crc32_combine)

MAGIC = b"\x89MCAP0\r\n"
MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
RECORD_HEAD = struct.Struct("<BQ")  # opcode, content length
_CHUNK = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed crc


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
        head = fh.read(RECORD_HEAD.size)
        if not head:
            return
        if len(head) < RECORD_HEAD.size:
            raise Truncated(f"file ends inside a record header at byte {pos}")
        opcode, length = RECORD_HEAD.unpack(head)
        start = pos + RECORD_HEAD.size
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


def chunk_payload(
    content: bytes | memoryview,
    check_crc: bool = True,
    zstd: zstandard.ZstdDecompressor | None = None,
) -> bytes:
    """The uncompressed records of a chunk record's content, checked; raises :class:`BadChunk`.

    The declared uncompressed size bounds the decompression (and may not
    exceed :data:`MAX_CHUNK_BYTES`), the result must have that size, and its
    CRC (when the writer wrote one, non-zero) must match, unless ``check_crc``
    is False (a data section CRC vouched for the bytes already). ``zstd``: a
    decompressor to reuse (a walk over many chunks: a new one per chunk cost
    about 10 us, 1.2 ms a minute of log); each call starts it afresh.
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
            if zstd is None:
                zstd = zstandard.ZstdDecompressor()
            payload = zstd.decompress(data, max_output_size=size)
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
    if check_crc and crc and crc32(payload) != crc:
        raise BadChunk(f"chunk CRC mismatch ({crc32(payload):#010x}, recorded {crc:#010x})")
    return payload


def chunk_records(payload: bytes) -> Iterator[tuple[int, memoryview]]:
    """``(opcode, content)`` of each record inside a chunk."""
    view = memoryview(payload)
    pos, end = 0, len(payload)
    while pos < end:
        if pos + RECORD_HEAD.size > end:
            raise BadChunk("chunk ends inside a record header")
        opcode, length = RECORD_HEAD.unpack_from(view, pos)
        pos += RECORD_HEAD.size
        if pos + length > end:
            raise BadChunk(f"chunk record of {length} bytes runs past the chunk's end")
        if opcode not in CHUNK_OPCODES:
            raise BadChunk(f"record with opcode {opcode:#04x} inside a chunk")
        if opcode == Opcode.MESSAGE and length < MESSAGE_HEAD.size:
            raise BadChunk(f"message record of {length} bytes inside a chunk")
        yield opcode, view[pos : pos + length]
        pos += length


def read_attachment(content: bytes) -> Attachment:
    """An attachment record from its content, its CRC checked; raises :class:`BadChunk`
    (a damaged name or media type too: the record is framed by its length, so the walk
    goes on past it)."""
    try:
        attachment = Attachment.read(ReadDataStream(BytesIO(content)))
        (crc,) = struct.unpack_from("<I", content, len(content) - 4)
    except (McapError, struct.error, ValueError, EOFError, IndexError) as err:
        raise BadChunk(f"attachment record unreadable ({type(err).__name__})") from None
    if crc and crc32(memoryview(content)[:-4]) != crc:
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
