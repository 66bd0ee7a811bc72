"""A summary without CRC that lost an index the statistics cannot count.

mcap's ``Writer(enable_crcs=False, use_statistics=False)`` writes a valid file whose
summary nothing vouches for. A chunk or attachment index whose opcode turned into one
MCAP readers skip, or a chunk index pointing past the file, leaves the indexes short of
the data section they should cover: the file is read front to back, as when the summary
indexes nothing, and the replay gives the clean result with a note (the data is whole).
(A whole file written so is read by its indexes without a note:
tests/replay/test_mcap_writer_options.py.)
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

import pytest
from mcap.opcode import Opcode
from support.clean_run import CleanRun
from support.rewritten_logs import replay, rewritten, summary_records

UNCHECKED: dict[str, Any] = {"enable_crcs": False, "use_statistics": False}


@pytest.mark.parametrize("index", [Opcode.CHUNK_INDEX, Opcode.ATTACHMENT_INDEX])
@pytest.mark.parametrize("which", [0, -1])
def test_an_index_lost_to_an_unknown_opcode_leaves_a_gap_read_front_to_back(
    clean_run: CleanRun,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    index: int,
    which: int,
) -> None:
    data = rewritten(clean_run.log, tmp_path / "nocrc.mcap", **UNCHECKED).read_bytes()
    at = [pos for op, pos in summary_records(data) if op == index][which]
    log = tmp_path / "log.mcap"
    log.write_bytes(data[:at] + bytes([data[at] | 0x80]) + data[at + 1 :])
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any("not indexed" in line and "read front to back" in line for line in err)


@pytest.mark.parametrize("options", [UNCHECKED, {"enable_crcs": False}])
def test_a_chunk_index_pointing_past_the_file_is_read_front_to_back(
    clean_run: CleanRun,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    options: dict[str, Any],
) -> None:
    """The chunk itself is whole: nothing is lost (the index alone was damaged)."""
    data = bytearray(rewritten(clean_run.log, tmp_path / "nocrc.mcap", **options).read_bytes())
    at = next(pos for op, pos in summary_records(bytes(data)) if op == Opcode.CHUNK_INDEX)
    (chunk,) = struct.unpack_from("<Q", data, at + 9 + 16)
    struct.pack_into("<Q", data, at + 9 + 16, chunk + 2**62)
    log = tmp_path / "log.mcap"
    log.write_bytes(data)
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any("read front to back" in line for line in err)


@pytest.mark.parametrize("damage", ["data end opcode", "header opcode"])
def test_damage_outside_the_indexes_leaves_them_in_use_without_a_note(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str], damage: str
) -> None:
    """Without the data end or header record in place the data section's bounds are not
    known: the summary's indexes are used as they are (a walk front to back would run into
    the summary, or blame it), and they hold everything."""
    data = bytearray(rewritten(clean_run.log, tmp_path / "nocrc.mcap", **UNCHECKED).read_bytes())
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)
    data[summary_start - 13 if damage == "data end opcode" else 8] ^= 0x80
    log = tmp_path / "log.mcap"
    log.write_bytes(data)
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert (code, doc, err) == (0, clean_run.result, [])


def test_a_damaged_message_index_map_length_is_a_gap_not_a_damaged_summary(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The chunk index's own numbers stand; where its message indexes end does not."""
    data = bytearray(rewritten(clean_run.log, tmp_path / "nocrc.mcap", **UNCHECKED).read_bytes())
    at = next(pos for op, pos in summary_records(bytes(data)) if op == Opcode.CHUNK_INDEX)
    struct.pack_into("<I", data, at + 9 + 32, 2**31)
    log = tmp_path / "log.mcap"
    log.write_bytes(data)
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any("message index map is damaged" in line and "front to back" in line for line in err)
