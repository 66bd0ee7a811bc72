"""The order tracker run over stream items, its frames and its events apart
(``dsp.driver.track_items`` yields them interleaved, in stream order), and the synthetic
bench and tracker settings the order-tracker tests share."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from acquisition.stream import SourceEvent, StreamItem, StreamLayout
from dsp.config import OrderTrackerConfig
from dsp.driver import track_items
from dsp.frames import OrderFrame
from dsp.synthetic import Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig

TDC = 84.0  # deg of the synthetic bench's TDC after the wheel's gap


def frames_and_events(
    layout: StreamLayout, items: Iterable[StreamItem], config: OrderTrackerConfig
) -> tuple[list[OrderFrame], list[SourceEvent]]:
    out = list(track_items(layout, items, config))
    frames = [x for x in out if isinstance(x, OrderFrame)]
    return frames, [x for x in out if isinstance(x, SourceEvent)]


def synthetic_bench(seed: int = 3, ramp: Ramp | None = None, **kw: Any) -> SyntheticBench:
    """Three random order contents on a 1500 -> 2500 rpm ramp in 4 s (``dsp.synthetic``)."""
    rng = np.random.default_rng(seed)
    contents = [random_content(rng) for _ in range(3)]
    return SyntheticBench(ramp or Ramp(1500.0, 2500.0, 4.0), contents, tdc_after_gap_deg=TDC, **kw)


def tracker_config(**kw: Any) -> OrderTrackerConfig:
    """Orders 0.5 to 2 on the synthetic bench's wheel."""
    tacho = kw.pop("tacho", TachoConfig(tdc_after_gap_deg=TDC))
    return OrderTrackerConfig(tacho=tacho, orders=(0.5, 1.0, 1.5, 2.0), **kw)


def run_tracker(
    bench: SyntheticBench, items: Iterable[StreamItem], config: OrderTrackerConfig | None = None
) -> tuple[list[OrderFrame], list[SourceEvent]]:
    return frames_and_events(bench.layout, items, config or tracker_config())
