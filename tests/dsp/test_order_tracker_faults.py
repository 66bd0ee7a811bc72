"""The streaming order tracker's flags and recoveries: NaN, clipped and gap samples flag
only the frames they touch, a channel that lost most of its window is left out, rpm out of
range, a dead tacho (split from test_order_tracker.py)."""

from __future__ import annotations

import numpy as np
from support.tracking import run_tracker, synthetic_bench, tracker_config

from acquisition.stream import EdgeBlock, SampleBlock
from dsp.orders import OrderTracker
from dsp.synthetic import Ramp


def test_nan_clipped_and_gap_flag_only_the_frames_they_touch():
    bench = synthetic_bench(ramp=Ramp(3000.0, 3000.0, 2.0))
    items = list(bench.items(2.0, block_s=0.1))

    def spoiled(nan: bool):
        for item in items:
            if isinstance(item, SampleBlock) and item.first_index == 512 * 5:  # t = 0.5 s
                data = item.data.copy()
                if nan:
                    data[1, 10] = np.nan
                data[2, 200] = 1e3
                item = SampleBlock(item.group, item.first_index, data)
            if (
                isinstance(item, SampleBlock) and item.first_index == 512 * 12
            ):  # t = 1.2 s: dropped block
                continue
            yield item

    frames, _ = run_tracker(bench, spoiled(nan=True), tracker_config(clip_level=100.0))
    whole, _ = run_tracker(bench, spoiled(nan=False), tracker_config(clip_level=100.0))
    assert [f.time_s for f in frames] == [f.time_s for f in whole]
    t_nan = 0.5 + 10 / 5120
    t_clip = 0.5 + 200 / 5120
    taper = tracker_config().taper_deg
    half = (360 + taper / 2) / (3000 * 6)  # the window reaches 360 deg + taper/2 each side (s)
    for f, ref in zip(frames, whole, strict=True):
        near = lambda t, f=f: abs(f.time_s - t) < half  # noqa: E731
        # a missing sample costs that sample, not the channel (dsp.gap_fit): filled from
        # the cycle before, the channel's amplitudes stay within the noise of the whole
        # window's, and only its variance factor says so
        assert "nan" not in f.flags
        if near(t_nan):
            assert f.channel_ok[1] and np.isfinite(f.amplitudes[:, 1]).all()
            assert f.variance_factor is not None and f.variance_factor[1] > 1.0
            assert np.all(np.delete(f.variance_factor, 1) == 1.0)
            err = np.abs(f.amplitudes[:, 1] - ref.amplitudes[:, 1])
            assert err.max() <= 0.01 * np.abs(ref.amplitudes[:, 1]).max()
        else:
            assert f.variance_factor is None
        # the other channels are untouched; the channel's later frames see the filled window
        # through the sweep-leakage correction (it takes the frames a cycle away in)
        others = [0, 2]
        assert np.array_equal(f.amplitudes[:, others], ref.amplitudes[:, others], equal_nan=True)
        if f.time_s < t_nan - half:
            assert np.array_equal(f.amplitudes, ref.amplitudes, equal_nan=True)
        elif np.isfinite(ref.amplitudes[:, 1]).all():
            err = np.abs(f.amplitudes[:, 1] - ref.amplitudes[:, 1])
            assert err.max() <= 0.01 * np.abs(ref.amplitudes[:, 1]).max()
        assert ("clipped" in f.flags) == near(t_clip)
        gap = abs(f.time_s - 1.25) < 0.05 + half
        assert ("missing_channel" in f.flags) == gap
        if gap:
            assert not f.channel_ok.any()
        if not f.flags - {"cycle_ambiguous", "leakage_uncorrected"}:
            assert f.channel_ok.all()
    assert frames[-1].time_s > 1.8  # the stream went on


def test_a_channel_that_lost_most_of_its_window_is_left_out_and_flagged():
    bench = synthetic_bench(ramp=Ramp(3000.0, 3000.0, 1.0))

    def spoiled():
        for item in bench.items(1.0, block_s=0.1):
            if isinstance(item, SampleBlock) and item.first_index in (512 * 5, 512 * 6):
                data = item.data.copy()
                data[1] = np.nan  # 0.5 - 0.7 s: five engine cycles of one channel
                item = SampleBlock(item.group, item.first_index, data)
            yield item

    frames, _ = run_tracker(bench, spoiled(), tracker_config())
    taper = tracker_config().taper_deg
    half = (360 + taper / 2) / (3000 * 6)
    # the first cycle of the stretch is filled from the cycle before; past it nothing is
    # left to fill from, and a window that lost most of its samples is not fitted
    inside = [f for f in frames if 0.5 + 0.04 + half <= f.time_s <= 0.7 - half]
    assert inside
    for f in inside:
        assert "nan" in f.flags and not f.channel_ok[1] and np.isnan(f.amplitudes[:, 1]).all()
        assert np.delete(f.channel_ok, 1).all() and np.isfinite(np.delete(f.amplitudes, 1, 1)).all()
    far = [f for f in frames if abs(f.time_s - 0.6) > 0.1 + half]
    assert far and all("nan" not in f.flags and f.channel_ok.all() for f in far)


def test_rpm_out_of_range_is_flagged():
    bench = synthetic_bench(ramp=Ramp(1000.0, 2000.0, 2.0))
    frames, _ = run_tracker(bench, bench.items(2.0), tracker_config(rpm_min=1200.0, rpm_max=6000.0))
    for f in frames:
        assert ("rpm_out_of_range" in f.flags) == (f.rpm < 1200.0)
    assert any("rpm_out_of_range" in f.flags for f in frames)


def test_dead_tacho_drops_samples_reports_once_and_recovers():
    bench = synthetic_bench(ramp=Ramp(3000.0, 3000.0, 8.0))
    items = [
        i
        for i in bench.items(8.0, block_s=0.1)
        if not (isinstance(i, EdgeBlock) and 2.0 < i.times_s[0] < 5.0)
    ]
    tracker = OrderTracker.from_layout(bench.layout, tracker_config())
    frames, events = [], []
    sizes = []
    for item in items:
        f, e = tracker.process(item)
        frames += f
        events += e
        sizes.append(sum(r.shape[1] for _, r in tracker.state.groups[0].pend))
    kinds = [e.kind for e in events]
    assert kinds.count("no_tacho") >= 1 and kinds.count("tacho_sync") == 2
    assert max(sizes) <= 2.1 * 5120  # bounded by max_wait_s
    times = np.array([f.time_s for f in frames])
    # edges stop after the block that starts at 2.0 s (its last edge ~2.1 s) and resume at 5.0 s
    assert not ((times > 2.15) & (times < 4.95)).any()
    assert times.max() > 7.5
    after = [f for f in frames if f.time_s > 5.2]
    assert after and all("no_tacho" not in f.flags for f in after)
