"""The streaming source contract every acquisition driver implements.

A source describes its channels once (:class:`StreamLayout`) and then yields
items in time order until it is exhausted or closed:

* :class:`SampleBlock` -- consecutive samples of one *sample group* (channels
  sharing one rate and one time grid). Sample ``k`` of a group lies at
  ``group.t0_s + k / group.rate_hz``; a block names its first index, so a gap
  (lost CAN frames, a dropped DAQ buffer) is an index jump, never shifted data.
* :class:`EdgeBlock` -- tacho edge timestamps from a counter input (seconds,
  float64: at one hour the resolution is still below a nanosecond).
* :class:`SourceEvent` -- something the user must hear about (lost frames,
  bus-off, NaN samples); the stream goes on.

Sources are context managers; ``close()`` is idempotent. Drivers override only
``_iter_items`` (python-can style: the base class does the bookkeeping once).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np


class SourceError(ValueError):
    """A source cannot be opened or read (bad file, missing channel, dead bus)."""


@dataclass(frozen=True)
class ChannelSpec:
    """One sampled channel: its name and physical unit (``"m/s^2"``, ``"rpm"``, ``"bar"``, ``"V"``)."""

    name: str
    unit: str


@dataclass(frozen=True)
class SampleGroup:
    """Channels sampled together on one time grid ``t_k = t0_s + k / rate_hz``."""

    name: str
    rate_hz: float
    channels: tuple[ChannelSpec, ...]
    t0_s: float = 0.0

    def index_of(self, channel: str) -> int:
        for i, spec in enumerate(self.channels):
            if spec.name == channel:
                return i
        raise KeyError(channel)


@dataclass(frozen=True)
class StreamLayout:
    """Everything a consumer needs to know before the first block arrives.

    ``edge_channels`` are tacho counter inputs delivering edge timestamps.
    ``metadata`` carries source-specific facts (the bench file text, the
    simulated truth) as plain JSON-serialisable values.
    """

    groups: tuple[SampleGroup, ...]
    edge_channels: tuple[str, ...] = ()
    metadata: dict[str, Any] = field(default_factory=dict)

    def group(self, name: str) -> SampleGroup:
        for g in self.groups:
            if g.name == name:
                return g
        raise KeyError(name)

    def find_channel(self, channel: str) -> tuple[SampleGroup, int]:
        """The group holding ``channel`` and its row index in that group's blocks."""
        for g in self.groups:
            for i, spec in enumerate(g.channels):
                if spec.name == channel:
                    return g, i
        raise SourceError(
            f"channel {channel!r} not in the source; it has: "
            + ", ".join(c.name for g in self.groups for c in g.channels)
        )

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for g in self.groups for c in g.channels)


@dataclass(frozen=True)
class SampleBlock:
    """Consecutive samples of one group.

    Attributes
    ----------
    group : str
        Name of the :class:`SampleGroup`.
    first_index : int
        Grid index of ``data[:, 0]`` on the group's time grid.
    data : (n_channels, n_samples) float64
        In the group's channel order and units. NaN marks a sample known bad.
    """

    group: str
    first_index: int
    data: np.ndarray

    @property
    def n_samples(self) -> int:
        return int(self.data.shape[1])


@dataclass(frozen=True)
class EdgeBlock:
    """Tacho edge times (s, float64, increasing) of one counter-input channel."""

    channel: str
    times_s: np.ndarray


@dataclass(frozen=True)
class SourceEvent:
    """A reportable event: ``kind`` is a short tag (``"gap"``, ``"bus_off"``), ``message`` one line.

    ``end_s``: where the event spans time (an outage), its end (``time_s`` its start).
    """

    kind: str
    message: str
    time_s: float | None = None
    count: int = 1
    end_s: float | None = None


StreamItem = SampleBlock | EdgeBlock | SourceEvent


class Source(ABC):
    """Base class of every acquisition driver (simulated bench, files, CAN)."""

    def __init__(self) -> None:
        self._closed = False

    @property
    @abstractmethod
    def layout(self) -> StreamLayout:
        """Channels and rates; available right after construction."""

    @abstractmethod
    def _iter_items(self) -> Iterator[StreamItem]:
        """Driver hook: yield items in non-decreasing time order."""

    def __iter__(self) -> Iterator[StreamItem]:
        for item in self._iter_items():
            if self._closed:
                return
            yield item

    def close(self) -> None:
        """Release the driver's resources. Safe to call more than once."""
        if not self._closed:
            self._closed = True
            self._shutdown()

    def _shutdown(self) -> None:
        """Driver hook for releasing resources (files, buses, threads)."""

    def __enter__(self) -> Source:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
