"""source -> dsp -> estimator -> sinks: the source on a thread of its own, the dsp on the
processing thread or (``dsp_thread``) on a third.

A reader thread pulls items from the source into a queue; the dsp tracks
orders and hands each item with the frames it completed to the processing
thread (the caller's), which updates the estimate and feeds the sinks, in the
order one thread would. A live source (CAN bus, paced simulator) gets an
unbounded first queue, so a slow viewer or disk never makes us drop samples:
the backlog is measured and reported instead. A file or unpaced simulator gets
a bounded one (back-pressure keeps memory flat; nothing is lost either way);
the queue between dsp and estimator is always bounded
(:data:`ptinertia.stage_threads.TRACKED_ITEMS`). The backlog is the time from an item's
arrival to the processing thread taking it up, its dsp included.

A dsp thread (issue 24) overlaps the dsp's numpy calls on whole blocks, which
release the GIL, with the estimator's small-matrix numpy, which holds it; measured,
the hand-overs cost more than that gains today (:data:`DSP_THREAD`), so it is off by
default. The tracker depends on nothing the estimator does, so every frame,
estimate and sink call is the same either way. An error in the dsp stage reaches
the processing thread with the item that raised it, after that item's
``on_item``, as it did with one thread.

Samples are rounded to float32 before anything sees them (on the reader thread,
beside the processing): that is what the recorder stores, so a replay of the
recording feeds the dsp stage exactly the same numbers and reproduces every
estimate bit for bit.
"""

from __future__ import annotations

import queue
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from acquisition.stream import Source, SourceEvent, StreamItem
from estimator.result import Estimate, EstimateUpdate
from estimator.streaming import InertiaEstimator
from ptinertia.sinks import RunContext, Sink, prepare_frames, wants_estimates
from ptinertia.stage_threads import (
    FINISHED,
    TRACKED_ITEMS,
    FrameTracker,
    HandOffQueue,
    Reader,
    Tracking,
)

# The dsp on a thread of its own (between the reader and the processing thread) only pays
# when the stages release the GIL for most of their time. Today they hold it for about 75 %
# of a replay's CPU (perf by thread), and the hand-overs cost more than the overlap gains:
# replay of the 60 s 10 x 25.6 kHz log on a quiet 2-core machine, interleaved, 4 runs each:
# 65-78x wall with the dsp on the processing thread, 59-73x on its own (CPU 62-75x against
# 52-64x); with PTINERTIA_NUMBA=1 95-98x against 89-91x, and again once the dsp's sums and
# frame assembly and the estimator's rows were compiled: 144-145x against 137-142x (load 3,
# benchmarks/bench_pipeline.py compiled_chain); after the per-block and per-run Python was
# cut (2026-11-26, load 1.5): replay 151x against 157x, live with recording 86x against 79x
# (under load 5 the thread won, 65-68x against 39-47x: a third busy thread takes a larger
# share of a shared machine, not a gain of the design). So the dsp runs on the processing
# thread; the threaded arrangement stays (tested) for stages that release the GIL.
DSP_THREAD = False
# How long a stopped run waits for the dsp thread to end the item it is in (a 0.5 s block
# takes milliseconds; a wait this long means the dsp hangs, and a stop must not).
DSP_STOP_WAIT_S = 10.0


@dataclass
class RunSummary:
    estimate: Estimate | None
    frames: int
    items: int
    max_backlog_s: float
    interrupted: bool
    max_estimate_latency_s: float = 0.0
    rejected: dict[str, int] = field(default_factory=dict)  # frames rejected, per reason
    orders_rejected: dict[str, int] = field(default_factory=dict)  # (frame, order)s, per reason
    # stretches without crank angle (a tacho or CAN outage): start_s, end_s, message
    gaps: list[dict[str, Any]] = field(default_factory=list)
    # CPU seconds of each thread: "source" (reading, decoding or simulating), and the
    # caller's from start to close, "dsp, estimator and sinks" (or, with a dsp thread,
    # "dsp" and "estimator and sinks"); what bounds a run on two cores is the largest
    # (benchmarks/bench_pipeline.py prints them)
    thread_cpu_s: dict[str, float] = field(default_factory=dict)


class Pipeline:
    """Wire a source, a tracker, the estimator and sinks, and run them to the end.

    Parameters
    ----------
    source : any :class:`acquisition.stream.Source`.
    tracker : the dsp stage.
    estimator : the streaming estimator.
    sinks : recorder, viewer, progress line ... (called in order).
    context : run-wide facts handed to the sinks' ``start``.
    live : the source runs on the wall clock (unbounded queue, backlog reports).
    """

    def __init__(
        self,
        source: Source,
        tracker: FrameTracker,
        estimator: InertiaEstimator,
        sinks: Sequence[Sink],
        context: RunContext,
        live: bool = False,
        queue_items: int = 64,
        estimate_period_s: float | None = None,
        dsp_thread: bool | None = None,
    ) -> None:
        self.source = source
        self.dsp_thread = DSP_THREAD if dsp_thread is None else dsp_thread
        self.tracker = tracker
        self.estimator = estimator
        self.sinks = list(sinks)
        self.context = context
        self.live = live
        self.queue: queue.Queue[Any] = HandOffQueue(maxsize=0 if live else queue_items)
        self.frames = 0
        self.items = 0
        self.max_backlog = 0.0
        self._last_backlog_report = 0.0
        # Publishing the full estimate (covariance, type-B part) costs more than a
        # frame update: do it every estimate_period_s of stream time (deterministic,
        # so a replay publishes the same estimates at the same frames, to the sinks
        # that want them: see _frames).
        # A live run publishes after every used frame (a bench engineer watches it);
        # as fast as possible, every 0.5 s of stream time is plenty (a publish
        # forces the queued frames' rows to be assembled: it is not free).
        self.estimate_period_s = (
            (0.0 if live else 0.5) if estimate_period_s is None else estimate_period_s
        )
        self._last_estimate_t = -float("inf")
        self._published = False
        # wall time from an item's arrival to the estimate it produced being in every sink, s
        self.estimate_latency_max = 0.0
        self.gaps: list[dict[str, Any]] = []

    def _frames(self, frames: list[Any], events: list[SourceEvent]) -> None:
        for event in events:
            if event.kind == "angle_gap":
                self.gaps.append(
                    {"start_s": event.time_s, "end_s": event.end_s, "message": event.message}
                )
            for sink in self.sinks:
                sink.on_event(event)
        if not frames:
            return
        # The frames of one block are estimated together (same decisions as one by one,
        # less numpy overhead); the estimate is published after the block's last used frame.
        for sink in self.sinks:  # (the recorder encodes the block's frames together)
            prepare_frames(sink, frames)
        last_used = None
        for frame, outcome in zip(frames, self.estimator.update_many(frames), strict=True):
            self.frames += 1
            # each frame to every sink in turn: a sink writing through another (the scene
            # through the recorder) keeps its messages beside the frame's in the file
            for sink in self.sinks:
                sink.on_frame(frame, outcome)
            if outcome.reason is None:
                last_used = frame
        for event in self.estimator.take_events():  # an elastic mode confirmed
            for sink in self.sinks:
                sink.on_event(event)
        if last_used is not None and (
            last_used.time_s - self._last_estimate_t >= self.estimate_period_s
        ):
            # The schedule runs whether or not the estimate is computed: once a frame with
            # an unseen motion is queued, every run of the stream must flush at the same
            # frames (InertiaEstimator.flush_timing_matters); until then
            # an estimate no sink wants is skipped (ptinertia.sinks.wants_estimates).
            self._last_estimate_t = last_used.time_s
            if not any(wants_estimates(sink) for sink in self.sinks) and (
                not self.estimator.flush_timing_matters
            ):
                return
            self._published = True
            update = EstimateUpdate(
                last_used.time_s, last_used.rpm, self.estimator.estimate(final=False)
            )
            for sink in self.sinks:  # (computed: every sink gets it)
                sink.on_estimate(update)

    def _backlog(self, enqueued: float) -> None:
        lag = time.monotonic() - enqueued
        self.max_backlog = max(self.max_backlog, lag)
        if self.live and lag > 1.0 and lag > 2 * self._last_backlog_report:
            self._last_backlog_report = lag
            for sink in self.sinks:
                sink.on_backlog(lag)

    def _item(self, enqueued: float, item: StreamItem) -> None:
        self._backlog(enqueued)
        self.items += 1
        for sink in self.sinks:
            sink.on_item(item)

    def run(self) -> RunSummary:
        """Process the whole stream; always closes the source and every sink."""
        reader = Reader(self.source, self.queue)
        tracked: queue.Queue[Any] = queue.Queue(maxsize=TRACKED_ITEMS)
        tracking = Tracking(self.tracker, self.queue, tracked, reader)
        interrupted = False
        error: BaseException | None = None
        final: Estimate | None = None
        cpu0 = time.thread_time()
        for sink in self.sinks:
            sink.start(self.context)
        reader.start()
        if self.dsp_thread:
            tracking.start()
            next_tracked: Callable[[], Any] = tracked.get
        else:  # the dsp on this thread, an item at a time (see DSP_THREAD)
            next_tracked = tracking.step
        try:
            while True:
                enqueued, item, done = next_tracked()
                if isinstance(done, BaseException):
                    if item is not FINISHED:
                        self._item(enqueued, item)  # as before the stage raised
                    raise done
                if item is FINISHED:
                    self._frames(*done)
                    break
                self._item(enqueued, item)
                if isinstance(item, SourceEvent):
                    for sink in self.sinks:
                        sink.on_event(item)
                    continue
                self._frames(*done)
                if self._published:
                    self._published = False
                    lag = time.monotonic() - enqueued
                    self.estimate_latency_max = max(self.estimate_latency_max, lag)
        except KeyboardInterrupt:
            interrupted = True
        except BaseException as err:
            error = err
        finally:
            reader.stop.set()
            tracking.stop.set()
            self.source.close()
            # the dsp thread stops between items: wait for the one it may be in, so that
            # nothing feeds the tracker after run() returns (bounded: never hang a stop)
            if self.dsp_thread:
                tracking.join(timeout=DSP_STOP_WAIT_S)
            final = self.estimator.estimate() if self.estimator.stats.used else None
            close_errors: list[BaseException] = []
            for sink in self.sinks:
                try:
                    sink.close(final)
                except BaseException as err:  # every sink gets its close, even after one fails
                    close_errors.append(err)
            if error is None and close_errors:
                error = close_errors[0]
        if error is not None:
            raise error
        processing = time.thread_time() - cpu0
        return RunSummary(
            final,
            self.frames,
            self.items,
            self.max_backlog,
            interrupted,
            self.estimate_latency_max,
            dict(self.estimator.stats.rejected),
            dict(self.estimator.stats.orders_rejected),
            list(self.gaps),
            {"source": reader.cpu_s, "dsp": tracking.cpu_s, "estimator and sinks": processing}
            if self.dsp_thread
            else {"source": reader.cpu_s, "dsp, estimator and sinks": processing},
        )
