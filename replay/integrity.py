"""The CRCs of a finished recording besides the chunks': the summary's and the data section's.

The footer's CRC covers the summary section (chunk indexes, schemas,
channels, statistics); the data end record's covers everything before it,
which is the only protection of the run metadata (layout, settings, truth)
and of the record headers. A reader that trusts the summary reads chunks by
its indexes; one that trusts the data section knows the metadata it parsed
is what the writer wrote. See ``docs/recording-format.md``.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import IO

from mcap.exceptions import McapError
from mcap.opcode import Opcode

from replay.chunks import READ_ERRORS
from replay.errors import LogError
from replay.mcap_records import MAGIC, BadChunk, chunk_payload, read_at, records


def check_summary_crc(fh: IO[bytes]) -> int:
    """The summary's start offset; raises McapError when the footer's CRC does not match."""
    size = fh.seek(0, 2)
    footer = read_at(fh, size - len(MAGIC) - 29, 29)
    opcode, length, start, _, crc = struct.unpack("<BQQQI", footer)
    if opcode != Opcode.FOOTER or length != 20:
        raise McapError("no footer record before the closing magic")
    if crc == 0:
        return int(start)
    if not 0 < start <= size - len(MAGIC) - 29:
        raise McapError(f"footer points the summary at byte {start}, outside the file")
    summary = read_at(fh, start, size - len(MAGIC) - 29 - start)
    if zlib.crc32(footer[:25], zlib.crc32(summary)) != crc:
        raise McapError("summary CRC mismatch")
    return int(start)


def check_data_crc(
    path: Path,
    data_end_offset: int | None,
    data_crc: int,
    chunks: list[tuple[int, int]] | None,
    explained: bool = False,
) -> bool:
    """Whether the data section's CRC matched; raise LogError when it failed and no damaged
    chunk explains it.

    The chunk and attachment CRCs cover the stream and the attached files; the
    run metadata, the record headers and the message indexes only this CRC. A
    damaged chunk is skipped and reported during the replay; damage elsewhere
    could change what the stream means (a rate in the layout), so the file is refused.

    Parameters
    ----------
    path : the recording.
    data_end_offset : byte offset of its data end record (None: none found, nothing to check).
    data_crc : the CRC that record holds (0: not written, nothing to check).
    chunks : (offset, length) of the chunk records from the summary, or None to find them.
    explained : a damaged attachment was found already.

    A match vouches for every chunk's bytes, so the walk need not check their
    CRCs again (decompressing the same bytes gives the same records).
    """
    if data_end_offset is None or data_crc == 0:
        return False
    crc = 0
    with open(path, "rb") as fh:
        remaining = data_end_offset
        while remaining > 0:
            block = fh.read(min(remaining, 1 << 20))
            if not block:
                break
            crc = zlib.crc32(block, crc)
            remaining -= len(block)
        if crc == data_crc:
            return True
        if explained:  # a damaged attachment
            return False
        for offset, length in chunks or _chunk_records(fh):
            head = read_at(fh, offset, 9)
            if len(head) < 9 or struct.unpack("<BQ", head) != (Opcode.CHUNK, length - 9):
                return (
                    False  # a damaged chunk header: the walk reads it by the summary, or skips it
                )
            try:
                chunk_payload(read_at(fh, offset + 9, length - 9))
            except BadChunk:
                return False  # the replay skips it and says so
    raise LogError(
        f"{path}: damaged recording: the data section's CRC does not match and no chunk "
        "or attachment explains it (its metadata or a record header is damaged)"
    )


def _chunk_records(fh: IO[bytes]) -> list[tuple[int, int]]:
    try:
        return [(o - 9, n + 9) for op, o, n in records(fh) if op == Opcode.CHUNK]
    except READ_ERRORS:
        return []
