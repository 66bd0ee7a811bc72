"""The streaming order tracker: block-size invariance first, then state, flags and errors.

Signals come from :mod:`dsp.synthetic` (closed-form crank angle and order
content, independent of the simulated bench).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import fields, replace

import numpy as np
import pytest
from support.tracking import TDC, run_tracker, synthetic_bench, tracker_config

from acquisition.stream import EdgeBlock, SampleBlock, SourceEvent
from dsp.config import make_plan
from dsp.errors import DspConfigError
from dsp.frames import OrderFrame
from dsp.orders import OrderTracker, initial_state, track
from dsp.synthetic import Ramp, SyntheticBench
from dsp.tacho import TachoConfig


def _one_block(bench: SyntheticBench, duration: float):
    """The whole stream as one edge block and one sample block per group."""
    items = list(bench.items(duration, block_s=duration))
    edges = [i for i in items if isinstance(i, EdgeBlock)]
    samples = [i for i in items if isinstance(i, SampleBlock)]
    out = []
    for ch in sorted({e.channel for e in edges}):
        out.append(EdgeBlock(ch, np.concatenate([e.times_s for e in edges if e.channel == ch])))
    for g in sorted({s.group for s in samples}):
        parts = [s for s in samples if s.group == g]
        out.append(SampleBlock(g, parts[0].first_index, np.concatenate([p.data for p in parts], 1)))
    return out


def _split_edges(items, rng):
    """Cut every edge block at random points too (down to single edges)."""
    for item in items:
        if isinstance(item, EdgeBlock) and item.times_s.size > 1:
            cuts = np.sort(
                rng.choice(
                    np.arange(1, item.times_s.size),
                    size=min(5, item.times_s.size - 1),
                    replace=False,
                )
            )
            for part in np.split(item.times_s, cuts):
                yield EdgeBlock(item.channel, part)
        else:
            yield item


def _assert_same_frames(a, b, tol=1e-9):
    assert len(a) == len(b) and len(a) > 10
    for fa, fb in zip(a, b, strict=True):
        assert fa.crank_angle_rad == fb.crank_angle_rad
        assert fa.flags == fb.flags
        assert abs(fa.time_s - fb.time_s) < 1e-12
        assert abs(fa.rpm - fb.rpm) < 1e-9 * fa.rpm
        scale = np.abs(fa.amplitudes).max()
        np.testing.assert_allclose(fa.amplitudes, fb.amplitudes, rtol=0, atol=tol * scale)
        np.testing.assert_array_equal(fa.channel_ok, fb.channel_ok)
        np.testing.assert_allclose(fa.leakage, fb.leakage, rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("tacho", ["edges", "sampled"])
def test_random_block_splits_give_the_same_frames(tacho):
    duration = 1.2 if tacho == "sampled" else 3.0
    bench = synthetic_bench(tacho=tacho, ramp=Ramp(1500.0, 3000.0, 2.0))
    config = tracker_config(tacho=TachoConfig(tdc_after_gap_deg=TDC, delivery=tacho))
    reference, _ = run_tracker(bench, _one_block(bench, duration), config)
    rng = np.random.default_rng(7)
    # blocks of 1 .. ~2 x 0.03 s, so many are a single sample
    split = _split_edges(bench.items(duration, block_s=0.03, rng_blocks=rng), rng)
    frames, _ = run_tracker(bench, split, config)
    _assert_same_frames(reference, frames)


def test_lost_samples_and_edges_give_the_same_frames_in_any_blocks():
    # what a lossy CAN bus leaves: runs of 9 NaN samples on one channel, runs of 5 edges
    # missing; the fills (dsp.gap_fit, dsp.wheel) must not depend on the block cut
    bench = synthetic_bench(ramp=Ramp(1500.0, 3000.0, 2.0))
    duration = 2.0
    rng = np.random.default_rng(11)
    holes = {
        (int(c), int(i))
        for c, i in zip(rng.integers(0, 3, 30), rng.integers(3000, 9500, 30), strict=True)
    }
    lost_edges = [0.4, 1.6]  # more than FILL_REPORT_S apart: one report each

    def spoiled(items):
        for item in items:
            if isinstance(item, SampleBlock):
                data = item.data.copy()
                for c, i in holes:
                    a = max(i - item.first_index, 0)
                    b = min(i + 9 - item.first_index, data.shape[1])
                    if a < b:
                        data[c, a:b] = np.nan
                item = SampleBlock(item.group, item.first_index, data)
            elif isinstance(item, EdgeBlock):
                t = item.times_s
                keep = np.ones(t.size, bool)
                for t0 in lost_edges:
                    keep &= ~((t >= t0) & (t < t0 + 4.5 / (3000 / 60 * 60)))
                item = EdgeBlock(item.channel, t[keep])
            yield item

    reference, events = run_tracker(bench, spoiled(_one_block(bench, duration)))
    assert [e.kind for e in events].count("tacho_filled") == len(lost_edges)
    assert sum(f.variance_factor is not None for f in reference) > 20
    assert all(
        f.channel_ok.all()
        for f in reference
        if not f.flags - {"cycle_ambiguous", "leakage_uncorrected"}
    )
    split = _split_edges(bench.items(duration, block_s=0.03, rng_blocks=rng), rng)
    frames, _ = run_tracker(bench, spoiled(split))
    _assert_same_frames(reference, frames)
    for fa, fb in zip(reference, frames, strict=True):
        assert (fa.variance_factor is None) == (fb.variance_factor is None)
        if fa.variance_factor is not None:
            np.testing.assert_allclose(fa.variance_factor, fb.variance_factor, rtol=1e-9)


def test_single_sample_blocks_give_the_same_frames():
    bench = synthetic_bench()
    duration = 0.6
    reference, _ = run_tracker(bench, _one_block(bench, duration))
    items = []
    for item in bench.items(duration, block_s=0.05):
        if isinstance(item, SampleBlock):
            items += [
                SampleBlock(item.group, item.first_index + k, item.data[:, k : k + 1])
                for k in range(item.n_samples)
            ]
        else:
            items.append(item)
    frames, _ = run_tracker(bench, items)
    _assert_same_frames(reference, frames)


def test_pure_step_and_class_agree_and_step_leaves_its_input_alone():
    bench = synthetic_bench()
    items = list(bench.items(1.5, block_s=0.07))
    tracker = OrderTracker.from_layout(bench.layout, tracker_config())
    state = initial_state(make_plan(bench.layout, tracker_config()))
    pure, wrapped = [], []
    for item in items:
        before = state
        snapshot = (before.next_frame, len(before.groups[0].acc), before.table.t_end)
        state, frames = track(state, item)
        assert (before.next_frame, len(before.groups[0].acc), before.table.t_end) == snapshot
        pure += frames
        wrapped += tracker.process(item)[0]
    _assert_same_frames(pure, wrapped, tol=1e-12)


def test_source_events_pass_through_and_stream_continues():
    bench = synthetic_bench()
    items = list(bench.items(1.0, block_s=0.1))
    items.insert(3, SourceEvent("gap", "3 CAN frames lost", 0.25))
    frames, events = run_tracker(bench, items)
    assert any(e.kind == "gap" for e in events)
    assert len(frames) > 20


def test_frames_sit_at_whole_revolutions_with_consistent_time_and_rpm():
    ramp = Ramp(2000.0, 2600.0, 3.0)
    bench = synthetic_bench(ramp=ramp)
    frames, _ = run_tracker(bench, bench.items(3.0))
    phis = np.array([f.crank_angle_rad for f in frames])
    np.testing.assert_allclose(np.diff(phis), 2 * math.pi, rtol=0, atol=1e-12)
    for f in frames:
        # time_s is when the crank reaches the frame angle; rpm the mean over +-360 deg
        assert abs(ramp.phi(f.time_s) - f.crank_angle_rad) < 1e-9
        t_a, t_b = (
            ramp.t_of_phi(f.crank_angle_rad - 2 * math.pi),
            ramp.t_of_phi(f.crank_angle_rad + 2 * math.pi),
        )
        assert abs(f.rpm - 120.0 / (t_b - t_a)) < 1e-9 * f.rpm
        expected_change = (ramp.rpm(t_b) - ramp.rpm(t_a)) / f.rpm
        assert abs(f.rpm_change - expected_change) < 1e-9


def test_latency_is_two_revolutions_plus_taper_plus_lookahead():
    # one sample per block: a frame comes out with the block that completes it
    bench = synthetic_bench(ramp=Ramp(3000.0, 3000.0, 1.0))
    config = tracker_config()
    tracker = OrderTracker.from_layout(bench.layout, config)
    worst = 0.0
    for item in bench.items(1.0, block_s=1 / 5120):
        frames, _ = tracker.process(item)
        if isinstance(item, SampleBlock):
            t_now = (item.first_index + item.n_samples) / 5120  # stream time when the item arrives
        else:
            t_now = item.times_s[-1]
        if frames:
            for f in frames:
                # oldest sample in the window: 360 deg + taper/2 before the centre
                t_first = bench.ramp.t_of_phi(
                    f.crank_angle_rad - 2 * math.pi - math.radians(config.taper_deg) / 2
                )
                worst = max(worst, (t_now - t_first) * 3000 / 60)
    # 2 revolutions + taper (45 deg) + about three teeth (6 deg each) of tacho look-ahead
    assert 2.0 < worst < 2.0 + (config.taper_deg + 4 * 6.0) / 360.0


def test_memory_stays_flat_on_a_long_stream():
    bench = synthetic_bench(ramp=Ramp(4000.0, 4000.0, 30.0))
    tracker = OrderTracker.from_layout(bench.layout, tracker_config())
    sizes = []
    for k, item in enumerate(bench.items(30.0, block_s=0.5)):
        tracker.process(item)
        if k % 10 == 9:
            st = tracker.state
            sizes.append(
                (st.table.t_lo.size, len(st.groups[0].acc), len(st.invalid), st.history[0].size)
            )
    early, late = np.array(sizes[: len(sizes) // 3]), np.array(sizes[len(sizes) // 3 :])
    assert (late.max(axis=0) <= early.max(axis=0) + np.array([3, 1, 0, 0])).all()
    assert late[:, 0].max() < 400


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"orders": (1.0, 1.25)}, "multiples of 0.5"),
        ({"orders": (1.0, 40.0)}, "Nyquist"),
        ({"tacho": {"teeth": 60, "missing": 60}}, "cannot miss"),
        ({"tacho": {"teeth": 4, "missing": 2}}, "at least 3 teeth"),
        ({"frames_per_rev": 4, "taper_deg": 95.0}, "frame spacing"),
        ({"channels": ("a0", "nope")}, "'nope'"),
        ({"tacho": {"channel": "crank"}}, "'crank'"),
    ],
)
def test_configurations_that_cannot_work_raise_one_line(kwargs, message):
    bench = synthetic_bench()
    with pytest.raises(DspConfigError, match=message) as info:
        if "tacho" in kwargs:
            kwargs = {**kwargs, "tacho": TachoConfig(**kwargs["tacho"])}
        OrderTracker.from_layout(bench.layout, replace(tracker_config(), **kwargs))
    assert "\n" not in str(info.value)
    assert isinstance(info.value, ValueError)


def test_sampled_tacho_too_slow_for_the_wheel_is_refused():
    bench = synthetic_bench(tacho="sampled", tacho_rate_hz=20_000.0)
    config = tracker_config(tacho=TachoConfig(delivery="sampled", tdc_after_gap_deg=TDC))
    with pytest.raises(DspConfigError, match="samples per tooth"):
        OrderTracker.from_layout(bench.layout, config)


def test_driver_yields_the_frames_and_events_of_the_stream_in_order():
    from dsp.driver import track_items
    from dsp.frames import OrderFrame

    bench = synthetic_bench()
    items = list(bench.items(1.0, block_s=0.1))
    out = list(track_items(bench.layout, items, tracker_config()))
    frames = [o for o in out if isinstance(o, OrderFrame)]
    events = [o for o in out if isinstance(o, SourceEvent)]
    reference, ref_events = run_tracker(bench, items)
    _assert_same_frames(reference, frames, tol=0.0)
    assert events == ref_events and events[0].kind == "tacho_sync"
    assert out.index(events[0]) < out.index(frames[0])


def test_four_frames_per_revolution_sit_every_90_deg_and_stay_exact():
    ramp = Ramp(2400.0, 2400.0, 1.5)
    bench = synthetic_bench(ramp=ramp)
    config = tracker_config(frames_per_rev=4, taper_deg=45.0)
    frames, _ = run_tracker(bench, bench.items(1.5), config)
    np.testing.assert_allclose(
        np.diff([f.crank_angle_rad for f in frames]), math.pi / 2, atol=1e-12
    )
    for f in frames:
        assert abs(ramp.phi(f.time_s) - f.crank_angle_rad) < 1e-9
        for c, content in enumerate(bench.contents):
            exact = content.at(f.rpm)[0][: len(config.orders)]
            np.testing.assert_allclose(
                f.amplitudes[:, c], exact, rtol=0, atol=1e-5 * np.abs(exact).max()
            )
    rng = np.random.default_rng(2)
    split, _ = run_tracker(bench, bench.items(1.5, block_s=0.02, rng_blocks=rng), config)
    _assert_same_frames(frames, split)


def test_a_block_with_the_wrong_channel_count_is_dropped_and_reported():
    bench = synthetic_bench(ramp=Ramp(3000.0, 3000.0, 1.5))
    items = []
    for item in bench.items(1.5, block_s=0.1):
        if isinstance(item, SampleBlock) and item.first_index == 512 * 7:
            item = SampleBlock(item.group, item.first_index, item.data[:2])  # a channel lost
        items.append(item)
    frames, events = run_tracker(bench, items)
    assert any(e.kind == "missing_channel" and "(2, 512)" in e.message for e in events)
    hit = [f for f in frames if "missing_channel" in f.flags]
    assert hit and all(not f.channel_ok.any() for f in hit)
    assert all(abs(f.time_s - 0.75) < 0.05 + 0.022 for f in hit)
    assert frames[-1].time_s > 1.4


def test_pieces_summed_in_one_call_round_as_one_call_per_piece():
    """The tracker adds the samples waiting from the last block and the new block in one
    pass; a segment the two share keeps a partial sum from each, bit for bit. (Pieces of
    one sample stay alone: numpy computes a one-element array on another path.)"""
    from dsp.sums import add_samples

    rng = np.random.default_rng(4)
    n = 3000
    phi = 100.0 + np.cumsum(rng.uniform(0.005, 0.015, n))  # several segments
    omega = rng.uniform(250.0, 350.0, n)
    x = rng.standard_normal((3, n))
    k2 = np.arange(1, 9)
    args = (25_600.0, k2, 1, 45.0, 1.5)
    cuts = [0, 37, 39, 1900, n]  # short pieces, then long ones
    one_by_one: dict = {}
    for a, b in itertools.pairwise(cuts):
        one_by_one = add_samples(one_by_one, phi[a:b], omega[a:b], [x[:, a:b]], 1000 + a, *args)
    pieces = [x[:, a:b] for a, b in itertools.pairwise(cuts)]
    together = add_samples({}, phi, omega, pieces, 1000, *args)
    assert one_by_one.keys() == together.keys()
    for m, row in one_by_one.items():
        np.testing.assert_array_equal(together[m], row)


def test_taper_table_is_np_interp_bit_for_bit():
    from dsp.frames import _S, _TABLE, rise_table

    rng = np.random.default_rng(5)
    grid = np.arange(_S.size) / (_S.size - 1)
    s = np.concatenate(
        (rng.uniform(-0.1, 1.1, 100_000), grid, np.nextafter(grid, 2), np.nextafter(grid, -1))
    )
    np.testing.assert_array_equal(rise_table(s), np.interp(s, _S, _TABLE))


def test_frames_carry_every_field_of_the_dataclass():
    """The assembler sets the frame's fields directly (dsp.assemble._finish): a field added
    to OrderFrame must not be left unset."""
    bench = synthetic_bench()
    frames, _ = run_tracker(bench, bench.items(1.0, block_s=0.25))
    assert frames
    assert set(vars(frames[0])) == {f.name for f in fields(OrderFrame)}


@pytest.mark.parametrize("block_s", [0.5, 0.07, None])
def test_held_back_samples_change_no_frame_and_delay_none(block_s, monkeypatch):
    """Ready samples that cannot complete a frame wait for the next block
    (dsp.segments._can_wait): every frame is the same, bit for bit, and comes out with the
    same stream item as when every ready sample is summed at once. None: random blocks
    down to one sample."""
    from dsp import segments

    bench = synthetic_bench(ramp=Ramp(1500.0, 3000.0, 2.0))
    rng = None if block_s else np.random.default_rng(5)
    items = list(bench.items(2.0, block_s=block_s or 0.03, rng_blocks=rng))
    waits = []
    can_wait = segments._can_wait

    def counted(*args):
        waits.append(can_wait(*args))
        return waits[-1]

    def emitted(tracker_items):
        tracker = OrderTracker.from_layout(bench.layout, tracker_config())
        return [(k, f) for k, item in enumerate(tracker_items) for f in tracker.process(item)[0]]

    monkeypatch.setattr(segments, "_can_wait", counted)
    held = emitted(items)
    monkeypatch.setattr(segments, "_can_wait", lambda *args: False)
    at_once = emitted(items)
    assert sum(waits) >= 3  # samples were held back
    assert len(held) == len(at_once) > 20
    for (k_a, a), (k_b, b) in zip(held, at_once, strict=True):
        assert k_a == k_b and a.crank_angle_rad == b.crank_angle_rad and a.flags == b.flags
        np.testing.assert_array_equal(a.amplitudes, b.amplitudes)
        np.testing.assert_array_equal(a.leakage, b.leakage)
