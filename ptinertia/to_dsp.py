"""From the bench file to the dsp stage (``dsp`` knows nothing of bench files)."""

from __future__ import annotations

import dataclasses
from typing import Any

from acquisition.stream import SourceEvent, StreamItem, StreamLayout
from dsp.config import OrderTrackerConfig
from dsp.errors import DspConfigError
from dsp.orders import OrderTracker
from dsp.tacho import TachoConfig
from ptinertia.config import Bench, Tacho

# the [tacho] keys the tracker reads, by name; the acquisition's own (sample_rate_hz,
# rpm_rate_hz) stay behind, and the tracker's thresholds keep their defaults
_TRACKER_TACHO_KEYS = frozenset(f.name for f in dataclasses.fields(TachoConfig)) & set(
    Tacho.model_fields
)


def tacho_config(tacho: Tacho) -> TachoConfig:
    """The tracker's tacho settings of a ``[tacho]`` table: the keys both share by name."""
    return TachoConfig(**tacho.model_dump(include=set(_TRACKER_TACHO_KEYS)))


def tracker_config(
    bench: Bench, orders: tuple[float, ...] | None = None, spectrum_channel: str | None = None
) -> OrderTrackerConfig:
    """The dsp configuration the bench file asks for (``orders`` overrides ``[dsp] orders``;
    ``spectrum_channel``: a channel tracked at every half order up to
    ``[estimator] pressure_max_order``, the cylinder pressure the gas torque comes from)."""
    tacho = tacho_config(bench.tacho)
    channels = tuple(c for s in bench.sensors for c in s.channels if c)
    fpr = bench.dsp.frames_per_rev
    if fpr != int(fpr):
        raise DspConfigError(f"[dsp] frames_per_rev: expected a whole number, got {fpr}")
    return OrderTrackerConfig(
        tacho=tacho,
        orders=tuple(orders if orders is not None else bench.dsp.orders),
        channels=channels,
        frames_per_rev=int(fpr),
        rpm_min=bench.dsp.rpm_min,
        rpm_max=bench.dsp.rpm_max,
        spectrum_channel=spectrum_channel,
        spectrum_max_order=bench.estimator.pressure_max_order,
    )


class BenchTracker:
    """The pipeline's :class:`~ptinertia.pipeline.FrameTracker` over :class:`dsp.orders.OrderTracker`."""

    def __init__(self, layout: StreamLayout, config: OrderTrackerConfig) -> None:
        self.tracker = OrderTracker.from_layout(layout, config)
        self.config = config

    def feed(self, item: StreamItem) -> tuple[list[Any], list[SourceEvent]]:
        return self.tracker.process(item)

    def finish(self) -> tuple[list[Any], list[SourceEvent]]:
        # A window that never saw its last revolution cannot be completed: nothing to flush.
        return [], []

    def describe(self) -> dict[str, Any]:
        return self.tracker.describe()
