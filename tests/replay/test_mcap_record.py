"""Recording to MCAP: round trip, third-party decoding, counts, chunk bounds, size.

The synthetic streams here are built by hand (random block lengths down to
one sample, NaN samples, empty edge blocks) so the tests are fast and cover
the corners a simulator never produces.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from support.mcap_logs import (
    BENCH_TEXT,
    DBC,
    TRUTH,
    FakeClock,
    assert_same_items,
    record,
    synthetic_items,
    synthetic_layout,
)

from acquisition.stream import (
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SampleGroup,
    SourceEvent,
    StreamItem,
    StreamLayout,
)
from replay.raw_writer import record_source
from replay.reader import open_log
from replay.recorder import McapRecorder
from replay.recording_head import RecordingInfo


@pytest.fixture(scope="module")
def recorded(
    tmp_path_factory: pytest.TempPathFactory,
) -> tuple[Path, list[StreamItem], StreamLayout]:
    layout = synthetic_layout()
    items = synthetic_items(layout, 3.0)
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    record(path, items, layout)
    return path, items, layout


def test_raw_items_round_trip_exactly(
    recorded: tuple[Path, list[StreamItem], StreamLayout],
) -> None:
    path, items, layout = recorded
    log = open_log(path)
    assert log.finished and not log.report.lines()
    assert log.layout == layout
    assert_same_items(list(log.items()), items)


def test_single_sample_blocks_round_trip(tmp_path: Path) -> None:
    layout = synthetic_layout(n_ch=2, rate_hz=200.0)
    items = synthetic_items(layout, 0.5, seed=3, min_block=1)
    items += [
        SampleBlock("acc", 10_000, np.zeros((2, 0))),
        SampleBlock("acc", 10_000, np.ones((2, 1))),
    ]
    path = tmp_path / "tiny.mcap"
    record_source(items, path, layout=layout, bench_text=BENCH_TEXT)
    assert_same_items(list(open_log(path).items()), items)


def test_metadata_attachments_and_truth(
    recorded: tuple[Path, list[StreamItem], StreamLayout],
) -> None:
    path, _, layout = recorded
    log = open_log(path)
    assert log.bench_text == BENCH_TEXT
    assert log.attachments["acc.dbc"] == DBC
    assert log.truth == TRUTH
    assert log.settings == {"dsp": {"orders": [1.0, 1.5]}}
    assert log.source == "synthetic"
    assert log.layout.metadata == layout.metadata
    assert log.metadata["ptinertia"]["format"] == "ptinertia-recording"
    assert log.result is None  # closed without a final estimate


def test_message_counts_per_topic(recorded: tuple[Path, list[StreamItem], StreamLayout]) -> None:
    path, items, _ = recorded
    want = {"/raw/acc": 0, "/raw/slow": 0, "/raw/edges/tacho": 0, "/events": 0}
    for item in items:
        if isinstance(item, SampleBlock):
            want[f"/raw/{item.group}"] += 1
        else:
            want["/raw/edges/tacho" if isinstance(item, EdgeBlock) else "/events"] += 1
    want.update({"/orders": 0, "/gating": 0, "/estimate": 0, "/raw/can": 0})
    # every event is also a foxglove.Log line; the 3D scene comes from a scene sink (none here)
    want.update({"/foxglove/log": want["/events"], "/foxglove/scene": 0, "/foxglove/tf": 0})
    assert open_log(path).message_counts == want


def test_third_party_reader_decodes_every_topic(
    recorded: tuple[Path, list[StreamItem], StreamLayout],
) -> None:
    """mcap + google.protobuf only: the schema in the file is all a reader needs."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    path, items, _ = recorded
    classes: dict[int, Any] = {}
    counts: dict[str, int] = {}
    decoded: dict[str, list[Any]] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None and schema.encoding == "protobuf"
            assert channel.message_encoding == "protobuf"
            if schema.id not in classes:
                fds = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
                pool = descriptor_pool.DescriptorPool()
                for fd in fds.file:
                    pool.Add(fd)
                desc = pool.FindMessageTypeByName(schema.name)
                classes[schema.id] = message_factory.GetMessageClass(desc)
            msg = classes[schema.id].FromString(message.data)
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            decoded.setdefault(channel.topic, []).append(msg)
    acc = [it for it in items if isinstance(it, SampleBlock) and it.group == "acc"]
    edges = [it for it in items if isinstance(it, EdgeBlock)]
    events = [it for it in items if isinstance(it, SourceEvent)]
    assert counts == {
        "/raw/acc": len(acc),
        "/raw/slow": len(items) - len(acc) - len(edges) - len(events),
        "/raw/edges/tacho": len(edges),
        "/events": len(events),
        "/foxglove/log": len(events),  # decoded from its embedded schema, as the others
    }
    for msg, block in zip(decoded["/raw/acc"], acc, strict=True):
        data = np.array(msg.data, dtype=np.float32).reshape(len(msg.channels), msg.n_samples)
        np.testing.assert_array_equal(data, block.data.astype(np.float32))
        assert msg.first_index == block.first_index and msg.group == "acc"
        assert msg.time_s == pytest.approx(block.first_index / 2560.0, abs=1e-12)
    for msg, eb in zip(decoded["/raw/edges/tacho"], edges, strict=True):
        assert list(msg.times_s) == eb.times_s.tolist()
    assert [(m.kind, m.message, m.count) for m in decoded["/events"]] == [
        (e.kind, e.message, e.count) for e in events
    ]


def test_mcap_protobuf_decoder_factory_reads_the_log(
    recorded: tuple[Path, list[StreamItem], StreamLayout],
) -> None:
    """The stock protobuf decoder of the mcap ecosystem (what Foxglove-like tools use)."""
    decoder = pytest.importorskip("mcap_protobuf.decoder")
    path, items, _ = recorded
    n = 0
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(topics=["/raw/slow"]):
            assert channel.topic == "/raw/slow" and list(msg.channels) == ["rpm"]
            n += 1
    assert n == sum(isinstance(i, SampleBlock) and i.group == "slow" for i in items)


def test_raw_can_frames_from_the_acquisition_thread(tmp_path: Path) -> None:
    """The CAN source's frame_listener runs on another thread than the other hooks."""
    import threading

    from acquisition.can.frames import RawFrame

    rng = np.random.default_rng(9)
    batches = [
        [
            RawFrame(
                1_700_000_000_000_000_000 + 1000 * (100 * b + k),
                int(rng.integers(0, 2**29)) if k % 3 == 0 else int(rng.integers(0, 2**11)),
                k % 3 == 0,
                rng.bytes(int(rng.choice([0, 8, 12, 64]))),
                k % 2 == 0,
            )
            for k in range(int(rng.integers(1, 60)))
        ]
        for b in range(40)
    ]
    layout = synthetic_layout()
    items = synthetic_items(layout, 2.0, seed=8)
    path = tmp_path / "can.mcap"
    rec = McapRecorder(path)
    rec.start(RecordingInfo(layout=layout, source="can:virtual:x", attachments={"daq.dbc": DBC}))

    def acquisition() -> None:
        for batch in batches:
            rec.on_can_frames(batch)

    listener = threading.Thread(target=acquisition)
    listener.start()
    for item in items:
        rec.on_item(item)
    listener.join()
    rec.close(None)
    rec.on_can_frames(batches[0])  # a late batch after close is dropped, not an error

    log = open_log(path)
    assert list(log.can_frames()) == batches
    assert_same_items(list(log.items()), items)
    assert log.attachments["daq.dbc"] == DBC
    assert log.message_counts is not None and log.message_counts["/raw/can"] == len(batches)


def test_chunks_span_at_most_half_a_second_of_stream(tmp_path: Path) -> None:
    layout = synthetic_layout()
    items = synthetic_items(layout, 4.0, seed=1)
    path = tmp_path / "chunks.mcap"
    record(path, items, layout)
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    spans = [(c.message_end_time - c.message_start_time) / 1e9 for c in summary.chunk_indexes]
    # a chunk closes on the first message at or past 0.5 s; blocks are at most 0.15 s long
    assert len(spans) >= 4 / (0.5 + 0.15)
    assert max(spans) < 0.5 + 0.15
    assert all(c.compression == "zstd" for c in summary.chunk_indexes)


def test_chunks_close_on_wall_time_when_stream_time_crawls(tmp_path: Path) -> None:
    layout = synthetic_layout(n_ch=1, rate_hz=100000.0)
    path = tmp_path / "slow.mcap"
    clock = FakeClock()
    rec = McapRecorder(path, chunk_s=0.2, monotonic=clock.monotonic)
    rec.start(RecordingInfo(layout=layout))
    for k in range(100):  # 1 s of wall time, 1 ms of stream time
        rec.on_item(SampleBlock("acc", k, np.zeros((1, 1))))
        clock.advance(0.01)
    rec.close(None)
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    assert len(summary.chunk_indexes) >= 4  # 1 s / 0.2 s, whatever the stream time did


def test_a_group_that_would_take_a_fixed_topic_is_refused(tmp_path: Path) -> None:
    from replay.errors import LogError

    layout = StreamLayout((SampleGroup("can", 100.0, (ChannelSpec("x", "V"),)),))
    with pytest.raises(LogError, match="share the topic /raw/can"):
        McapRecorder(tmp_path / "x.mcap").start(RecordingInfo(layout=layout))


def test_raw_payload_is_float32_sized(tmp_path: Path) -> None:
    layout = synthetic_layout(n_ch=10, rate_hz=25600.0)
    rng = np.random.default_rng(2)
    items: list[StreamItem] = [
        SampleBlock("acc", k * 2560, rng.standard_normal((10, 2560))) for k in range(10)
    ]
    stats = record_source(items, tmp_path / "size.mcap", layout=layout)
    float32_bytes = 4 * 10 * 2560 * 10
    assert stats.payload_bytes["/raw/acc"] <= 1.2 * float32_bytes
    assert stats.payload_bytes["/raw/acc"] >= float32_bytes
