"""One pass over a recording's structure before it is read: the summary of a finished file,
or its records front to back, giving the metadata, attachments, schemas, channels and chunks.

A finished log (footer and summary present) is scanned through its summary
(:mod:`replay.summary`), unless the summary leaves something out (mcap's
``Writer`` can write a file without indexes; a summary without CRC may have
lost a record): then, as for a log whose writer died, the records are walked
front to back, seeking past chunk contents. :mod:`replay.reader` builds the
log from the scan.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import IO

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel, Metadata, Schema, Statistics

from replay.chunks import READ_ERRORS
from replay.errors import describe
from replay.integrity import check_summary_crc
from replay.mcap_records import (
    MAGIC,
    MESSAGE_HEAD,
    RECORD_HEAD,
    BadChunk,
    chunk_payload,
    chunk_records,
    chunk_times,
    ends_data,
    parse_definition,
    read_at,
    read_attachment,
    records,
)
from replay.summary import omission, read_indexed, read_metadata, read_summary, untiled


@dataclass
class Scan:
    """What a scan found (see the module docstring)."""

    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[str, int] | None = None
    chunks: int = 0
    messages: int = 0  # messages outside chunks (mcap's Writer(use_chunking=False))
    last_log_time: int | None = None
    readable: int = 0
    data_end: bool = False  # the data section was complete
    error: str | None = None
    definitions_error: str | None = None  # the chunk holding the channels was damaged
    data_verified: bool = False  # the data section's CRC matched
    chunk_records: list[tuple[int, int]] | None = None  # (offset, length), finished logs
    data_end_offset: int | None = None  # where the data end record starts
    data_crc: int = 0  # the data section's CRC as recorded (0: not written)
    notes: list[str] = field(default_factory=list)
    # an attachment was damaged: it explains a data CRC mismatch (the notes do not: they
    # also say the summary left records out, which explains no damage)
    attachment_damaged: bool = False


class NoSummary(McapError):
    """A finished file whose footer declares no summary section: what the recorder
    writes when it must stop early (a full disk, ``McapOutput.cut``, with no footer CRC),
    and what mcap's Writer writes for a file it was told to finish without one (``crc``:
    the footer's CRC of its own fields, then matched)."""

    def __init__(self, message: str, crc: bool) -> None:
        super().__init__(message)
        self.crc = crc


def scan_finished(path: Path) -> Scan:
    """Read the summary section, its CRC checked; the attachments, theirs checked."""
    scan = Scan()
    with open(path, "rb") as fh:
        summary_start, section, checked = check_summary_crc(fh)
        if summary_start == 0:
            raise NoSummary("no summary section", checked)
        summary = read_summary(section)
        data_end, data_crc = _data_end(fh, summary_start)
        gap = omission(summary, checked)
        walked = None
        if gap is not None:  # valid MCAP (mcap's Writer can leave the indexes out): the data has it
            walked = scan_stream(path)
        elif not checked and data_end is not None and (start := _data_start(fh)) is not None:
            # an index lost to damage leaves a gap: read front to back if the data is whole
            gap = untiled(summary, start, data_end)
            walked = scan_stream(path) if gap is not None else None
            if walked is not None and not (
                walked.data_end_offset == data_end and walked.error is None
            ):
                walked = None  # the data is damaged too: its indexes skip what is (as before)
        if walked is not None:
            walked.notes.append(
                f"the summary does not index the whole file ({gap}): read front to back"
            )
            _count_messages(walked, summary.statistics)
            return walked
        scan.schemas = dict(summary.schemas)
        scan.channels = dict(summary.channels)
        scan.chunks = len(summary.chunk_indexes)
        scan.chunk_records = [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]
        if summary.chunk_indexes:
            scan.last_log_time = max(c.message_end_time for c in summary.chunk_indexes)
        _count_messages(scan, summary.statistics)
        for meta_index in summary.metadata_indexes:
            meta = read_metadata(fh, meta_index)
            scan.metadata[meta.name] = dict(meta.metadata)
        for index in summary.attachment_indexes:
            at, length = index.offset, index.length
            try:
                content = read_indexed(fh, at, length, Opcode.ATTACHMENT, "attachment")
            except McapError as err:
                if not checked:  # the index itself may be what is damaged: read front to back
                    raise
                # the summary's CRC vouches for the index: the attachment's own record
                # header is damaged (the walk could not get past it either). That is damage
                # no CRC of its own locates: it explains no data CRC mismatch, so a
                # recording with a data CRC is refused (its run metadata may be hit too)
                scan.notes.append(f"{err}: attachment ignored")
                continue
            _attach(scan, content, at)
        if data_end is not None:
            scan.data_end_offset, scan.data_crc = data_end, data_crc
    return scan


def _data_end(fh: IO[bytes], summary_start: int) -> tuple[int | None, int]:
    """Where the data end record starts (None: not just before the summary) and its CRC."""
    if summary_start > 13:
        opcode, length, crc = struct.unpack("<BQI", read_at(fh, summary_start - 13, 13))
        if opcode == Opcode.DATA_END and length == 4:
            return summary_start - 13, crc
    return None, 0


def _data_start(fh: IO[bytes]) -> int | None:
    """Where the data section's first record after the header starts (None: the header
    record is damaged; the summary's indexes are then used as they are)."""
    opcode, length = RECORD_HEAD.unpack(read_at(fh, len(MAGIC), RECORD_HEAD.size))
    return len(MAGIC) + RECORD_HEAD.size + length if opcode == Opcode.HEADER else None


def _count_messages(scan: Scan, stats: Statistics | None) -> None:
    """Messages per topic of the scan's channels, from the summary's statistics (if any)."""
    if stats is not None:
        counts = stats.channel_message_counts
        scan.counts = {ch.topic: int(counts.get(cid, 0)) for cid, ch in scan.channels.items()}


def _attach(scan: Scan, content: bytes, offset: int) -> None:
    try:
        att = read_attachment(content)
    except BadChunk as err:
        scan.notes.append(
            f"{err} (at byte {offset}): attachment ignored; a data CRC mismatch is put down to "
            "it, so the run metadata is not verified by that CRC"
        )
        scan.attachment_damaged = True
        return
    scan.attachments[att.name] = bytes(att.data)


def scan_stream(path: str | Path) -> Scan:
    """Walk the records of an unfinished file, reading only metadata, attachments and the first chunk.

    A chunk is complete when its declared length fits in the file (see
    :func:`replay.chunks.records`), so the scan seeks past chunk contents.
    """
    scan = Scan()
    with open(path, "rb") as fh:
        try:
            for opcode, offset, length in records(fh):
                if opcode == Opcode.CHUNK:
                    if not scan.channels:
                        try:
                            payload = chunk_payload(read_at(fh, offset, length))
                        except BadChunk as err:  # the walk skips it; definitions may follow
                            scan.definitions_error = f"chunk at byte {offset - 9}: {err}"
                            payload = b""
                        for op, content in chunk_records(payload):
                            if op in (Opcode.SCHEMA, Opcode.CHANNEL):
                                _define(scan, parse_definition(op, content))
                    scan.chunks += 1
                    scan.last_log_time = chunk_times(fh, offset)[1]
                elif opcode == Opcode.METADATA:
                    meta = Metadata.read(ReadDataStream(BytesIO(read_at(fh, offset, length))))
                    scan.metadata[meta.name] = dict(meta.metadata)
                elif opcode == Opcode.ATTACHMENT:
                    _attach(scan, read_at(fh, offset, length), offset - 9)
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    _define(scan, parse_definition(opcode, read_at(fh, offset, length)))
                elif opcode == Opcode.MESSAGE and length >= MESSAGE_HEAD.size:
                    (log_time,) = struct.unpack("<Q", read_at(fh, offset + 6, 8))
                    scan.messages += 1
                    scan.last_log_time = max(log_time, scan.last_log_time or 0)
                scan.readable = offset + length
                if ends_data(opcode, length):
                    if opcode == Opcode.DATA_END:
                        scan.data_end_offset = offset - 9
                        (scan.data_crc,) = struct.unpack("<I", read_at(fh, offset, 4))
                    scan.data_end = True
                    break
        except READ_ERRORS as err:
            scan.error = describe(err)
    return scan


def _define(scan: Scan, record: Schema | Channel) -> None:
    if isinstance(record, Schema):
        scan.schemas[record.id] = record
    else:
        scan.channels[record.id] = record
