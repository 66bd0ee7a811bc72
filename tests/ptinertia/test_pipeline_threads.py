"""The pipeline's stages on their own threads (reader, dsp inline or on a third thread,
processing): the sinks hear
what one thread would have told them, in the same order, and an error in a stage
reaches the caller as it did.

A scripted tracker (item i completes frames tagged i) and a scripted estimator (every
frame used) make the expected sequence of sink calls known without running the dsp
stage or the estimator; the replay tests check the real chain (replay equals live).
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from acquisition.stream import (
    ChannelSpec,
    SampleBlock,
    SampleGroup,
    Source,
    SourceEvent,
    StreamItem,
    StreamLayout,
)
from ptinertia.pipeline import Pipeline

LAYOUT = StreamLayout((SampleGroup("accel", 100.0, (ChannelSpec("a", "m/s^2"),)),))


class ListSource(Source):
    """``items`` in order; raises ``error`` after them when given."""

    def __init__(self, items: list[StreamItem], error: BaseException | None = None) -> None:
        super().__init__()
        self.items = items
        self.error = error
        self.closed = False

    @property
    def layout(self) -> StreamLayout:
        return LAYOUT

    def _iter_items(self) -> Iterator[StreamItem]:
        yield from self.items
        if self.error is not None:
            raise self.error

    def _shutdown(self) -> None:
        self.closed = True


class ScriptedTracker:
    """Block ``i`` completes ``i % 3`` frames (time ``i + j / 10``) and, every fourth
    block, an event; ``fail_at``: the block index whose feed raises."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.fail_at = fail_at
        self.finished = False

    def feed(self, item: StreamItem) -> tuple[list[Any], list[SourceEvent]]:
        assert isinstance(item, SampleBlock)
        i = item.first_index
        if i == self.fail_at:
            raise ValueError(f"block {i}: bad samples")
        frames = [SimpleNamespace(time_s=i + j / 10, rpm=1000.0) for j in range(i % 3)]
        events = (
            [SourceEvent("angle_gap", f"dsp {i}", float(i), end_s=i + 0.5)] if i % 4 == 0 else []
        )
        return frames, events

    def finish(self) -> tuple[list[Any], list[SourceEvent]]:
        self.finished = True
        return [SimpleNamespace(time_s=1e6, rpm=1000.0)], []


class ScriptedEstimator:
    """Every frame used; the estimate is the number of frames so far."""

    def __init__(self) -> None:
        self.stats = SimpleNamespace(used=0, rejected={}, orders_rejected={})

    def update_many(self, frames: list[Any]) -> list[Any]:
        self.stats.used += len(frames)
        return [SimpleNamespace(reason=None, time_s=f.time_s) for f in frames]

    def take_events(self) -> list[SourceEvent]:
        return []

    def estimate(self, final: bool = True) -> int:
        return int(self.stats.used)


class Log:
    """A sink writing down every call."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []

    def start(self, context: Any) -> None:
        self.calls.append(("start",))

    def on_item(self, item: StreamItem) -> None:
        self.calls.append(("item", getattr(item, "first_index", getattr(item, "message", None))))

    def on_event(self, event: SourceEvent) -> None:
        self.calls.append(("event", event.message))

    def on_frame(self, frame: Any, outcome: Any) -> None:
        self.calls.append(("frame", frame.time_s))

    def on_estimate(self, update: Any) -> None:
        self.calls.append(("estimate", update.time_s, update.estimate))

    def on_backlog(self, seconds: float) -> None:
        pass

    def close(self, final: Any) -> None:
        self.calls.append(("close", final))


def _items(n: int) -> list[StreamItem]:
    out: list[StreamItem] = []
    for i in range(n):
        out.append(SampleBlock("accel", i, np.full((1, 4), float(i))))
        if i % 5 == 2:
            out.append(SourceEvent("dropout", f"source {i}", float(i)))
    return out


def _expected(items: list[StreamItem], stop_at: int | None = None) -> list[tuple[Any, ...]]:
    """The calls one thread makes: each item, then its events and frames, then an
    estimate after a block with a used frame (period 0 here), at the end what finish()
    flushed; with ``stop_at``, up to the item of the block that raised."""
    tracker, used = ScriptedTracker(), 0
    calls: list[tuple[Any, ...]] = [("start",)]
    for item in items:
        if isinstance(item, SourceEvent):
            calls += [("item", item.message), ("event", item.message)]
            continue
        assert isinstance(item, SampleBlock)
        calls.append(("item", item.first_index))
        if item.first_index == stop_at:
            return calls
        frames, events = tracker.feed(item)
        calls += [("event", e.message) for e in events]
        calls += [("frame", f.time_s) for f in frames]
        used += len(frames)
        if frames:
            calls.append(("estimate", frames[-1].time_s, used))
    calls += [("frame", 1e6), ("estimate", 1e6, used + 1)]
    return calls


def _run(
    items: list[StreamItem],
    tracker: ScriptedTracker,
    sink: Log,
    error: BaseException | None = None,
    queue_items: int = 64,
    dsp_thread: bool = True,
) -> Any:
    context: Any = SimpleNamespace()
    estimator: Any = ScriptedEstimator()
    pipeline = Pipeline(
        ListSource(items, error),
        tracker,
        estimator,
        [sink],
        context,
        queue_items=queue_items,
        estimate_period_s=0.0,
        dsp_thread=dsp_thread,
    )
    return pipeline.run()


@pytest.mark.parametrize("dsp_thread", [True, False], ids=["dsp thread", "dsp inline"])
def test_sinks_hear_every_call_in_the_order_one_thread_makes(dsp_thread: bool) -> None:
    items = _items(60)
    sink = Log()
    summary = _run(items, ScriptedTracker(), sink, queue_items=2, dsp_thread=dsp_thread)
    final = summary.estimate
    assert sink.calls == [*_expected(items), ("close", final)]
    assert summary.items == len(items)
    assert summary.frames == sum(i % 3 for i in range(60)) + 1


@pytest.mark.parametrize("dsp_thread", [True, False], ids=["dsp thread", "dsp inline"])
def test_a_dsp_error_reaches_the_caller_after_its_item_and_the_sinks_are_closed(
    dsp_thread: bool,
) -> None:
    items = _items(200)
    sink, tracker = Log(), ScriptedTracker(fail_at=37)
    with pytest.raises(ValueError, match="block 37: bad samples"):
        _run(items, tracker, sink, queue_items=4, dsp_thread=dsp_thread)  # reader blocked
    used = sum(i % 3 for i in range(37))
    assert sink.calls == [*_expected(items, stop_at=37), ("close", used)]
    assert not tracker.finished


@pytest.mark.parametrize("dsp_thread", [True, False], ids=["dsp thread", "dsp inline"])
def test_a_source_error_comes_after_every_item_before_it_and_nothing_is_flushed(
    dsp_thread: bool,
) -> None:
    items = _items(30)
    sink, tracker = Log(), ScriptedTracker()
    with pytest.raises(OSError, match="device gone"):
        _run(items, tracker, sink, error=OSError("device gone"), dsp_thread=dsp_thread)
    expected = _expected(items)[:-2]  # all but what finish() would have flushed
    assert sink.calls == [*expected, ("close", sum(i % 3 for i in range(30)))]
    assert not tracker.finished


class ProbedSource(ListSource):
    """A source whose attributes are looked up elsewhere (a proxy): the lookup of
    ``samples_as_recorded`` itself fails."""

    @property
    def samples_as_recorded(self) -> bool:
        raise ConnectionError("proxy: remote source gone")


@pytest.mark.parametrize("dsp_thread", [True, False], ids=["dsp thread", "dsp inline"])
def test_an_error_reading_the_source_s_attributes_ends_the_run_not_hangs_it(
    dsp_thread: bool,
) -> None:
    items = _items(5)
    sink, tracker = Log(), ScriptedTracker()
    pipeline = Pipeline(
        ProbedSource(items),
        tracker,
        ScriptedEstimator(),  # type: ignore[arg-type]
        [sink],
        SimpleNamespace(),  # type: ignore[arg-type]
        estimate_period_s=0.0,
        dsp_thread=dsp_thread,
    )
    # (was: the reader thread died before queueing its end, and run() waited for ever)
    with pytest.raises(ConnectionError, match="remote source gone"):
        pipeline.run()
    assert sink.calls == [("start",), ("close", None)]


class SlowTracker(ScriptedTracker):
    """From block 2 on, a feed that signals it has begun and then computes for a while
    (tens of ms, no sleep); records whether a feed was still running when the run ended."""

    def __init__(self) -> None:
        super().__init__()
        self.begun = threading.Event()
        self.feeding = False

    def feed(self, item: StreamItem) -> tuple[list[Any], list[SourceEvent]]:
        assert isinstance(item, SampleBlock)
        if item.first_index >= 2:
            self.feeding = True
            self.begun.set()
            sum(range(2_000_000))
            self.feeding = False
        return super().feed(item)


class SinkFailingInAFeed(Log):
    """Fails on the first frame, once the dsp thread is inside a feed."""

    def __init__(self, tracker: SlowTracker) -> None:
        super().__init__()
        self.tracker = tracker

    def on_frame(self, frame: Any, outcome: Any) -> None:
        assert self.tracker.begun.wait(timeout=60)
        raise ValueError("sink failed")


def test_a_failed_run_waits_for_the_dsp_thread_to_leave_its_feed() -> None:
    tracker = SlowTracker()
    with pytest.raises(ValueError, match="sink failed"):
        _run(_items(10), tracker, SinkFailingInAFeed(tracker), queue_items=2)
    # nothing feeds the tracker once run() is over (it was: the dsp thread ran on)
    assert not tracker.feeding


class Shared(Log):
    """A sink writing its frame calls, and its block hook if ``prepares``, to a log shared
    with other sinks (under its ``name``)."""

    def __init__(self, shared: list[tuple[Any, ...]], name: str, prepares: bool) -> None:
        super().__init__()
        self.shared, self.name = shared, name
        if prepares:
            self.prepare_frames = self._prepare  # type: ignore[attr-defined]

    def _prepare(self, frames: list[Any]) -> None:
        self.shared.append((self.name, "prepare", tuple(f.time_s for f in frames)))

    def on_frame(self, frame: Any, outcome: Any) -> None:
        self.shared.append((self.name, "frame", frame.time_s))


def test_each_frame_reaches_every_sink_before_the_next_frame() -> None:
    # a sink writing through another (the Foxglove scene through the recorder) keeps its
    # messages beside their frame's only if the frames go to the sinks one at a time;
    # a block's prepare_frames comes before its frames, to the sinks that have it
    shared: list[tuple[Any, ...]] = []
    sinks = [Shared(shared, "recorder", prepares=True), Shared(shared, "scene", prepares=False)]
    pipeline = Pipeline(
        ListSource(_items(12), None), ScriptedTracker(), ScriptedEstimator(), sinks,
        SimpleNamespace(), estimate_period_s=0.0, dsp_thread=False,
    )  # fmt: skip
    pipeline.run()
    expected: list[tuple[Any, ...]] = []
    for i in range(12):
        block = tuple(i + j / 10 for j in range(i % 3))  # ScriptedTracker's frames
        if block:
            expected.append(("recorder", "prepare", block))
        for t in block:
            expected += [("recorder", "frame", t), ("scene", "frame", t)]
    expected += [
        ("recorder", "prepare", (1e6,)),
        ("recorder", "frame", 1e6),
        ("scene", "frame", 1e6),
    ]
    assert shared == expected
