"""Recordings rewritten by mcap's own ``Writer`` with the options a user's tool may choose.

A file without chunk indexes, metadata indexes or statistics is valid MCAP: the
replay reads it front to back, says so, and gives the clean result.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest
from mcap.opcode import Opcode
from mcap.records import Channel, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, IndexType, Writer
from support.clean_run import CleanRun
from support.rewritten_logs import replay, rewritten, summary_records

from replay.errors import LogError
from replay.reader import open_log


@pytest.mark.parametrize(
    "options",
    [
        {"use_chunking": False},
        {"use_chunking": False, "enable_crcs": False, "use_statistics": False},
        {"index_types": IndexType.NONE},
        {"index_types": IndexType.CHUNK},
        {"index_types": IndexType.METADATA | IndexType.ATTACHMENT},
        {"repeat_channels": False, "repeat_schemas": False},
    ],
    ids=[
        "no-chunks",
        "no-chunks-crcs-statistics",
        "no-indexes",
        "chunk-index-only",
        "no-chunk-index",
        "no-channels",
    ],
)
def test_a_summary_without_indexes_is_read_front_to_back_with_the_clean_result(
    clean_run: CleanRun,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    options: dict[str, Any],
) -> None:
    log = rewritten(clean_run.log, tmp_path / "log.mcap", **options)
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any("the summary does not index the whole file" in line for line in err)


@pytest.mark.parametrize(
    "options",
    [
        {},
        # without a summary CRC its indexes must tile the data section (replay.summary.untiled):
        # a whole file passes, whatever the chunks
        {"enable_crcs": False, "use_statistics": False},
        {"enable_crcs": False, "compression": CompressionType.NONE},
        {"enable_crcs": False, "chunk_size": 4096},  # many chunks, metadata between them
    ],
    ids=["default", "unchecked", "unchecked-uncompressed", "unchecked-small-chunks"],
)
def test_an_indexed_summary_is_read_by_its_indexes_without_a_note(
    clean_run: CleanRun,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    options: dict[str, Any],
) -> None:
    log = rewritten(clean_run.log, tmp_path / "log.mcap", **options)
    for path in (log, clean_run.log):  # a user's tool's copy, and our own recording
        opened = open_log(path)
        assert opened.chunk_records is not None and opened.report.notes == []
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert (code, doc, err) == (0, clean_run.result, [])


@pytest.mark.parametrize(
    ("record", "said"),
    [
        (Opcode.CHUNK_INDEX, "1 chunk index(es), its statistics count 2"),
        (Opcode.CHANNEL, "channel(s), its statistics count"),
        (Opcode.SCHEMA, "a channel refers to schema"),
    ],
)
def test_a_record_lost_from_a_summary_without_crc_is_caught_by_the_statistics(
    clean_run: CleanRun,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    record: int,
    said: str,
) -> None:
    """A record whose opcode turned into one MCAP readers skip: the counts disagree."""
    data = rewritten(clean_run.log, tmp_path / "nocrc.mcap", enable_crcs=False).read_bytes()
    at = [pos for op, pos in summary_records(data) if op == record][-1]
    log = tmp_path / "log.mcap"
    log.write_bytes(data[:at] + bytes([data[at] | 0x80]) + data[at + 1 :])
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any(said in line and "read front to back" in line for line in err)


@pytest.mark.parametrize(
    ("index", "flipped_to"),
    [(Opcode.CHUNK_INDEX, Opcode.ATTACHMENT), (Opcode.METADATA_INDEX, Opcode.METADATA)],
)
def test_a_data_section_record_in_a_summary_without_crc_is_damage(
    clean_run: CleanRun,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    index: int,
    flipped_to: int,
) -> None:
    """Without a CRC and statistics, only the opcode tells the index was damaged."""
    options: dict[str, Any] = {"enable_crcs": False, "use_statistics": False}
    data = rewritten(clean_run.log, tmp_path / "nocrc.mcap", **options).read_bytes()
    at = next(pos for op, pos in summary_records(data) if op == index)
    log = tmp_path / "log.mcap"
    log.write_bytes(data[:at] + bytes([flipped_to]) + data[at + 1 :])
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any(f"opcode {flipped_to:#04x} in the summary section" in line for line in err)


def test_layout_names_utf8_cannot_hold_replay_as_the_clean_run(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A lone surrogate is legal in the layout's JSON, not in UTF-8: the fast decoder
    leaves that group to the field-by-field one instead of failing to start."""

    def extra_group(layout: dict[str, Any]) -> None:
        channel = {"name": "\ud800", "unit": "V"}
        layout["groups"].append({"name": "extra", "rate_hz": 10.0, "channels": [channel]})

    log = rewritten(clean_run.log, tmp_path / "log.mcap", edit_layout=extra_group)
    code, doc, _ = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result


def test_an_edge_channel_that_is_not_a_string_is_one_line(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def number(layout: dict[str, Any]) -> None:
        layout["edge_channels"] = [5]

    topics = {"/raw/edges/tacho": "/raw/edges/5"}
    log = rewritten(clean_run.log, tmp_path / "log.mcap", edit_layout=number, topics=topics)
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 2 and doc is None
    assert len(err) == 1 and "edge channel 'tacho'" in err[0] and "edge channels: 5" in err[0]


def test_an_attachment_index_with_a_damaged_length_is_not_trusted(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A summary without CRC whose attachment index says 2**40 bytes more: read front to
    back, not allocated (its indexes no longer follow each other to the data end)."""
    data = bytearray(
        rewritten(clean_run.log, tmp_path / "nocrc.mcap", enable_crcs=False).read_bytes()
    )
    at = next(pos for op, pos in summary_records(bytes(data)) if op == Opcode.ATTACHMENT_INDEX)
    struct.pack_into("<Q", data, at + 9 + 8, struct.unpack_from("<Q", data, at + 17)[0] + 2**40)
    log = tmp_path / "log.mcap"
    log.write_bytes(data)
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any("does not index the whole file" in line and "front to back" in line for line in err)


def test_a_chunk_whose_index_runs_past_the_file_is_skipped_without_reading_it(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A chunk index and the record header agreeing on 2**40 more bytes (no CRC on the
    summary; the data section's CRC then fails and the chunk is looked at; the walk front
    to back cannot get past it either): skipped and reported, not allocated, not sought.
    (An index alone pointing elsewhere: tests/replay/test_mcap_summary_gaps.py.)"""
    options: dict[str, Any] = {"enable_crcs": False, "enable_data_crcs": True}
    data = bytearray(rewritten(clean_run.log, tmp_path / "nocrc.mcap", **options).read_bytes())
    at = [pos for op, pos in summary_records(bytes(data)) if op == Opcode.CHUNK_INDEX][-1]
    chunk, length = struct.unpack_from("<QQ", data, at + 9 + 16)
    struct.pack_into("<Q", data, at + 9 + 24, length + 2**40)
    struct.pack_into("<Q", data, chunk + 1, length - 9 + 2**40)
    log = tmp_path / "log.mcap"
    log.write_bytes(data)
    code, doc, _ = replay(log, tmp_path / "r.json", capsys)
    assert code == 0
    (skipped,) = doc["recording_skipped"]
    assert skipped["kind"] == "damaged" and "runs past the end of the file" in skipped["reason"]


def test_an_empty_summary_with_a_crc_is_valid_and_its_crc_checked(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Nothing in the summary: mcap's Writer points the footer at byte 0 with the CRC of
    the footer's own fields (valid MCAP), not a footer pointing outside the file."""
    options: dict[str, Any] = {
        "index_types": IndexType.NONE,
        "repeat_channels": False,
        "repeat_schemas": False,
        "use_statistics": False,
        "use_summary_offsets": False,
    }
    data = rewritten(clean_run.log, tmp_path / "empty.mcap", **options).read_bytes()
    footer = len(data) - 8 - 29
    start, _, crc = struct.unpack_from("<QQI", data, footer + 9)
    assert start == 0 and crc != 0
    code, doc, err = replay(tmp_path / "empty.mcap", tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert not any("damaged" in line or "closed early" in line for line in err)
    assert any("a finished recording without a summary section" in line for line in err)
    log = tmp_path / "flipped.mcap"
    log.write_bytes(data[:-9] + bytes([data[-9] ^ 1]) + data[-8:])  # the CRC's last byte
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any("summary CRC mismatch" in line for line in err)


def test_a_damaged_layout_is_refused_when_the_summary_indexes_no_metadata(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A file read front to back because its summary indexes chunks only: its note explains
    no damage, so a data CRC mismatch (a rate changed in the run metadata) still refuses it."""
    log = rewritten(
        clean_run.log, tmp_path / "log.mcap", enable_data_crcs=True, index_types=IndexType.CHUNK
    )
    data = bytearray(log.read_bytes())
    at = data.index(b'"rate_hz": 5120.0') + len(b'"rate_hz": 5')
    data[at] = ord("2")  # 5120 -> 5220 Hz
    log.write_bytes(data)
    with pytest.raises(LogError, match="data section's CRC does not match"):
        open_log(log)
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert (code, doc) == (2, None) and "data section's CRC does not match" in err[-1]


@pytest.mark.parametrize("data_crc", [False, True], ids=["no-data-crc", "data-crc"])
def test_a_damaged_attachment_header_under_a_checked_summary(
    clean_run: CleanRun, tmp_path: Path, data_crc: bool
) -> None:
    """The summary's CRC vouches for the attachment index: the attachment's own record
    header is what is damaged. Without a data CRC (mcap Writer's default) that attachment
    alone is lost; with one, the mismatch is not put down to it (the run metadata beside
    it may be hit too): the file is refused."""
    log = rewritten(clean_run.log, tmp_path / "log.mcap", enable_data_crcs=data_crc)
    data = bytearray(log.read_bytes())
    at = next(pos for op, pos in summary_records(bytes(data)) if op == Opcode.ATTACHMENT_INDEX)
    offset = struct.unpack_from("<Q", data, at + 9)[0]
    data[offset + 1] ^= 1  # the attachment record's length
    log.write_bytes(data)
    if data_crc:
        with pytest.raises(LogError, match="data section's CRC does not match"):
            open_log(log)
        return
    opened = open_log(log)
    assert opened.chunk_records is not None
    assert any("attachment ignored" in n for n in opened.report.notes)
    assert sum(1 for _ in opened.items()) == sum(1 for _ in open_log(clean_run.log).items())


def test_a_damaged_attachment_header_does_not_hide_a_damaged_layout(
    clean_run: CleanRun, tmp_path: Path
) -> None:
    """Our recording (data CRC written) with its attachment's header and the layout's rate
    both damaged: refused, not opened with a 5220 Hz layout."""
    data = bytearray(clean_run.data)
    at = data.index(b'"rate_hz": 5120.0') + len(b'"rate_hz": 5')
    data[at] = ord("2")
    att = data.index(b"bench.toml") - 29  # the record's opcode: name length, times, before
    assert data[att] == Opcode.ATTACHMENT
    data[att + 1] ^= 1
    log = tmp_path / "log.mcap"
    log.write_bytes(data)
    with pytest.raises(LogError):
        open_log(log)


def test_an_attachment_whose_media_type_does_not_decode_is_ignored_alone(
    clean_run: CleanRun, tmp_path: Path
) -> None:
    """A flipped bit in the attachment's media type (not UTF-8 any more): that attachment
    is ignored and said to be, the stream replays (before: 'truncated before any data')."""
    data = bytearray(clean_run.data)
    at = data.index(b"application/toml")
    data[at] ^= 0x80
    log = tmp_path / "log.mcap"
    log.write_bytes(data)
    opened = open_log(log)
    assert any("attachment" in n and "ignored" in n for n in opened.report.notes)
    assert sum(1 for _ in opened.items()) == sum(1 for _ in open_log(clean_run.log).items())


def test_a_finished_file_without_a_message_opens_as_an_empty_log(
    clean_run: CleanRun, tmp_path: Path
) -> None:
    """mcap's Writer leaves a file without messages without chunk indexes: nothing is
    missing, so it is not read front to back (its channels are in the summary only)."""
    with open(clean_run.log, "rb") as src, open(tmp_path / "empty.mcap", "wb") as out:
        writer = Writer(out, enable_data_crcs=True)
        writer.start(profile="", library="a user's tool")
        schemas: dict[int, int] = {0: 0}
        channels: set[int] = set()
        for rec in StreamReader(src).records:
            if isinstance(rec, Schema) and rec.id not in schemas:
                schemas[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel) and rec.id not in channels:
                channels.add(rec.id)
                writer.register_channel(
                    rec.topic, rec.message_encoding, schemas[rec.schema_id], rec.metadata
                )
            elif isinstance(rec, Metadata):
                writer.add_metadata(rec.name, dict(rec.metadata))
        writer.finish()
    opened = open_log(tmp_path / "empty.mcap")
    assert opened.report.notes == [] and list(opened.items()) == []


def test_a_rate_too_large_for_a_float_is_one_line(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    def huge(layout: dict[str, Any]) -> None:
        layout["groups"][0]["rate_hz"] = 10**400

    log = rewritten(clean_run.log, tmp_path / "log.mcap", edit_layout=huge)
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert (code, doc) == (2, None) and len(err) == 1 and str(log) in err[0]
