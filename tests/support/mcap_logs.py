"""Synthetic streams, frames and outcomes recorded to MCAP, shared by the replay and dsp tests.

:class:`FakeClock` stands in for ``time.monotonic`` and ``time.sleep`` where the
recorder and the paced replay source take a clock: the tests never sleep.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from acquisition.stream import (
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SampleGroup,
    SourceEvent,
    StreamItem,
    StreamLayout,
)
from dsp.frames import OrderFrame
from estimator.outcome import FrameOutcome
from replay.recorder import McapRecorder
from replay.recording_head import RecordingInfo

BENCH_TEXT = '[powertrain]\nname = "synthetic"\n'


DBC = b'VERSION ""\nBO_ 256 ACC: 64 Vector__XXX\n'


TRUTH = {"inertia_kgm2": {"Ixx": 12.5, "Iyy": 20.25}, "cog_m": [0.1, -0.02, 0.3], "mass_kg": 150.0}


class FakeClock:
    """A monotonic clock that moves only when slept on or advanced; it remembers the sleeps."""

    def __init__(self, start_s: float = 1000.0) -> None:
        self.now_s = start_s
        self.sleeps: list[float] = []

    def monotonic(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now_s += seconds

    def advance(self, seconds: float) -> None:
        self.now_s += seconds


def synthetic_layout(n_ch: int = 4, rate_hz: float = 2560.0) -> StreamLayout:
    acc = SampleGroup("acc", rate_hz, tuple(ChannelSpec(f"s{i}", "m/s^2") for i in range(n_ch)))
    slow = SampleGroup("slow", rate_hz / 16, (ChannelSpec("rpm", "rpm"),), t0_s=0.25)
    return StreamLayout((acc, slow), ("tacho",), {"truth": TRUTH, "note": "synthetic"})


def synthetic_items(
    layout: StreamLayout, seconds: float, seed: int = 0, min_block: int = 1
) -> list[StreamItem]:
    """Items in time order: random-length blocks of both groups, tacho edges, two events."""
    rng = np.random.default_rng(seed)
    acc, slow = layout.groups
    items: list[StreamItem] = []
    n_acc = int(seconds * acc.rate_hz)
    i = j = 0
    edge_t = 0.0
    while i < n_acc:
        n = min(n_acc - i, int(rng.integers(min_block, int(0.15 * acc.rate_hz))))
        data = rng.standard_normal((len(acc.channels), n)) * 30.0
        if i == 0 and n > 3:
            data[1, 3] = np.nan  # a sample known bad must survive the trip
        items.append(SampleBlock("acc", i, data))
        i += n
        t_end = i / acc.rate_hz
        m = int((t_end - slow.t0_s) * slow.rate_hz) - j
        if m > 0:
            items.append(SampleBlock("slow", j, 3000.0 + rng.standard_normal((1, m))))
            j += m
        edges = []
        while edge_t + 0.02 < t_end:
            edge_t += 0.02 + 1e-4 * rng.random()
            edges.append(edge_t)
        items.append(EdgeBlock("tacho", np.array(edges)))  # sometimes empty
        if len(items) in (7, 8):
            items.append(SourceEvent("gap", f"lost {len(items)} frames", t_end, 2))
    items.append(SourceEvent("bus_off", "no time on this one", None, 1))
    return items


def rounded(item: StreamItem) -> StreamItem:
    """What a recording must give back: samples rounded to float32, everything else as is."""
    if isinstance(item, SampleBlock):
        return SampleBlock(item.group, item.first_index, item.data.astype(np.float32).astype(float))
    return item


def assert_same_items(got: Sequence[StreamItem], want: Sequence[StreamItem]) -> None:
    assert len(got) == len(want)
    for k, (a, b) in enumerate(zip(got, want, strict=True)):
        b = rounded(b)
        assert type(a) is type(b), k
        if isinstance(a, SampleBlock):
            assert isinstance(b, SampleBlock)
            assert (a.group, a.first_index) == (b.group, b.first_index), k
            assert a.data.dtype == np.float64
            np.testing.assert_array_equal(a.data, b.data)  # NaN == NaN here, bits otherwise
        elif isinstance(a, EdgeBlock):
            assert isinstance(b, EdgeBlock)
            assert a.channel == b.channel
            assert a.times_s.tobytes() == b.times_s.tobytes(), k
        else:
            assert a == b, k


def record(
    path: Path, items: list[StreamItem], layout: StreamLayout, chunk_s: float = 0.5
) -> McapRecorder:
    rec = McapRecorder(path, chunk_s=chunk_s)
    rec.start(
        RecordingInfo(
            layout=layout,
            bench_text=BENCH_TEXT,
            truth=TRUTH,
            settings={"dsp": {"orders": [1.0, 1.5]}},
            source="synthetic",
            attachments={"acc.dbc": DBC},
        )
    )
    for item in items:
        rec.on_item(item)
    rec.close(None)
    return rec


def make_frame(t: float, rng: np.random.Generator) -> OrderFrame:
    amp = rng.standard_normal((3, 4)) + 1j * rng.standard_normal((3, 4))
    amp[2, 1] = complex(np.nan, np.nan)
    return OrderFrame(
        time_s=t,
        rpm=1500.0 + 100 * t,
        crank_angle_rad=4 * math.pi * t,
        orders=(1.0, 1.5, 3.0),
        channels=("s0", "s1", "s2", "s3"),
        amplitudes=amp,
        channel_ok=np.array([True, False, True, True]),
        rpm_change=0.003 * t,
        leakage=rng.random(4) * 1e-3,
        flags=frozenset({"nan"} if t > 0.5 else set()),
    )


def make_outcome(frame: OrderFrame, used: bool) -> FrameOutcome:
    if not used:
        return FrameOutcome(frame.time_s, frame.rpm, (), {}, "rpm_unsteady", {})
    return FrameOutcome(
        frame.time_s,
        frame.rpm,
        (1.0, 3.0),
        {1.5: "non_rigid"},
        None,
        {1.0: 0.01, 1.5: 0.4, 3.0: 0.02},
    )
