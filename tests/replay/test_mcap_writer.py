"""The threaded MCAP writer: the same bytes as mcap's own writer, errors in the caller's thread.

``replay.mcapwriter.ThreadedWriter`` compresses and writes chunks on a
background thread; the recorder's crash safety and every reader rely on it
writing exactly what ``mcap.writer.Writer`` writes.
"""

from __future__ import annotations

import errno
import io
import os
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap.writer import CompressionType, Writer
from support.mcap_logs import BENCH_TEXT, assert_same_items, synthetic_items, synthetic_layout
from support.mcap_writer_calls import drive

from acquisition.stream import ChannelSpec, SampleBlock, SampleGroup, StreamLayout
from replay import mcap_output, stream_codec
from replay.errors import LogError
from replay.mcap_output import LateBytes
from replay.mcap_records import MAGIC
from replay.mcapwriter import ThreadedWriter
from replay.reader import open_log
from replay.recorder import McapRecorder
from replay.recording_head import RecordingInfo

COMPRESSIONS = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "": CompressionType.NONE}


@pytest.mark.parametrize("compression", list(COMPRESSIONS))
@pytest.mark.parametrize("seed", [0, 1])
def test_same_bytes_as_the_mcap_writer(compression: str, seed: int) -> None:
    if compression == "lz4":
        pytest.importorskip("lz4")
    ours, theirs = io.BytesIO(), io.BytesIO()
    drive(ThreadedWriter(ours, chunk_size=50_000, compression=compression), seed)
    drive(
        Writer(
            theirs,
            chunk_size=50_000,
            compression=COMPRESSIONS[compression],
            enable_data_crcs=True,
        ),
        seed,
    )
    assert len(theirs.getvalue()) > 100_000
    assert ours.getvalue() == theirs.getvalue()
    summary = make_reader(io.BytesIO(ours.getvalue())).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 2000
    assert len(summary.chunk_indexes) > 20  # size-bound and flushed chunks both happened


def test_late_sample_data_is_written_as_the_bytes_it_stands_for() -> None:
    """The recorder hands sample blocks over uncast (``stream_codec.LateSamples``); the
    writer thread casts and joins them: the file is the one their bytes give."""
    group = SampleGroup("acc", 100.0, tuple(ChannelSpec(f"c{i}", "V") for i in range(3)))
    rng = np.random.default_rng(5)
    wide = rng.standard_normal((3, 4000))
    wide.flags.writeable = False  # (as the pipeline's: only read-only arrays are cast late)
    blocks = [SampleBlock("acc", 50 * k, wide[:, k : k + 50 * (k % 4)]) for k in range(200)]
    files = []
    for encode in (stream_codec.encode_samples, stream_codec.encode_samples_late):
        out = io.BytesIO()
        writer = ThreadedWriter(out, chunk_size=20_000)
        writer.start()
        channel = writer.register_channel(
            "/raw/acc", "protobuf", writer.register_schema("s", "protobuf", b"x")
        )
        for k, block in enumerate(blocks):
            data = encode(block, group)
            writer.add_message(channel, k, data, k)
            if k % 37 == 0:
                writer.flush()
        writer.finish()
        files.append(out.getvalue())
    assert isinstance(stream_codec.encode_samples_late(blocks[1], group), LateBytes)
    assert files[1] == files[0]
    summary = make_reader(io.BytesIO(files[1])).get_summary()
    assert summary is not None and summary.statistics is not None
    assert summary.statistics.message_count == 200
    assert len(summary.chunk_indexes) > 10  # size-bound and flushed chunks both happened


def test_a_buffer_refilled_by_its_owner_is_recorded_as_it_was_handed_over(
    tmp_path: Path,
) -> None:
    """A caller may refill one writable array block after block: the recorder encodes such
    an array at once (only read-only arrays are cast late, on the writer thread)."""
    layout = StreamLayout((SampleGroup("acc", 100.0, (ChannelSpec("a", "m/s^2"),)),))
    path = tmp_path / "refilled.mcap"
    rec = McapRecorder(path, chunk_s=10.0)  # every block waits in one chunk
    rec.start(RecordingInfo(layout=layout, bench_text=BENCH_TEXT))
    buffer = np.zeros((1, 10), np.float32)
    for k in range(40):
        buffer[:] = k
        rec.on_item(SampleBlock("acc", 10 * k, buffer))
    rec.close(None)
    got = [item.data[0, 0] for item in open_log(path).items() if isinstance(item, SampleBlock)]
    assert got == [float(k) for k in range(40)]


def test_a_chunk_handed_over_whole_is_what_its_messages_one_by_one_give() -> None:
    """``add_chunk`` (the recorder's: records packed on the writer thread) against
    ``add_message`` for each message and ``flush``: the same file, size-bound splits and
    the channel records waiting for the first message included."""
    rng = np.random.default_rng(3)
    groups = [
        [
            (1 + int(rng.integers(2)), 1000 * g + k, rng.bytes(int(rng.integers(0, 900))), 7)
            for k in range(int(rng.integers(1, 30)))
        ]
        for g in range(40)
    ]
    files, chunks = [], []
    for whole in (False, True):
        out = io.BytesIO()
        writer = ThreadedWriter(out, chunk_size=4_000)
        writer.start()
        schema = writer.register_schema("s", "protobuf", b"x")
        writer.register_channel("/a", "protobuf", schema)
        writer.register_channel("/b", "protobuf", schema)
        for group in groups:
            if whole:
                writer.add_chunk(group)
                continue
            for channel, log_time, data, publish_time in group:
                writer.add_message(channel, log_time, data, publish_time)
            writer.flush()
        writer.finish()
        files.append(out.getvalue())
        chunks.append(writer.chunks)
    assert files[1] == files[0]
    assert chunks[1] == chunks[0] > len(groups)  # some groups were split by size


def test_an_empty_file_is_the_mcap_writers_too() -> None:
    ours, theirs = io.BytesIO(), io.BytesIO()
    for writer in (ThreadedWriter(ours), Writer(theirs, enable_data_crcs=True)):
        writer.start(profile="", library="ptinertia test")
        writer.register_channel("/x", "json", writer.register_schema("S", "jsonschema", b"{}"))
        writer.finish()
    assert ours.getvalue() == theirs.getvalue()


def test_a_flushed_chunk_is_in_the_file_after_sync(tmp_path: Path) -> None:
    path = tmp_path / "open.mcap"
    with open(path, "wb") as fh:
        writer = ThreadedWriter(fh)
        writer.start()
        schema = writer.register_schema("S", "jsonschema", b"{}")
        channel = writer.register_channel("/x", "json", schema)
        for k in range(10):
            writer.add_message(channel, k, b"{}", k)
        writer.flush()
        writer.sync()
        writer.add_message(channel, 10, b"{}", 10)  # the open chunk: not in the file yet
        with open(path, "rb") as cut:
            reader = NonSeekingReader(cut)
            got = []
            with pytest.raises(EndOfFile):  # the file ends where the next chunk goes
                for _, _, message in reader.iter_messages(log_time_order=False):
                    got.append(message.log_time)
        assert got == list(range(10))
        writer.finish()
    with open(path, "rb") as fh:
        assert [m.log_time for _, _, m in make_reader(fh).iter_messages()] == list(range(11))
    assert not _writer_threads()


class FailingStream(io.BytesIO):
    """Accepts ``limit`` bytes, then fails like a full disk."""

    def __init__(self, limit: int) -> None:
        super().__init__()
        self.limit = limit

    def write(self, data: Any) -> int:
        if self.tell() + len(data) > self.limit:
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(data)


def test_a_write_error_reaches_the_callers_thread() -> None:
    writer = ThreadedWriter(FailingStream(20_000), chunk_size=1000)
    writer.start()
    channel = writer.register_channel("/x", "", 0)
    with pytest.raises(OSError, match="No space left"):
        for k in range(1000):  # the error comes back on a flush after the chunk that failed
            writer.add_message(channel, k, bytes(100), k)
            if k % 10 == 9:
                writer.flush()
    with pytest.raises(OSError, match="No space left"):
        writer.finish()
    writer.finish()  # once finished, a second call is a no-op
    assert not _writer_threads()


def test_a_full_disk_leaves_the_complete_chunks_readable(tmp_path: Path) -> None:
    """The chunk that does not fit is cut off and the file closed: mcap's own reader and
    ours read every message of the chunks written before it."""
    stream = FailingStream(20_000)
    writer = ThreadedWriter(stream, chunk_size=1000)
    writer.start()
    channel = writer.register_channel("/x", "", 0)
    sent = 0
    with pytest.raises(OSError, match="No space left"):
        for k in range(1000):
            writer.add_message(channel, k, bytes(100), k)
            sent = k + 1
            if k % 10 == 9:
                writer.flush()
    writer.stop()
    kept_until = writer.cut_end_ns()
    assert kept_until is not None and 0 < kept_until < sent
    data = stream.getvalue()
    assert len(data) <= 20_000 and data.endswith(MAGIC)
    times = [m.log_time for _, _, m in make_reader(io.BytesIO(data)).iter_messages()]
    assert times == list(range(kept_until + 1))  # every complete chunk, in order, nothing else


def test_a_chunk_written_in_pieces_is_the_joined_chunk(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """To a plain file a chunk goes out with ``os.writev`` (no joined copy); a short count
    (a disk filling up) is completed by ``write``: the file is the one a BytesIO gets."""
    real_writev = os.writev
    calls = []

    def short_writev(fd: int, parts: list[bytes]) -> int:
        calls.append(len(parts))
        if len(calls) % 2:
            return real_writev(fd, parts)
        joined = b"".join(parts)
        return os.write(fd, joined[: len(joined) // 3])

    monkeypatch.setattr(mcap_output.os, "writev", short_writev)
    files = []
    for to_file in (False, True):
        path = tmp_path / "pieces.mcap"
        stream: Any = open(path, "wb", buffering=0) if to_file else io.BytesIO()
        drive(ThreadedWriter(stream, chunk_size=50_000), 1)
        files.append(path.read_bytes() if to_file else stream.getvalue())
        stream.close()
    assert len(calls) > 4  # chunks went out through writev, whole and short
    assert files[1] == files[0]


def test_a_chunk_of_more_parts_than_writev_takes_is_joined(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # os.writev refuses more than IOV_MAX buffers (EINVAL, which would read as a disk
    # failure): such a chunk is joined and written whole, the same file
    monkeypatch.setattr(mcap_output, "_IOV_MAX", 2)
    counted = []
    monkeypatch.setattr(mcap_output.os, "writev", lambda fd, parts: counted.append(parts) or 0)
    path = tmp_path / "joined.mcap"
    with open(path, "wb", buffering=0) as stream:
        drive(ThreadedWriter(stream, chunk_size=50_000), 1)
    reference = io.BytesIO()
    drive(ThreadedWriter(reference, chunk_size=50_000), 1)
    assert counted == [] and path.read_bytes() == reference.getvalue()


class FullDiskFile(io.FileIO):
    """A real file on a disk with ``limit`` bytes free: a write takes what fits (a short
    count, as write(2) does), the next one fails with ENOSPC."""

    limit = 60_000

    def write(self, data: Any) -> int:
        room = self.limit - self.tell()
        if room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        return super().write(memoryview(data)[:room])


def test_a_recording_cut_by_a_full_disk_replays_what_was_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import replay.recorder

    monkeypatch.setattr(
        replay.recorder, "open", lambda p, *_, **__: FullDiskFile(p, "w"), raising=False
    )
    layout = synthetic_layout()
    items = synthetic_items(layout, 6.0, seed=3)
    path = tmp_path / "full.mcap"
    rec = McapRecorder(path, chunk_s=0.2)
    rec.start(RecordingInfo(layout=layout, bench_text=BENCH_TEXT))
    fed = []
    with pytest.raises(LogError, match="No space left on device; the recording is closed readable"):
        for item in items:
            rec.on_item(item)
            fed.append(item)
        rec.close(None)
    rec.close(None)
    assert path.stat().st_size <= FullDiskFile.limit
    log = open_log(path)
    assert any("closed early" in line for line in log.report.lines())
    got = list(log.items())
    assert 0 < len(got) < len(fed)
    assert_same_items(got, fed[: len(got)])  # what is in the file is what was fed
    with open(path, "rb") as fh:  # and mcap's own reader reads it too
        assert sum(1 for _ in make_reader(fh).iter_messages()) > 0


def test_recording_to_a_full_disk_is_one_line(tmp_path: Path) -> None:
    if not Path("/dev/full").exists():
        pytest.skip("needs /dev/full")
    rec = McapRecorder("/dev/full")
    with pytest.raises(LogError, match="cannot write the recording /dev/full: No space left"):
        rec.start(RecordingInfo(layout=synthetic_layout(), bench_text=BENCH_TEXT))
    rec.close(None)
    assert not _writer_threads()


def test_ctrl_c_mid_run_leaves_a_finished_file(tmp_path: Path) -> None:
    """A KeyboardInterrupt between two items, then ``close`` (what the pipeline does)."""
    layout = synthetic_layout()
    items = synthetic_items(layout, 3.0, seed=2)
    path = tmp_path / "interrupted.mcap"
    rec = McapRecorder(path, chunk_s=0.2)
    rec.start(RecordingInfo(layout=layout, bench_text=BENCH_TEXT))
    fed = []
    try:
        for k, item in enumerate(items):
            if k == len(items) // 2:
                raise KeyboardInterrupt
            rec.on_item(item)
            fed.append(item)
    except KeyboardInterrupt:
        pass
    finally:
        rec.close(None)
    log = open_log(path)
    assert log.finished
    assert_same_items(list(log.items()), fed)
    assert not _writer_threads()


def test_a_failed_start_leaves_no_thread(tmp_path: Path) -> None:
    rec = McapRecorder(tmp_path / "x.mcap")
    with pytest.raises(TypeError):  # settings that do not serialise
        rec.start(RecordingInfo(layout=synthetic_layout(), settings={"x": object()}))
    assert not _writer_threads()
    rec.close(None)
    with pytest.raises(RuntimeError, match="after close"):
        rec.on_item(SampleBlock("acc", 0, np.zeros((4, 1))))


# Writer threads alive when a test starts are not its own: under pytest-xdist a worker's
# earlier test (another module's recorder, closed and joined) can still be seen exiting on a
# loaded machine, which failed the full-disk tests now and then. Each test checks the
# threads it started itself.
_BEFORE: set[threading.Thread] = set()


@pytest.fixture(autouse=True)
def _threads_before_the_test() -> None:
    _BEFORE.clear()
    _BEFORE.update(t for t in threading.enumerate() if t.name == "mcap-writer")


def _writer_threads() -> list[threading.Thread]:
    return [
        t
        for t in threading.enumerate()
        if t.name == "mcap-writer" and t.is_alive() and t not in _BEFORE
    ]
