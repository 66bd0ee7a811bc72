"""Replaying a recording as a source: same items, pacing, shutdown, and a live run reproduced bit for bit."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
from support.mcap_logs import (
    FakeClock,
    assert_same_items,
    record,
    synthetic_items,
    synthetic_layout,
)

from acquisition.stream import SampleBlock, StreamItem
from estimator.result import EstimateUpdate
from ptinertia.sinks import Sink
from ptinertia.stage_threads import as_recorded
from replay.errors import LogError
from replay.recorder import McapRecorder
from replay.source import McapSource, item_end_time

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def log_path(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[StreamItem]]:
    layout = synthetic_layout(n_ch=3, rate_hz=2048.0)
    items = synthetic_items(layout, 2.0, seed=11)
    path = tmp_path_factory.mktemp("src") / "run.mcap"
    record(path, items, layout)
    return path, items


@pytest.mark.parametrize("cut", [None, 0.6], ids=["finished", "killed"])
def test_source_yields_the_recorded_stream(
    tmp_path: Path, log_path: tuple[Path, list[StreamItem]], cut: float | None
) -> None:
    path, items = log_path
    if cut is not None:  # what a SIGKILL leaves: a prefix of the file
        data = path.read_bytes()
        path = tmp_path / "cut.mcap"
        path.write_bytes(data[: int(cut * len(data))])
    with McapSource(path) as source:
        assert source.layout.groups == synthetic_layout(n_ch=3, rate_hz=2048.0).groups
        got = list(source)
    if cut is None:
        assert_same_items(got, items)
        assert source.report.lines() == []
    else:
        assert 0 < len(got) < len(items)
        assert_same_items(got, items[: len(got)])
        assert any("unfinished recording" in line for line in source.report.lines())


def test_replayed_samples_are_already_as_recorded(
    log_path: tuple[Path, list[StreamItem]],
) -> None:
    """The pipeline skips its float32 rounding for a replay (``samples_as_recorded``): the
    rounding must change nothing, and the samples must be what was recorded."""
    path, items = log_path
    blocks = [i for i in McapSource(path) if isinstance(i, SampleBlock)]
    assert McapSource.samples_as_recorded and blocks
    for block in blocks:
        rounded = as_recorded(block)
        assert isinstance(rounded, SampleBlock)
        assert block.data.dtype == np.float64
        assert np.array_equal(rounded.data, block.data, equal_nan=True)
    recorded = [as_recorded(i) for i in items if isinstance(i, SampleBlock)]
    for got, want in zip(blocks, recorded, strict=True):
        assert isinstance(want, SampleBlock)
        assert np.array_equal(got.data, want.data, equal_nan=True)


def test_realtime_pacing_follows_stream_time(log_path: tuple[Path, list[StreamItem]]) -> None:
    path, items = log_path
    clock = FakeClock()
    source = McapSource(path, speed=4.0, monotonic=clock.monotonic, sleep=clock.sleep)
    layout = source.layout
    times = [t for t in (item_end_time(i, layout) for i in items) if t is not None]
    span = max(times) - times[0]  # the first item is released at once
    start = clock.monotonic()
    released = [(clock.monotonic(), item_end_time(item, layout)) for item in source]
    elapsed = clock.monotonic() - start
    assert len(released) == len(items)
    assert elapsed == pytest.approx(span / 4.0, abs=1e-9)
    # every item is released once its last sample's stream time has elapsed, at 4x
    for wall, t in released:
        if t is not None:
            assert wall - start >= (t - times[0]) / 4.0 - 1e-9
    assert all(s > 0 for s in clock.sleeps)


def test_close_interrupts_a_paced_replay(log_path: tuple[Path, list[StreamItem]]) -> None:
    path, _ = log_path
    clock = FakeClock()  # stands still: the next item is minutes away, whatever the machine
    source = McapSource(path, speed=0.01, monotonic=clock.monotonic)
    got: list[StreamItem] = []
    first = threading.Event()

    def read() -> None:
        for item in source:
            got.append(item)
            first.set()

    reader = threading.Thread(target=read)
    reader.start()
    assert first.wait(timeout=30.0)  # a guard against a hang, not a measurement
    source.close()  # from another thread, while the reader waits for the next item
    reader.join(timeout=30.0)
    assert not reader.is_alive()
    assert 1 <= len(got) < 5


def test_closing_during_an_injected_sleep_ends_the_replay(
    log_path: tuple[Path, list[StreamItem]],
) -> None:
    path, items = log_path
    clock = FakeClock()
    source = McapSource(path, speed=1.0, monotonic=clock.monotonic, sleep=lambda s: source.close())
    got = list(source)
    assert 1 <= len(got) < len(items)


def test_simulated_sweep_written_as_mcap_replays_like_the_source(tmp_path: Path) -> None:
    """``simulate --out x.mcap``: the file writer interface, bench text and truth included."""
    from ptinertia.config import load_bench
    from ptinertia.sources import open_source
    from replay.raw_writer import McapFileWriter

    bench_path = ROOT / "examples" / "i3-bench.toml"
    text = bench_path.read_text()
    out = tmp_path / "sweep.mcap"
    with open_source("sim", load_bench(bench_path), bench_text=text, duration_s=0.5) as source:
        items = list(source)
        layout = source.layout
    with McapFileWriter(out) as writer:
        writer.start(layout)
        for item in items:
            writer.write(item)
    with McapSource(out) as replayed:
        assert replayed.log.bench_text == text
        assert replayed.log.truth == layout.metadata["truth"]
        assert replayed.layout.groups == layout.groups
        assert_same_items(list(replayed), items)


def test_bad_speed_is_one_line(log_path: tuple[Path, list[StreamItem]]) -> None:
    with pytest.raises(LogError, match="speed: expected a positive factor"):
        McapSource(log_path[0], speed=0.0)


def test_replay_of_a_recorded_simulated_run_is_bit_identical(tmp_path: Path) -> None:
    """Live run with the recorder, then the same chain on the recording: the same numbers."""
    runner = pytest.importorskip("ptinertia.runner")
    from ptinertia.config import load_bench
    from ptinertia.sources import open_source
    from replay.reader import open_log

    bench_path = ROOT / "examples" / "i3-bench.toml"
    bench, text = load_bench(bench_path), bench_path.read_text()
    path = tmp_path / "live.mcap"
    recorder, counter = McapRecorder(path), Counting()
    with open_source("sim", bench, bench_text=text, duration_s=2.5) as source:
        live, live_doc = runner.run_source(
            bench, text, source, "sim", runner.RunOptions(quiet=True, sinks=(recorder, counter))
        )
    assert live_doc is not None and live.estimate is not None

    log = open_log(path)
    assert log.bench_text == text and log.truth == source.layout.metadata["truth"]
    with McapSource(log) as replayed_source:
        replay, replay_doc = runner.run_source(
            load_bench(bench_path),
            log.bench_text,
            replayed_source,
            log.source,
            runner.RunOptions(quiet=True),
        )
    assert json.dumps(replay_doc, sort_keys=True) == json.dumps(live_doc, sort_keys=True)
    assert replay.frames == live.frames and replay.items == live.items
    final = log.final_estimate()
    assert final is not None
    assert final.theta.tobytes() == replay.estimate.theta.tobytes()
    assert final.cov.tobytes() == replay.estimate.cov.tobytes()
    assert log.result == json.loads(json.dumps(replay.estimate.to_json()))
    counts = log.message_counts
    assert counts is not None
    assert counts["/orders"] == counts["/gating"] == live.frames
    assert counts["/estimate"] == counter.estimates + 1  # every published update, plus the final
    source_events = sum(origin == "source" for origin, _ in log.events())
    assert sum(counts[t] for t in counts if t.startswith("/raw/")) + source_events == live.items
    assert sum(isinstance(i, SampleBlock) for i in log.items()) == sum(
        counts[t] for t in counts if t.startswith("/raw/") and not t.startswith("/raw/edges/")
    )


class Counting(Sink):
    def __init__(self) -> None:
        self.estimates = 0

    def on_estimate(self, update: EstimateUpdate) -> None:
        self.estimates += 1
