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
import threading
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import McapError
from mcap.opcode import Opcode

from replay.chunks import READ_ERRORS
from replay.errors import LogError
from replay.mcap_records import (
    MAGIC,
    BadChunk,
    chunk_payload,
    crc32,
    crc32_combine,
    read_at,
    records,
)


def check_summary_crc(fh: IO[bytes]) -> tuple[int, bytes, bool]:
    """The summary's start offset (0: none), its bytes (up to the footer) and whether its
    CRC was written and checked (0 in the footer: not written); raises McapError when the
    footer's CRC does not match."""
    size = fh.seek(0, 2)
    footer = read_at(fh, size - len(MAGIC) - 29, 29)
    opcode, length, start, _, crc = struct.unpack("<BQQQI", footer)
    if opcode != Opcode.FOOTER or length != 20:
        raise McapError("no footer record before the closing magic")
    if start == 0:  # no summary; mcap's Writer still writes the CRC of the footer's fields
        if crc and crc32(footer[:25]) != crc:
            raise McapError("summary CRC mismatch (the footer declares no summary)")
        return 0, b"", bool(crc)
    if not 0 < start <= size - len(MAGIC) - 29:
        raise McapError(f"footer points the summary at byte {start}, outside the file")
    summary = read_at(fh, start, size - len(MAGIC) - 29 - start)
    if crc and crc32(footer[:25], crc32(summary)) != crc:
        raise McapError("summary CRC mismatch")
    return int(start), summary, bool(crc)


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
    if _data_crc(path, data_end_offset) == data_crc:
        return True
    if explained:  # a damaged attachment
        return False
    with open(path, "rb", buffering=0) as fh:  # what else explains the mismatch
        size = fh.seek(0, 2)
        for offset, length in chunks or _chunk_records(fh):
            if offset + length > size:  # the walk skips it
                return False
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


# Reading the file is most of the check (8 of 9.3 ms for a 60 s log: copies from the page
# cache; the CRC itself 1 ms with ISA-L): its two halves are read on two threads and their
# CRCs combined, 9.3 -> about 5 ms of wall time before a replay's first item (measured
# 2026-11-26, load 1). Below 8 MB one thread is as fast.
SPLIT_ABOVE_BYTES = 8 << 20


def _data_crc(path: Path, size: int) -> int:
    """CRC-32 of the file's first ``size`` bytes (a file cut shorter gets a CRC of its own,
    which no recorded CRC matches)."""
    if crc32_combine is None or size < SPLIT_ABOVE_BYTES:
        return _crc_of(path, 0, size)
    half = size // 2
    second = _OnThread("ptinertia-data-crc-2", _crc_of, path, half, size)
    try:
        first = _crc_of(path, 0, half)
    finally:
        second.join()  # (not left reading a file its caller gave up on)
    return crc32_combine(first, second.result(), size - half)


def _crc_of(path: Path, start: int, end: int) -> int:
    """CRC-32 of bytes ``start`` to ``end`` of the file (up to its end, if it is shorter)."""
    crc = 0
    buffer = memoryview(bytearray(1 << 20))  # one buffer: fresh blocks cost page faults
    with open(path, "rb", buffering=0) as fh:
        fh.seek(start)
        remaining = end - start
        while remaining > 0:
            n = fh.readinto(buffer[: min(remaining, len(buffer))])
            if not n:
                break
            crc = crc32(buffer[:n], crc)
            remaining -= n
    return crc


def _chunk_records(fh: IO[bytes]) -> list[tuple[int, int]]:
    try:
        return [(o - 9, n + 9) for op, o, n in records(fh) if op == Opcode.CHUNK]
    except READ_ERRORS:
        return []


class _OnThread:
    """``fn(*args)`` on a daemon thread of its own, started at once (a caller that gives up
    must not hold the exit); :meth:`result` waits and returns what it returned, or raises
    what it raised."""

    def __init__(self, name: str, fn: Callable[..., Any], *args: Any) -> None:
        self._value: Any = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(fn, *args), daemon=True)
        self._thread.name = name
        self._thread.start()

    def _run(self, fn: Callable[..., Any], *args: Any) -> None:
        try:
            self._value = fn(*args)
        except BaseException as err:  # handed to the caller by result()
            self._error = err

    def join(self) -> None:
        self._thread.join()

    def result(self) -> Any:
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value


class DataCheck(_OnThread):
    """:func:`check_data_crc` on a thread of its own, started at once; :meth:`result` waits.

    Opening a log for a replay (:class:`replay.source.McapSource`) starts it, and the
    first message read waits for it, so the CRC of the whole file (its two halves on two
    threads: 3.7-5 ms for a 60 s log, file reads and the CRC releasing the GIL) runs
    beside the pipeline's set-up: a replay of a 60 s log started that much later before.
    A mismatch stops the replay before its first item with the same :class:`LogError`.
    """

    def __init__(
        self,
        path: Path,
        data_end_offset: int | None,
        data_crc: int,
        chunks: list[tuple[int, int]] | None,
        explained: bool = False,
    ) -> None:
        args = (path, data_end_offset, data_crc, chunks, explained)
        super().__init__("ptinertia-data-crc", check_data_crc, *args)

    def result(self) -> bool:
        """What :func:`check_data_crc` returned; raises what it raised."""
        return bool(super().result())
