"""Windowed streaming of recorded files: the chunk-to-block machinery every file source shares.

A file source (CSV, MDF) parses its files in chunks; :class:`SampleStream` cuts
one sample group's chunks into grid-indexed blocks (a jump is a ``"gap"``
event, a time that does not increase or lies off the grid is a
:class:`SourceError`, NaN samples are reported once per channel),
:class:`EdgeStream` does the same for tacho edge times, and
:class:`WindowedFileSource` merges them into time windows of ``block_s``
seconds, so an hour-long recording is never held in memory.

Its own module because it knows no file format: :mod:`acquisition.files.csvfile`
and :mod:`acquisition.files.mdf` each only supply the chunks.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from acquisition.stream import (
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SampleGroup,
    Source,
    SourceError,
    SourceEvent,
    StreamItem,
    StreamLayout,
)

# (first row number in the file, times (n,) s, data (n_ch, n)); edges have data None
Chunk = tuple[int, np.ndarray, np.ndarray | None]

OFF_GRID_TOLERANCE = 0.25  # of a sample period: rounding of written times stays far below


def infer_rate(times: np.ndarray, where: str) -> float:
    """Sample rate (Hz) from the first timestamps of a group.

    Least-squares slope of time against grid index, on a growing prefix so that
    times written with few decimals (a quantised median step) and gaps do not
    bias it; samples off the current grid are left out (reported later).
    Snapped to a whole Hz when within 10 ppm: DAQ rates are whole numbers, and
    an unsnapped rate would drift off the grid in a long file.
    """
    if times.size < 2:
        raise SourceError(
            f"{where}: need at least 2 samples to know the sample rate, got {times.size}"
        )
    period = float(np.median(np.diff(times)))
    if not period > 0:
        raise SourceError(f"{where}: time_s must increase, median step is {period:g} s")
    m = 16
    while True:
        t = times[: min(m, times.size)] - times[0]
        k = np.round(t / period)
        near = np.abs(t - k * period) < OFF_GRID_TOLERANCE * period
        kc = k[near] - k[near].mean()
        denom = float(np.dot(kc, kc))
        if denom > 0:
            period = float(np.dot(kc, t[near] - t[near].mean()) / denom)
        if m >= times.size:
            break
        m *= 4
    rate = 1.0 / period
    if abs(rate - round(rate)) <= 1e-5 * rate:
        rate = float(round(rate))
    return rate


def _check_increasing(
    times: np.ndarray,
    row0: int,
    previous: float | None,
    what: str,
    noun: str,
    row_word: str = "row",
) -> None:
    """Finite and strictly increasing, also across the chunk boundary (``previous``)."""
    bad = np.flatnonzero(~np.isfinite(times))
    if bad.size:
        raise SourceError(
            f"{what} at {row_word} {row0 + bad[0]} is {float(times[bad[0]])}, expected a time in s"
        )
    seq = times if previous is None else np.concatenate([[previous], times])
    back = np.flatnonzero(np.diff(seq) <= 0)
    if back.size:
        b = int(back[0])
        row = row0 + b + (0 if previous is not None else 1)
        raise SourceError(
            f"{what} at {row_word} {row} is {float(seq[b + 1])!r} s, "
            f"not after the previous {float(seq[b])!r} s "
            f"({noun} must increase)"
        )


def _matrix(data: np.ndarray | None, where: str) -> np.ndarray:
    if data is None:
        raise SourceError(f"{where}: no channel columns after the time")
    return data


class SampleStream:
    """One sample group read chunk by chunk, cut into grid-indexed blocks by time."""

    def __init__(
        self,
        name: str,
        channels: Sequence[ChannelSpec],
        where: str,
        chunks: Iterator[Chunk],
        row_word: str = "row",
    ) -> None:
        self.where = where
        # what the chunks' row numbers count: a CSV "line", an MDF "record"
        self.row_word = row_word
        self._chunks = chunks
        first = next(chunks, None)
        if first is None:
            raise SourceError(f"{where}: no samples")
        # the rate needs a few samples: pull chunks until there are enough
        row0, times, data = first[0], first[1], _matrix(first[2], where)
        while times.size < 1000:
            more = next(chunks, None)
            if more is None:
                break
            times = np.concatenate([times, more[1]])
            data = np.concatenate([data, _matrix(more[2], where)], axis=1)
        self._check_times(times, row0, None)
        self.group = SampleGroup(name, infer_rate(times, where), tuple(channels), float(times[0]))
        self._row0, self._times, self._data = row0, times, data
        self._last_index = -1
        self._last_time: float | None = None
        self._nan_reported: set[int] = set()

    def _check_times(self, times: np.ndarray, row0: int, previous: float | None) -> None:
        _check_increasing(times, row0, previous, f"{self.where}: time_s", "time", self.row_word)

    def next_time(self) -> float | None:
        """Time of the next unread sample, or None at the end."""
        self._fill(-math.inf)
        return float(self._times[0]) if self._times.size else None

    def _fill(self, t_end: float) -> None:
        while self._times.size == 0 or self._times[-1] < t_end:
            more = next(self._chunks, None)
            if more is None:
                return
            row0, times = more[0], more[1]
            last = self._last_time if self._times.size == 0 else float(self._times[-1])
            self._check_times(times, row0, last)
            if self._times.size == 0:
                self._row0 = row0
            self._times = np.concatenate([self._times, times])
            self._data = np.concatenate([self._data, _matrix(more[2], self.where)], axis=1)

    def take_until(self, t_end: float) -> list[StreamItem]:
        """Blocks (split at gaps) and events for the samples with ``t < t_end``."""
        self._fill(t_end)
        n = int(np.searchsorted(self._times, t_end, side="left"))
        if n == 0:
            return []
        times, data, row0 = self._times[:n], self._data[:, :n], self._row0
        self._times, self._data, self._row0 = self._times[n:], self._data[:, n:], row0 + n
        self._last_time = float(times[-1])
        g = self.group
        exact = (times - g.t0_s) * g.rate_hz
        idx = np.round(exact).astype(np.int64)
        off = np.flatnonzero(np.abs(exact - idx) > OFF_GRID_TOLERANCE)
        if off.size:
            i = off[0]
            raise SourceError(
                f"{self.where}: time_s at {self.row_word} {row0 + i} is {float(times[i])!r} s, "
                f"off the {g.rate_hz:g} Hz sampling grid by {(exact[i] - idx[i]):+.2f} samples "
                "(expected t0 + k / rate)"
            )
        seq = np.concatenate([[self._last_index], idx])
        if np.any(np.diff(seq) <= 0):
            i = int(np.flatnonzero(np.diff(seq) <= 0)[0])
            raise SourceError(
                f"{self.where}: time_s at {self.row_word} {row0 + i} is {float(times[i])!r} s, "
                f"on the same {g.rate_hz:g} Hz grid point as the previous sample "
                "(expected one sample per period)"
            )
        items: list[StreamItem] = []
        jumps = np.flatnonzero(np.diff(seq) > 1)
        for j in jumps:
            missing = int(seq[j + 1] - seq[j] - 1)
            items.append(
                SourceEvent(
                    "gap",
                    f"{self.where}: {missing} samples missing before t = {times[j]:.6f} s",
                    float(times[j]),
                    missing,
                )
            )
        cuts = [0, *jumps.tolist(), n]
        for a, b in itertools.pairwise(cuts):
            if b > a:
                items.append(SampleBlock(g.name, int(idx[a]), np.ascontiguousarray(data[:, a:b])))
        self._last_index = int(idx[-1])
        nan_rows = np.isnan(data).any(axis=1)
        for c in np.flatnonzero(nan_rows):
            if c not in self._nan_reported:
                self._nan_reported.add(int(c))
                first = int(np.flatnonzero(np.isnan(data[c]))[0])
                items.append(
                    SourceEvent(
                        "nan",
                        f"{self.where}: channel {g.channels[c].name!r} has NaN samples "
                        f"from t = {times[first]:.6f} s",
                        float(times[first]),
                    )
                )
        return items


class EdgeStream:
    """Edge times of one counter channel read chunk by chunk."""

    def __init__(
        self, channel: str, where: str, chunks: Iterator[Chunk], row_word: str = "row"
    ) -> None:
        self.channel = channel
        self.row_word = row_word
        self.where = where
        self._chunks = chunks
        self._times = np.zeros(0)
        self._row0 = 0
        self._last: float | None = None

    def _fill(self, t_end: float) -> None:
        while self._times.size == 0 or self._times[-1] < t_end:
            more = next(self._chunks, None)
            if more is None:
                return
            row0, times, _ = more
            previous = float(self._times[-1]) if self._times.size else self._last
            what = f"{self.where}: {self.channel} edge"
            _check_increasing(times, row0, previous, what, "edge times", self.row_word)
            if self._times.size == 0:
                self._row0 = row0
            self._times = np.concatenate([self._times, times])

    def next_time(self) -> float | None:
        self._fill(-math.inf)
        return float(self._times[0]) if self._times.size else None

    def take_until(self, t_end: float) -> list[StreamItem]:
        self._fill(t_end)
        n = int(np.searchsorted(self._times, t_end, side="left"))
        if n == 0:
            return []
        out, self._times = self._times[:n], self._times[n:]
        self._row0 += n
        self._last = float(out[-1])
        return [EdgeBlock(self.channel, out)]


class WindowedFileSource(Source):
    """Merge sample and edge streams into time-ordered windows of ``block_s`` seconds."""

    def __init__(
        self,
        samples: Sequence[SampleStream],
        edges: Sequence[EdgeStream],
        metadata: dict[str, Any],
        block_s: float = 0.1,
    ) -> None:
        super().__init__()
        if not block_s > 0:
            raise SourceError(
                f"block_s: expected a positive block length in seconds, got {block_s}"
            )
        names = [s.group.name for s in samples]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise SourceError(f"sample group names used twice: {sorted(dup)}")
        channels = [c.name for s in samples for c in s.group.channels] + [e.channel for e in edges]
        dup = {c for c in channels if channels.count(c) > 1}
        if dup:
            raise SourceError(f"channel names used twice across the files: {sorted(dup)}")
        self._samples = list(samples)
        self._edges = list(edges)
        self.block_s = float(block_s)
        self._layout = StreamLayout(
            tuple(s.group for s in samples), tuple(e.channel for e in edges), dict(metadata)
        )

    @property
    def layout(self) -> StreamLayout:
        return self._layout

    def _iter_items(self) -> Iterator[StreamItem]:
        streams: list[SampleStream | EdgeStream] = [*self._samples, *self._edges]
        starts = [t for t in (s.next_time() for s in streams) if t is not None]
        if not starts:
            return
        origin = min(starts)
        k = 0
        while True:
            nxt = [t for t in (s.next_time() for s in streams) if t is not None]
            if not nxt:
                return
            # skip empty windows (a long pause in every file) in one step
            k = max(k, math.floor((min(nxt) - origin) / self.block_s))
            t_end = origin + (k + 1) * self.block_s
            items: list[tuple[float, int, StreamItem]] = []
            for order, s in enumerate(streams):
                for item in s.take_until(t_end):
                    items.append((_start_time(item, self._layout), order, item))
            items.sort(key=lambda it: (it[0], it[1]))
            for _, _, item in items:
                yield item
            k += 1


def _start_time(item: StreamItem, layout: StreamLayout) -> float:
    if isinstance(item, SampleBlock):
        g = layout.group(item.group)
        return g.t0_s + item.first_index / g.rate_hz
    if isinstance(item, EdgeBlock):
        return float(item.times_s[0])
    return item.time_s if item.time_s is not None else -math.inf
