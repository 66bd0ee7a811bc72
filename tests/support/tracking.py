"""The order tracker run over stream items, its frames and its events apart
(``dsp.driver.track_items`` yields them interleaved, in stream order)."""

from __future__ import annotations

from collections.abc import Iterable

from acquisition.stream import SourceEvent, StreamItem, StreamLayout
from dsp.config import OrderTrackerConfig
from dsp.driver import track_items
from dsp.frames import OrderFrame


def frames_and_events(
    layout: StreamLayout, items: Iterable[StreamItem], config: OrderTrackerConfig
) -> tuple[list[OrderFrame], list[SourceEvent]]:
    out = list(track_items(layout, items, config))
    frames = [x for x in out if isinstance(x, OrderFrame)]
    return frames, [x for x in out if isinstance(x, SourceEvent)]
