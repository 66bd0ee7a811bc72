"""The pipeline's stage threads (:mod:`ptinertia.pipeline`): the reader, which pulls a
source's items into a queue rounded as recorded, and the dsp stage on a thread of its own;
the items they hand on and the sentinels that end a stream.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Iterable
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from acquisition.stream import SampleBlock, SourceEvent, StreamItem

END = object()
FINISHED = object()  # the tracker's finish(): what it flushed follows

# Items between the dsp and the processing thread: enough to ride out an estimate's
# publication (a few blocks' worth of dsp), few enough that memory stays flat (a 0.5 s
# block of 10 channels at 25.6 kHz is 1 MB).
TRACKED_ITEMS = 4


class FrameTracker(Protocol):
    """The dsp stage as the pipeline drives it, perhaps on a thread of its own
    (``Pipeline(dsp_thread=True)``): it must leave the items it is fed as they are (the
    sinks get them after it) and not write again into arrays of the frames it returned
    (the estimator reads them while it goes on)."""

    def feed(self, item: StreamItem) -> tuple[list[Any], list[SourceEvent]]:
        """Process one item; return the frames and events it completed."""
        ...

    def finish(self) -> tuple[list[Any], list[SourceEvent]]:
        """End of stream: flush what can still be completed."""
        ...


def as_recorded(item: StreamItem) -> StreamItem:
    """The item as the recorder stores it (samples rounded to float32), its samples a new
    read-only array: nothing writes to them again, so the recorder may cast them later, on
    its writer thread (replay.stream_codec.encode_samples_late)."""
    if isinstance(item, SampleBlock) and item.data.dtype != np.float32:
        data = item.data.astype(np.float32).astype(np.float64)
        data.flags.writeable = False
        return replace(item, data=data)
    return item


def put_unless_stopped(q: queue.Queue[Any], value: Any, stop: threading.Event) -> bool:
    """Put ``value`` on a bounded queue unless ``stop`` is set first; True when it was put."""
    while not stop.is_set():
        try:
            q.put(value, timeout=0.1)
            return True
        except queue.Full:
            continue
    return False


class Reader(threading.Thread):
    """Pulls items from the source into the queue, rounded as recorded (:func:`as_recorded`),
    until exhausted or stopped."""

    def __init__(self, items: Iterable[StreamItem], q: queue.Queue[Any]) -> None:
        super().__init__(name="ptinertia-acquisition", daemon=True)
        self.items = items
        self.q = q
        self.error: BaseException | None = None
        self.stop = threading.Event()
        self.cpu_s = 0.0  # CPU seconds of this thread, set before its end is queued

    def run(self) -> None:
        # a recording's samples are its float32 values already: rounding them again would
        # cost two casts per block and change nothing (replay.source.McapSource)
        try:
            recorded = getattr(self.items, "samples_as_recorded", False) is True
            for item in self.items:
                arrived = time.monotonic()
                # the float32 rounding here, not on the processing thread: its casts release
                # the GIL, so it runs beside the dsp on the other core (bit for bit the same)
                if not recorded:
                    item = as_recorded(item)
                if not put_unless_stopped(self.q, (arrived, item), self.stop):
                    break
        except BaseException as err:  # handed to the processing thread, re-raised there
            self.error = err
        finally:  # unless stopped: then nobody reads on, and a full queue would block for ever
            self.cpu_s = time.thread_time()
            put_unless_stopped(self.q, (time.monotonic(), END), self.stop)


class Tracking(threading.Thread):
    """The dsp stage on its own thread: takes the reader's ``(arrival, item)`` and puts
    ``(arrival, item, done)`` on ``out``, ``done`` being what ``tracker.feed`` returned
    (None for a source event, the exception if it raised); at the end of the stream
    ``(arrival, FINISHED, done)`` with ``tracker.finish()``'s (or the reader's error),
    then nothing more. Stops early when ``stop`` is set."""

    def __init__(
        self,
        tracker: FrameTracker,
        items: queue.Queue[Any],
        out: queue.Queue[Any],
        reader: Reader,
    ) -> None:
        super().__init__(name="ptinertia-dsp", daemon=True)
        self.tracker = tracker
        self.items = items
        self.out = out
        self.reader = reader
        self.stop = threading.Event()
        self.cpu_s = 0.0  # CPU seconds of this thread, set before the end of the stream is queued

    def step(self, timeout: float | None = None) -> tuple[float, Any, Any] | None:
        """Take one item from the reader and run the dsp on it: ``(arrival, item, done)``
        as put on ``out`` (None when nothing came within ``timeout`` s)."""
        done: Any
        try:
            arrived, item = self.items.get(timeout=timeout)
        except queue.Empty:
            return None
        if item is END:
            arrived, item = time.monotonic(), FINISHED
        try:
            if item is FINISHED:
                error = self.reader.error  # set before the reader put its end
                done = error if error is not None else self.tracker.finish()
            elif isinstance(item, SourceEvent):
                done = None
            else:
                done = self.tracker.feed(item)
        except BaseException as err:  # handed on with its item, re-raised there
            done = err
        return arrived, item, done

    def run(self) -> None:
        while True:
            got = self.step(timeout=0.1)
            if got is None:
                if self.stop.is_set():
                    return
                continue
            self.cpu_s = time.thread_time()
            if not put_unless_stopped(self.out, got, self.stop):
                return
            if got[1] is FINISHED or isinstance(got[2], BaseException):
                return
