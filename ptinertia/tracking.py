"""From the bench file to the dsp stage (``dsp`` knows nothing of bench files)."""

from __future__ import annotations

from typing import Any

from acquisition.stream import SourceEvent, StreamItem, StreamLayout
from dsp.config import OrderTrackerConfig
from dsp.orders import OrderTracker
from dsp.tacho import TachoConfig
from ptinertia.config import Bench


def tracker_config(
    bench: Bench, orders: tuple[float, ...] | None = None, spectrum_channel: str | None = None
) -> OrderTrackerConfig:
    """The dsp configuration the bench file asks for (``orders`` overrides ``[dsp] orders``;
    ``spectrum_channel``: a channel tracked at every half order up to
    ``[estimator] pressure_max_order``, the cylinder pressure the gas torque comes from)."""
    t = bench.tacho
    tacho = TachoConfig(
        kind=t.kind,
        teeth=t.teeth,
        missing=t.missing,
        delivery=t.delivery,
        channel=t.channel,
        tdc_after_gap_deg=t.tdc_after_gap_deg,
        tdc_offset_deg=t.tdc_offset_deg,
        rpm_channel=t.rpm_channel,
        phase_reference=t.phase_reference,
        cam_channel=t.cam_channel,
        cam_angle_deg=t.cam_angle_deg,
        pressure_channel=t.pressure_channel,
    )
    channels = tuple(c for s in bench.sensors for c in s.channels if c)
    fpr = bench.dsp.frames_per_rev
    if fpr != int(fpr):
        from dsp.errors import DspConfigError

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
