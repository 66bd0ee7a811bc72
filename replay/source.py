"""Replay a recording's raw stream as a :class:`acquisition.stream.Source`.

The items come back exactly as the live dsp stage received them (same blocks,
same order, the same float32-rounded samples), so with unchanged settings the
dsp stage and the estimator reproduce every recorded frame and estimate bit
for bit. ``speed=None`` replays as fast as the consumer takes the items;
``speed=1.0`` paces them to the wall clock (an item is released when the
stream time of its last sample has elapsed), ``speed=10`` ten times faster.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

from acquisition.channels import ChannelNeed, check_channels
from acquisition.stream import (
    EdgeBlock,
    SampleBlock,
    Source,
    SourceError,
    StreamItem,
    StreamLayout,
)
from replay.errors import LogError
from replay.reader import open_log
from replay.recorded_log import ReadReport, RecordedLog


def item_end_time(item: StreamItem, layout: StreamLayout) -> float | None:
    """Stream time at which ``item`` is complete (s), None when it carries no time."""
    if isinstance(item, SampleBlock):
        group = layout.group(item.group)
        return group.t0_s + (item.first_index + item.n_samples - 1) / group.rate_hz
    if isinstance(item, EdgeBlock):
        return float(item.times_s[-1]) if len(item.times_s) else None
    return item.time_s


class McapSource(Source):
    """The raw stream of a recording.

    Parameters
    ----------
    log : a path or an already opened :class:`RecordedLog`.
    speed : None for as fast as possible, else the pace relative to real time (1.0: real time).
    monotonic : callable returning seconds
        The clock the pacing follows (``time.monotonic``; a test's fake clock).
    sleep : callable taking seconds, or None
        How to wait for the next item's time. None (the default) waits on the
        source's stop event, a ``time.sleep`` that :meth:`close` cuts short; a
        test passes its fake clock's. After an injected sleep the replay stops
        if the source was closed meanwhile.
    """

    # The sample blocks hold the recorded float32 values (in float64): the pipeline need not
    # round them to float32 again (ptinertia.stage_threads.as_recorded would give them back unchanged).
    samples_as_recorded = True

    def __init__(
        self,
        log: RecordedLog | str | Path,
        speed: float | None = None,
        *,
        monotonic: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], object] | None = None,
    ) -> None:
        super().__init__()
        if speed is not None and not (speed > 0 and math.isfinite(speed)):
            raise LogError(f"speed: expected a positive factor of real time, got {speed}")
        # the data CRC on a thread of its own, beside the pipeline's set-up: the first item
        # waits for it (replay.integrity.DataCheck)
        self.log = log if isinstance(log, RecordedLog) else open_log(log, check_later=True)
        self.speed = speed
        self._monotonic = monotonic
        self._sleep = sleep
        self._stop = threading.Event()

    @property
    def layout(self) -> StreamLayout:
        return self.log.layout

    @property
    def report(self) -> ReadReport:
        """What was recovered and skipped so far."""
        return self.log.report

    def _iter_items(self) -> Iterator[StreamItem]:
        layout = self.layout
        wall0: float | None = None
        t_first = 0.0
        for item in self.log.items():
            if self.speed is not None:
                t = item_end_time(item, layout)
                if t is not None:
                    if wall0 is None:
                        wall0, t_first = self._monotonic(), t
                    delay = wall0 + (t - t_first) / self.speed - self._monotonic()
                    if delay > 0 and self._wait(delay):
                        return
            if self._stop.is_set():
                return
            yield item

    def _wait(self, seconds: float) -> bool:
        """Wait ``seconds``; True when the source was closed meanwhile."""
        if self._sleep is None:
            return self._stop.wait(seconds)
        self._sleep(seconds)
        return self._stop.is_set()

    def __enter__(self) -> McapSource:
        return self

    def _shutdown(self) -> None:
        # close() comes from the processing thread while the reader thread may be
        # sleeping in the pacing wait: wake it up.
        self._stop.set()


def open_replay(
    path: str | Path, required: Sequence[ChannelNeed] = (), speed: float | None = None
) -> McapSource:
    """A :class:`McapSource`, checked against the channels a consumer needs.

    Parameters
    ----------
    path : the recording.
    required : the channels the estimate needs (the app's
        ``ptinertia.to_acquisition.channel_needs`` of the bench, e.g. a ``--bench``
        override); empty: no check.
    speed : as for :class:`McapSource`.

    Raises
    ------
    LogError
        The file is not a replayable recording.
    SourceError
        A required channel is missing from the recording.
    """
    source = McapSource(path, speed=speed)
    try:
        check_channels(source.layout, required, str(path))
    except SourceError:
        source.log.verify()  # a damaged layout: the CRC's error is the one that says so
        raise
    return source
