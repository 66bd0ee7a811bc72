"""The pipeline's stage threads (:mod:`ptinertia.pipeline`): the reader, which pulls a
source's items into a queue rounded as recorded, and the dsp stage on a thread of its own;
the items they hand on and the sentinels that end a stream.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterable
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


class _WhenDrained(threading.Condition):
    """A queue's ``not_full`` condition whose ``notify`` (the consumer's, after each get)
    wakes the producer only once ``drained()`` says so."""

    def __init__(self, lock: threading.Lock, drained: Callable[[], bool]) -> None:
        super().__init__(lock)
        self._drained = drained
        self._all = False

    def notify(self, n: int = 1) -> None:
        if self._all or self._drained():
            super().notify(n)

    def notify_all(self) -> None:
        # (every waiter, drained or not: Python 3.13's Queue.shutdown wakes them so)
        self._all = True
        try:
            super().notify_all()
        finally:
            self._all = False


class HandOffQueue(queue.Queue[Any]):
    """A bounded queue whose consumer wakes a producer blocked on it being full only once it
    has taken half of it: the producer then refills it in one go, not an item a wake.

    Why: the reader runs ahead of the processing thread, so with ``queue.Queue`` every item
    taken woke it (a futex call on the processing thread, then the reader asking for the GIL
    to decode one item). Measured (issue 24, the compiled replay of the 60 s log): swapped in
    by hand, 12-14 interleaved runs, load 1: best 0.194 -> 0.191 s and 0.224 -> 0.215 s,
    medians 2-3 % less; as built, three interleaved pairs of best-of-5 replays, load 0.8:
    0.245-0.257 -> 0.219-0.231 s. Unbounded (``maxsize`` 0): as ``queue.Queue``."""

    def __init__(self, maxsize: int = 0) -> None:
        super().__init__(maxsize)
        self.not_full = _WhenDrained(self.mutex, self._drained)

    def _drained(self) -> bool:
        return self.maxsize <= 0 or self._qsize() <= self.maxsize // 2


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
