"""A damaged or crafted recording is never read as good: every CRC checked, every size bounded.

A bad chunk is skipped and the result says so (``recording_skipped``, one line
on stderr); damage no CRC can place (the run metadata) or a crafted value
refuses the file with one line and exit 2; a path in a recorded bench never
leaves the recording's attachments.
"""

from __future__ import annotations

import contextlib
import json
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zstandard
from mcap.opcode import Opcode
from mcap.reader import NonSeekingReader
from mcap.stream_reader import CRCValidationError
from mcap.writer import Writer
from support.clean_run import CleanRun
from support.mcap_logs import synthetic_layout

from acquisition.stream import (
    SampleBlock,
    SampleGroup,
    Source,
    SourceError,
    StreamItem,
    StreamLayout,
)
from ptinertia.cli import main
from ptinertia.config import load_bench
from ptinertia.runner import RunOptions, run_source
from replay import mcap_records
from replay.errors import LogError
from replay.mcap_records import BadChunk, Truncated, chunk_payload, records
from replay.raw_writer import record_source
from replay.reader import open_log
from replay.recording_head import RecordingInfo, run_metadata
from replay.schemas import META_RUN, full_name, schema_data, stream_topics
from replay.source import McapSource

EXAMPLE_BENCH = Path(__file__).resolve().parents[2] / "examples" / "i3-bench.toml"


def replay(log: Path, out: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> Any:
    """Exit code, result document (or None), stderr lines of ``ptinertia replay log``."""
    out.unlink(missing_ok=True)
    code = main(["replay", str(log), "--quiet", "--json", str(out), *extra])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    doc = json.loads(out.read_text()) if out.exists() else None
    return code, doc, err


def chunk_offsets(path: Path) -> list[tuple[int, int]]:
    """(content offset, length) of every chunk record."""
    out: list[tuple[int, int]] = []
    with open(path, "rb") as fh:
        for opcode, offset, length in records(fh):
            if opcode == Opcode.DATA_END:
                return out
            if opcode == Opcode.CHUNK:
                out.append((offset, length))
    return out


def flipped(data: bytes, byte: int, bit: int = 0) -> bytes:
    out = bytearray(data)
    out[byte] ^= 1 << bit
    return bytes(out)


def test_a_flipped_bit_in_a_chunk_is_skipped_and_reported_by_time_span(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    offset, length = chunk_offsets(clean_run.log)[3]
    log = tmp_path / "flip.mcap"
    log.write_bytes(flipped(clean_run.data, offset + length // 2, 3))
    # the mcap library's own reader refuses the same file
    with open(log, "rb") as fh, pytest.raises(CRCValidationError):
        for _ in NonSeekingReader(fh, validate_crcs=True).iter_messages():
            pass
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0
    skipped = doc["recording_skipped"]
    assert [s["kind"] for s in skipped] == ["damaged"]
    assert 0 < skipped[0]["from_s"] < skipped[0]["to_s"] < 4.0
    assert "CRC mismatch" in skipped[0]["reason"]
    assert doc["frames"]["used"] < clean_run.result["frames"]["used"]
    assert sum("damaged chunk" in line for line in err) == 1


def test_a_chunk_declaring_a_terabyte_is_skipped_without_allocating_it(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    offset, _ = chunk_offsets(clean_run.log)[2]
    data = bytearray(clean_run.data)
    struct.pack_into("<Q", data, offset + 16, 2**40)  # uncompressed size
    log = tmp_path / "huge.mcap"
    log.write_bytes(data)
    code, doc, _ = replay(log, tmp_path / "r.json", capsys)
    assert code == 0
    assert "uncompressed bytes" in doc["recording_skipped"][0]["reason"]


def _chunk_content(payload_size: int, data: bytes, compression: str, crc: int = 0) -> bytes:
    name = compression.encode()
    return (
        struct.pack("<QQQI", 0, 1, payload_size, crc)
        + struct.pack("<I", len(name))
        + name
        + struct.pack("<Q", len(data))
        + data
    )


def test_zstd_bombs_are_refused_by_the_declared_size(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(mcap_records, "MAX_CHUNK_BYTES", 1 << 20)
    zeros = bytes(16 << 20)
    with_size = zstandard.ZstdCompressor().compress(zeros)
    without_size = zstandard.ZstdCompressor(write_content_size=False).compress(zeros)
    assert len(with_size) < 32_000
    for declared in (1 << 19, 16 << 20):  # less than the frame holds; more than the bound
        for bomb in (with_size, without_size):
            with pytest.raises(BadChunk):
                chunk_payload(_chunk_content(declared, bomb, "zstd"))
    with pytest.raises(BadChunk, match="compression"):
        chunk_payload(_chunk_content(3, b"abc", "brotli"))
    good = b"\x05" + struct.pack("<Q", 22) + bytes(22)
    assert chunk_payload(_chunk_content(31, good, "", zlib.crc32(good))) == good
    with pytest.raises(BadChunk, match="CRC"):
        chunk_payload(_chunk_content(31, good, "", zlib.crc32(good) ^ 1))


def test_damaged_run_metadata_is_refused_in_one_line(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    at = clean_run.data.index(b'"rate_hz": ') + len(b'"rate_hz": ') + 1
    log = tmp_path / "meta.mcap"
    log.write_bytes(flipped(clean_run.data, at, 0))  # a digit of the rate: still a number
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert (code, doc) == (2, None)
    assert len(err) == 1 and "data section's CRC does not match" in err[0]
    # re-recorded: refused before the recording is created (no empty log left behind)
    again = tmp_path / "again.mcap"
    code, doc, err = replay(log, tmp_path / "r.json", capsys, "--record", str(again))
    assert (code, doc) == (2, None) and not again.exists()
    assert len(err) == 1 and "data section's CRC does not match" in err[0]


def test_a_crc_checked_beside_the_set_up_stops_the_replay_before_its_first_item(
    clean_run: CleanRun, tmp_path: Path
) -> None:
    """``open_log(check_later=True)`` (a replay's) opens damaged run metadata, but nothing
    is read from it: the first message waits for the CRC and gets its error."""
    at = clean_run.data.index(b'"rate_hz": ') + len(b'"rate_hz": ') + 1
    log = tmp_path / "meta.mcap"
    log.write_bytes(flipped(clean_run.data, at, 0))
    with pytest.raises(LogError, match="CRC does not match"):
        open_log(log)
    opened = open_log(log, check_later=True)
    for read in (lambda: next(opened.items()), opened.verify, lambda: next(iter(McapSource(log)))):
        with pytest.raises(LogError, match="data section's CRC does not match"):
            read()
    good = open_log(clean_run.log, check_later=True)
    assert not good.data_verified and good.verify()  # checked, on its thread
    assert sum(1 for _ in good.items()) == sum(1 for _ in open_log(clean_run.log).items()) > 0


def test_a_damaged_bench_attachment_is_dropped_and_said(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    at = clean_run.data.rindex(b"[engine]")  # the attachment (the metadata holds it too)
    log = tmp_path / "att.mcap"
    log.write_bytes(flipped(clean_run.data, at + 2, 1))
    report = open_log(log).report
    assert any("attachment 'bench.toml': CRC mismatch" in line for line in report.lines())
    code, _, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 2 and "holds no bench file" in err[-1]


def test_a_damaged_summary_falls_back_to_the_data_and_gives_the_clean_result(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "summary.mcap"
    log.write_bytes(flipped(clean_run.data, len(clean_run.data) - 300, 5))
    code, doc, err = replay(log, tmp_path / "r.json", capsys)
    assert code == 0 and doc == clean_run.result
    assert any("summary damaged" in line for line in err)
    # the file has its footer: not called unfinished
    assert not any("no footer" in line or "writer stopped" in line for line in err)
    assert any("the data section is whole" in line for line in err)


def test_a_cut_recording_says_what_it_lost(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    log = tmp_path / "cut.mcap"
    log.write_bytes(clean_run.data[: len(clean_run.data) // 2])
    code, doc, _ = replay(log, tmp_path / "r.json", capsys)
    assert code == 0
    (tail,) = doc["recording_skipped"]
    assert tail["kind"] == "truncated" and 1.0 < tail["from_s"] < 3.0


def _crafted(path: Path, layout: StreamLayout, truth: Any = None, raw: bytes | None = None) -> None:
    """A recording (mcap's own writer) with a crafted layout or truth, and one raw message."""
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        info = RecordingInfo(layout=layout, truth=truth)
        writer.add_metadata(META_RUN, run_metadata(info, layout, 0))
        ids = {}
        for topic, kind in stream_topics(layout).items():
            sid = writer.register_schema(full_name(kind), "protobuf", schema_data())
            ids[topic] = writer.register_channel(topic, "protobuf", sid)
        writer.add_message(ids["/raw/acc"], 1, raw or b"", 1)
        writer.finish()


def test_crafted_values_are_one_line_each(tmp_path: Path) -> None:
    layout = synthetic_layout()
    acc, slow = layout.groups
    nan_rate = StreamLayout((SampleGroup("acc", float("nan"), acc.channels), slow), ("tacho",))
    _crafted(tmp_path / "nan.mcap", nan_rate)
    with pytest.raises(LogError, match=r"rate_hz nan is not in"):
        open_log(tmp_path / "nan.mcap")
    _crafted(tmp_path / "truth.mcap", StreamLayout(layout.groups, ("tacho",)), truth=5)
    with pytest.raises(LogError, match="truth: expected a JSON object or null, got int"):
        open_log(tmp_path / "truth.mcap")
    _crafted(tmp_path / "proto.mcap", layout, raw=b"\xff\xff\xff")
    log = open_log(tmp_path / "proto.mcap")
    assert list(log.items()) == []
    assert log.report.skipped["/raw/acc"] == 1
    assert any("DecodeError" in line or "/raw/acc" in line for line in log.report.lines())


def test_a_recorded_bench_cannot_read_the_users_files(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    secret = tmp_path / "secret.csv"
    secret.write_text("root:x:0:0:root:/root:/bin/bash\n")
    text = EXAMPLE_BENCH.read_text()
    gas = text[text.index("[gas]") : text.index("[[sensors]]")]
    log = tmp_path / "run.mcap"
    assert main(["run", "--duration", "1", "--rerun", "off", "--quiet", "--record", str(log)]) == 0
    layout = open_log(log).layout
    trace = "\n".join(f"{a},{1 + 40 * max(0.0, 1 - abs(a - 370) / 60)}" for a in range(0, 721, 10))
    for name in (str(secret), "../../../../../../../../etc/passwd", "../data/trace.csv"):
        crafted = text.replace(gas, f'[gas]\nmodel = "trace"\nfile = "{name}"\n\n')
        evil = tmp_path / "evil.mcap"
        record_source(
            open_log(log).items(),
            evil,
            layout=layout,
            bench_text=crafted,
            attachments={"trace.csv": trace.encode()},
        )
        capsys.readouterr()
        code, _, err = replay(evil, tmp_path / "r.json", capsys)
        if name.endswith("trace.csv"):  # the attachment, whatever the directory
            assert code in (0, 1) and not any("trace" in line for line in err), err
            continue
        assert code == 2 and len(err) == 1
        assert "not attached to the recording" in err[0] and "root:" not in err[0]
        # the report runs a raw-only recording through the chain: the same bench, the same refusal
        assert main(["report", str(evil), "--out", str(tmp_path / "r.html")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not attached to the recording" in err[0], err


def test_a_sidecar_truth_that_is_not_an_object_is_one_line(tmp_path: Path) -> None:
    """The same check for any source (a CSV's ``meta.json {"truth": 5}``): the runner's."""

    class Crafted(Source):
        layout = StreamLayout(synthetic_layout().groups, ("tacho",), {"truth": 5})

        def _iter_items(self) -> Iterator[StreamItem]:
            return iter(())

    bench = load_bench(EXAMPLE_BENCH)
    with pytest.raises(SourceError, match="'truth': expected a JSON object or null, got int"):
        run_source(bench, "", Crafted(), "file:run.csv", RunOptions(quiet=True))


@pytest.mark.parametrize(("opcode", "bit"), [(Opcode.CHUNK, 2), (Opcode.MESSAGE_INDEX, 3)])
def test_a_record_flipped_into_an_end_record_does_not_end_the_read(
    clean_run: CleanRun, tmp_path: Path, opcode: int, bit: int
) -> None:
    """Read front to back (no footer), a chunk that became a footer (0x06 -> 0x02) or an
    index that became a data end (0x07 -> 0x0F) is skipped and said, and the read goes on."""
    data = clean_run.data[: 3 * len(clean_run.data) // 4]
    path = tmp_path / "cut.mcap"
    path.write_bytes(data)
    starts = []
    with open(path, "rb") as fh, contextlib.suppress(Truncated):
        for op, offset, _ in records(fh):
            if op == opcode:
                starts.append(offset - 9)
    log = tmp_path / "flipped.mcap"
    log.write_bytes(flipped(data, starts[2], bit))
    cut, damaged = open_log(path), open_log(log)
    want = [b.first_index for b in cut.items() if isinstance(b, SampleBlock)]
    got = [b.first_index for b in damaged.items() if isinstance(b, SampleBlock)]
    assert got[-1] == want[-1]  # read to the same end
    if opcode == Opcode.CHUNK:
        assert len(got) < len(want)
        (entry,) = [s for s in damaged.report.skipped_document() if s["kind"] == "damaged"]
        assert entry["byte"] == starts[2] and "opcode 0x02" in entry["reason"]
    else:  # an index is not data: nothing lost
        assert got == want


def test_without_pread_the_chunks_are_read_by_seek_and_read_to_the_same_result(
    clean_run: CleanRun, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch
) -> None:
    """A platform without os.pread (Windows) reads the summary's chunks by a seek and a
    read: the replay's result is the clean one, without a note."""
    from replay import chunks

    assert chunks._pread is not None  # (this machine has it: the default path is pread)
    monkeypatch.setattr(chunks, "_pread", None)
    code, doc, err = replay(clean_run.log, tmp_path / "r.json", capsys)
    assert (code, err) == (0, []) and doc == clean_run.result
