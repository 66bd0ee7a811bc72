"""Chunks by stream time and the data section's CRC, checked with the mcap library's readers.

A recording whose results lag the raw stream (as the dsp's frames do) must
still have chunks that do not overlap in time, so a time-indexed read opens
only the chunks of its window; the data end record carries a CRC the mcap
stream reader validates.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.records import DataEnd
from mcap.stream_reader import CRCValidationError, StreamReader
from support.mcap_logs import (
    BENCH_TEXT,
    FakeClock,
    assert_same_items,
    make_frame,
    make_outcome,
    synthetic_items,
    synthetic_layout,
)

from acquisition.stream import SampleBlock, StreamItem
from replay.reader import open_log
from replay.recorder import McapRecorder
from replay.recording_head import RecordingInfo
from replay.time_chunks import TimeChunker

LAG_S = 0.08  # frames describe the stream this far behind its newest sample


def _record_with_lagging_results(path: Path, seconds: float) -> list[StreamItem]:
    """Raw items, and after each sample block an order frame and gating ``LAG_S`` behind it."""
    layout = synthetic_layout()
    items = synthetic_items(layout, seconds, seed=3)
    rng = np.random.default_rng(0)
    rate = layout.groups[0].rate_hz
    rec = McapRecorder(path, time_origin_ns=1_700_000_000 * 10**9)
    rec.start(RecordingInfo(layout=layout, bench_text=BENCH_TEXT))
    for item in items:
        rec.on_item(item)
        if isinstance(item, SampleBlock) and item.group == "acc":
            t = (item.first_index + item.n_samples) / rate - LAG_S
            if t > 0:
                frame = make_frame(t, rng)
                rec.on_frame(frame, make_outcome(frame, used=True))
    rec.close(None)
    return items


@pytest.fixture(scope="module")
def lagging_log(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[StreamItem]]:
    path = tmp_path_factory.mktemp("timeidx") / "lag.mcap"
    return path, _record_with_lagging_results(path, 6.0)


def test_chunks_hold_one_half_second_each_and_do_not_overlap(
    lagging_log: tuple[Path, list[StreamItem]],
) -> None:
    path, items = lagging_log
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    origin = 1_700_000_000 * 10**9
    assert len(chunks) == 12  # 6 s in 0.5 s slices
    for k, chunk in enumerate(chunks):
        # slice k of the stream: [0.5 k, 0.5 (k + 1)) s
        assert origin + k * 500_000_000 <= chunk.message_start_time
        assert chunk.message_end_time < origin + (k + 1) * 500_000_000
    # and the raw stream still comes back in the order it was recorded
    assert_same_items(list(open_log(path).items()), items)


class _SeekLog(io.BytesIO):
    """A file that remembers where it was read from."""

    def __init__(self, data: bytes) -> None:
        super().__init__(data)
        self.reads: list[int] = []

    def read(self, size: int | None = -1) -> bytes:
        self.reads.append(self.tell())
        return super().read(size)


def test_a_time_window_read_opens_only_the_chunks_of_that_window(
    lagging_log: tuple[Path, list[StreamItem]],
) -> None:
    path, _ = lagging_log
    origin = 1_700_000_000 * 10**9
    start, end = origin + 2 * 10**9, origin + 4 * 10**9  # seconds 2 to 4 of the run
    fh = _SeekLog(path.read_bytes())
    reader = make_reader(fh)
    summary = reader.get_summary()
    assert summary is not None
    fh.reads.clear()
    times = [m.log_time for _, _, m in reader.iter_messages(starting_at=start, ending_before=end)]
    assert times and min(times) >= start and max(times) < end
    opened = {
        c.chunk_start_offset
        for c in summary.chunk_indexes
        if any(c.chunk_start_offset <= r < c.chunk_start_offset + c.chunk_length for r in fh.reads)
    }
    in_window = {
        c.chunk_start_offset
        for c in summary.chunk_indexes
        if start <= c.message_start_time and c.message_end_time < end
    }
    assert len(in_window) == 4
    assert opened == in_window


def test_log_and_publish_times_are_on_the_stream_clock(
    lagging_log: tuple[Path, list[StreamItem]],
) -> None:
    path, _ = lagging_log
    lag: dict[str, float] = {}
    with open(path, "rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages(log_time_order=False):
            d = (message.publish_time - message.log_time) / 1e9
            assert d >= 0  # published when measured or later, never before
            lag[channel.topic] = max(lag.get(channel.topic, 0.0), d)
    # a frame is published once the stream has reached its block's end, LAG_S after its time
    # (the newest item's time stamp is its first sample or edge, a little before that end)
    assert LAG_S / 2 < lag["/orders"] <= LAG_S
    assert lag["/raw/acc"] == 0.0
    assert lag["/raw/edges/tacho"] < 0.15  # an edge block's first edge precedes the newest block's


def test_the_data_section_crc_is_written_and_checked(
    lagging_log: tuple[Path, list[StreamItem]],
) -> None:
    path, _ = lagging_log
    data = path.read_bytes()
    ends = [r for r in StreamReader(io.BytesIO(data), validate_crcs=True).records]
    crc = [r.data_section_crc for r in ends if isinstance(r, DataEnd)]
    assert len(crc) == 1 and crc[0] != 0
    # a changed byte in the head (the bench attachment, outside every chunk) is caught
    at = data.index(BENCH_TEXT.encode())
    spoiled = data[:at] + b"X" + data[at + 1 :]
    with pytest.raises(CRCValidationError):
        for _ in StreamReader(io.BytesIO(spoiled), validate_crcs=True).records:
            pass


def test_a_message_later_than_the_wait_goes_to_the_oldest_open_chunk() -> None:
    clock = FakeClock()
    chunker = TimeChunker(0.5, 0.25, clock.monotonic)
    assert chunker.add("raw", 100_000_000, (1, 1, b"", 1)) == []
    assert chunker.add("raw", 600_000_000, (1, 2, b"", 2)) == []
    ready = chunker.add("raw", 760_000_000, (1, 3, b"", 3))  # 0.25 s past slice 0: it is written
    assert [[m[1] for m in c] for c in ready] == [[1]]
    chunker.add("result", 200_000_000, (2, 4, b"", 4))  # too late for slice 0: slice 1 takes it
    chunker.add("raw", 1100_000_000, (1, 5, b"", 5))
    chunker.add("raw", 900_000_000, (1, 6, b"", 6))  # the raw stream keeps its order: slice 2
    chunker.add("result", 900_000_000, (2, 7, b"", 7))  # a result need not follow the raw stream
    assert chunker.late_messages == 2
    assert [[m[1] for m in c] for c in chunker.drain()] == [[2, 3, 4, 7], [5, 6]]


def test_a_crawling_stream_is_written_on_wall_time() -> None:
    clock = FakeClock()
    chunker = TimeChunker(0.5, 0.25, clock.monotonic)
    chunker.add("raw", 0_000_000, (1, 0, b"", 0))
    clock.advance(0.74)
    assert chunker.add("raw", 1_000_000, (1, 1, b"", 1)) == []
    clock.advance(0.01)
    assert len(chunker.add("raw", 2_000_000, (1, 2, b"", 2))) == 1
