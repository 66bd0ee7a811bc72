"""Drive an order tracker from a :class:`acquisition.stream.Source`.

``for out in track_source(source, config)`` yields, in stream order, every
:class:`~dsp.frames.OrderFrame` and every :class:`~acquisition.stream.SourceEvent`
(the source's own events passed through, and the tracker's: tacho sync and
loss, dropped samples, cam mismatch). Frames a stream item completes come
after that item's events.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

from acquisition.stream import Source, SourceEvent, StreamItem, StreamLayout
from dsp.config import OrderTrackerConfig
from dsp.frames import OrderFrame
from dsp.orders import OrderTracker


def track_items(
    layout: StreamLayout, items: Iterable[StreamItem], config: OrderTrackerConfig
) -> Iterator[OrderFrame | SourceEvent]:
    """Frames and events of ``items`` (any iterable of stream items described by ``layout``)."""
    tracker = OrderTracker.from_layout(layout, config)
    for item in items:
        frames, events = tracker.process(item)
        yield from events
        yield from frames


def track_source(source: Source, config: OrderTrackerConfig) -> Iterator[OrderFrame | SourceEvent]:
    """Frames and events of a whole source; the configuration is checked before the first item."""
    return track_items(source.layout, source, config)
