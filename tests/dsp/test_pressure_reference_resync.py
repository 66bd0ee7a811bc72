"""The pressure reference after a tacho outage: the wheel's new run is a chain of its own,
whose 720 deg cycle the cylinder pressure must decide again (dsp.pressure_votes skips the
votes only while every chain is decided)."""

from __future__ import annotations

import numpy as np

from acquisition.stream import EdgeBlock
from dsp.config import OrderTrackerConfig
from dsp.driver import track_items
from dsp.frames import OrderFrame
from dsp.synthetic import Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig


def test_the_cycle_is_decided_again_after_a_tacho_outage() -> None:
    """0.9 s without tacho edges at 3000 rpm, the pressure as the phase reference: the
    frames before the outage and from 0.6 s after it are decided (none flagged
    cycle_ambiguous), the run after the outage as well as the first."""
    rng = np.random.default_rng(5)
    contents = [random_content(rng) for _ in range(3)]
    bench = SyntheticBench(
        Ramp(3000.0, 3000.0, 4.0), contents, tdc_after_gap_deg=84.0, pressure=True
    )
    config = OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=84.0, phase_reference="pressure"),
        orders=(0.5, 1.0, 1.5, 2.0),
        spectrum_channel="a1",
        frames_per_rev=2,
    )
    items = [
        EdgeBlock(i.channel, i.times_s[(i.times_s < 1.0) | (i.times_s >= 1.9)])
        if isinstance(i, EdgeBlock)
        else i
        for i in bench.items(4.0, block_s=0.04, rng_blocks=np.random.default_rng(2))
    ]
    frames = [x for x in track_items(bench.layout, items, config) if isinstance(x, OrderFrame)]
    before = [f for f in frames if 0.5 < f.time_s < 0.95]
    after = [f for f in frames if f.time_s > 2.5]
    assert len(before) > 30 and len(after) > 100
    assert not any("cycle_ambiguous" in f.flags for f in before + after)
