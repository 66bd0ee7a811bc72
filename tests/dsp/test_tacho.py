"""Tacho processing: sampled edges, wheel decoding, crank angle, the 720 deg cycle.

Truth comes from closed forms (:mod:`dsp.synthetic`: a linear rpm ramp has a
quadratic crank angle with an exact inverse), never from the code under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dsp import angle as ang
from dsp.config import OrderTrackerConfig
from dsp.orders import OrderTracker
from dsp.synthetic import Ramp, SyntheticBench, random_content
from dsp.tacho import EdgeDetector, EdgeDetectorState, TachoConfig, detect_edges
from dsp.wheel import DecoderState, decode_edges

TDC = 84.0
WHEEL = TachoConfig(tdc_after_gap_deg=TDC)


def _bench(ramp: Ramp, **kw) -> SyntheticBench:
    rng = np.random.default_rng(11)
    return SyntheticBench(
        ramp, [random_content(rng) for _ in range(2)], tdc_after_gap_deg=TDC, **kw
    )


def _edges_of(bench: SyntheticBench, t_end: float, rate: float, block: int, rng=None):
    det = EdgeDetector(rate, 0.0, 1.5, 3.5)
    out = []
    n = int(t_end * rate)
    k = 0
    while k < n:
        size = int(rng.integers(1, 2 * block)) if rng is not None else block
        size = min(size, n - k)
        out.append(det.process(bench.tacho_volts((k + np.arange(size)) / rate), k))
        k += size
    return np.concatenate(out)


# -- sampled tacho -----------------------------------------------------------------------------


def test_edges_of_a_sampled_square_wave_are_exact_when_the_ramp_spans_two_samples():
    ramp = Ramp(1000.0, 6000.0, 0.5)
    bench = _bench(ramp, rise_s=12.5e-6)  # 2.5 samples at 200 kHz, like the simulated bench
    got = _edges_of(bench, 0.5, 200_000.0, 20_000)
    truth = bench.edge_times(0.5)
    truth = truth[(truth > 1e-4) & (truth < 0.5 - 1e-4)]
    assert got.size == truth.size
    np.testing.assert_allclose(got, truth, rtol=0, atol=1e-10)


def test_fast_edges_are_timed_within_the_sample_period():
    ramp = Ramp(4500.0, 4500.0, 0.2)
    bench = _bench(ramp, rise_s=2e-6)  # shorter than the 5 us sample period
    got = _edges_of(bench, 0.2, 200_000.0, 7_000)
    truth = bench.edge_times(0.2)
    truth = truth[(truth > 1e-4) & (truth < 0.2 - 1e-4)]
    err = got - truth
    # the mid crossing is interpolated between a sample below and one above the ramp
    assert np.abs(err).max() <= 0.5 * (5e-6 - 2e-6) + 1e-9
    assert abs(err.mean()) < 0.2e-6  # no bias: the ramp is centred on the edge


def test_edge_detection_is_block_invariant():
    bench = _bench(Ramp(2000.0, 2500.0, 0.1), rise_s=12.5e-6)
    one = _edges_of(bench, 0.1, 200_000.0, 20_000)
    rng = np.random.default_rng(5)
    split = _edges_of(bench, 0.1, 200_000.0, 40, rng)
    np.testing.assert_array_equal(one, split)


def test_hysteresis_ignores_chatter_and_noise():
    rate = 200_000.0
    t = np.arange(40_000) / rate
    rng = np.random.default_rng(0)
    # a 1 kHz square wave with 0.4 V rms noise, plus a stretch of chatter around mid level
    clean = 5.0 * (np.mod(t * 1000.0, 1.0) < 0.5)
    x = clean + 0.4 * rng.standard_normal(t.size)
    x[30_000:32_000] = 2.5 + 0.6 * np.sin(2 * np.pi * 37_000 * t[30_000:32_000])
    _, edges = detect_edges(EdgeDetectorState(), x, 0, rate, 0.0, 1.5, 3.5)
    truth = np.arange(1, 200) / 1000.0
    truth = truth[(truth < 0.1495) | (truth > 0.1595)]  # the chatter hides 0.150 .. 0.159
    assert edges.size == truth.size
    assert np.abs(edges - truth).max() < 10 / rate


# -- wheel decoding ----------------------------------------------------------------------------


def _knots(times, cfg=WHEEL):
    _state, knots, events = decode_edges(DecoderState(), times, cfg)
    return knots, events


def test_wheel_numbering_gives_the_exact_crank_angle():
    ramp = Ramp(800.0, 5000.0, 2.0, phi0_rad=0.3)
    bench = _bench(ramp)
    times = bench.edge_times(2.0)
    knots, events = _knots(times)
    assert [e.kind for e in events] == ["tacho_sync"]
    phi_w = WHEEL.phi_first_tooth_rad + knots.n * 2 * math.pi / 60
    # the wheel knows phi modulo 360 deg: the offset to the truth is a whole number of turns
    turns = (ramp.phi(knots.t_s) - phi_w) / (2 * math.pi)
    np.testing.assert_allclose(turns, np.round(turns[0]), rtol=0, atol=1e-9)
    steps = np.diff(knots.n)
    assert set(steps.tolist()) == {1, 3}  # one pitch, or three across the 60-2 gap
    assert knots.t_s[0] <= times[60]  # synchronised within the first revolution and a bit


def test_block_split_does_not_change_the_knots():
    times = _bench(Ramp(1000.0, 3000.0, 1.0)).edge_times(1.0)
    one, _ = _knots(times)
    state = DecoderState()
    parts = []
    for chunk in np.split(times, [1, 2, 3, 50, 51, 170, 171, 172, 600]):
        state, k, _ = decode_edges(state, chunk, WHEEL)
        parts.append(k)
    np.testing.assert_array_equal(np.concatenate([p.t_s for p in parts]), one.t_s)
    np.testing.assert_array_equal(np.concatenate([p.n for p in parts]), one.n)


@pytest.mark.parametrize("fault", ["missing", "extra_early", "extra_late", "missing_at_gap"])
def test_a_missed_or_extra_edge_is_reported_and_the_wheel_resyncs(fault):
    ramp = Ramp(1500.0, 2500.0, 3.0)
    bench = _bench(ramp)
    times = bench.edge_times(3.0)
    k = 1000 + (57 - (1000 % 58))  # tooth 57: the last before a gap
    if fault == "missing":
        times = np.delete(times, 1000)
    elif fault == "missing_at_gap":
        times = np.delete(times, k)
    else:
        frac = 0.2 if fault == "extra_early" else 0.8
        times = np.sort(np.append(times, times[1000] + frac * (times[1001] - times[1000])))
    knots, events = _knots(times)
    kinds = [e.kind for e in events]
    expected = "tacho_extra_edge" if fault.startswith("extra") else "tacho_missing_edge"
    assert kinds == ["tacho_sync", expected, "tacho_sync"], kinds
    assert "without angle" in events[2].message and "uncertain" not in events[2].message
    # every knot, before and after the stretch, is an exact edge at its exact angle
    phi_w = WHEEL.phi_first_tooth_rad + knots.n * 2 * math.pi / 60
    turns = (ramp.phi(knots.t_s) - phi_w) / (2 * math.pi)
    np.testing.assert_allclose(turns, np.round(turns[0]), rtol=0, atol=1e-9)
    assert np.isin(knots.t_s, bench.edge_times(3.0)).all()
    # no knot across the fault: the knots jump over at least the faulty pitch
    t_fault = bench.edge_times(3.0)[1000 if fault != "missing_at_gap" else k]
    before, after = knots.t_s[knots.t_s < t_fault], knots.t_s[knots.t_s > t_fault]
    assert after[0] - before[-1] > 2 * (times[2] - times[1])
    assert set(knots.run.tolist()) == {0, 1}


def test_a_false_gap_is_never_confirmed():
    # a missed edge mid-revolution looks like a 60-1 gap; the 60-2 search must not lock on it
    cfg = TachoConfig(teeth=60, missing=1, tdc_after_gap_deg=TDC)
    ramp = Ramp(3000.0, 3000.0, 1.0)
    theta0 = math.radians(TDC)
    j = np.arange(0, 50 * 60)
    j = j[(j % 60) < 59]
    t = ramp.t_of_phi(2 * math.pi * j / 60 - theta0)
    t = t[t > 0]
    t_bad = np.delete(t, 20)  # before the first real gap
    knots, _events = _knots(t_bad, cfg)
    phi_w = cfg.phi_first_tooth_rad + knots.n * 2 * math.pi / 60
    turns = (ramp.phi(knots.t_s) - phi_w) / (2 * math.pi)
    np.testing.assert_allclose(turns, np.round(turns[0]), rtol=0, atol=1e-9)


# -- crank angle between knots -----------------------------------------------------------------


def test_cubic_pieces_reproduce_a_constant_acceleration_exactly():
    ramp = Ramp(900.0, 6500.0, 1.5, phi0_rad=1.0)
    bench = _bench(ramp)
    knots, _ = _knots(bench.edge_times(1.5))
    phi = WHEEL.phi_first_tooth_rad + knots.n * 2 * math.pi / 60
    turns = np.round((ramp.phi(knots.t_s[0]) - phi[0]) / (2 * math.pi))
    table = ang.add_knots(ang.AngleTable(), knots.t_s, phi + 2 * math.pi * turns, knots.run)
    t = np.linspace(table.t_lo[0] + 1e-9, table.t_end - 1e-9, 20001)
    ok, p, w, _ = ang.lookup(table, t)
    assert ok.all()
    np.testing.assert_allclose(p, ramp.phi(t), rtol=0, atol=1e-9)
    np.testing.assert_allclose(w, ramp.omega(t), rtol=1e-9)
    back, _w_back = ang.time_at(table, ramp.phi(t[::97]))
    np.testing.assert_allclose(back, t[::97], rtol=0, atol=1e-12)


def test_cubic_pieces_follow_a_speed_ripple_to_a_small_fraction_of_a_tooth():
    # firing-frequency ripple of +-2 % at 800 rpm (idle): the worst case of a real crank
    w0, amp, h = 800 * 2 * math.pi / 60, 0.02, 1.5

    def phi_of(t):
        return w0 * t + amp * w0 / (h * w0) * (1 - np.cos(h * w0 * t))

    tt = np.linspace(0, 3.0, 3_000_001)
    th = phi_of(tt)
    teeth = 2 * math.pi * np.arange(1, int(th[-1] / (2 * math.pi / 60))) / 60
    t_teeth = np.interp(teeth, th, tt)
    table = ang.add_knots(ang.AngleTable(), t_teeth, teeth, np.zeros(teeth.size, np.int64))
    t = np.linspace(table.t_lo[0], table.t_end - 1e-6, 5000)
    _, p, _, _ = ang.lookup(table, t)
    assert np.abs(p - phi_of(t)).max() < 1e-4 * (2 * math.pi / 60)


# -- the 720 deg cycle -------------------------------------------------------------------------


def _half_order_signs(reference: str, phi0: float):
    ramp = Ramp(2500.0, 2500.0, 1.5, phi0_rad=phi0)
    bench = _bench(
        ramp, cam_angle_deg=100.0 if reference == "cam" else None, pressure=reference == "pressure"
    )
    tacho = TachoConfig(tdc_after_gap_deg=TDC, phase_reference=reference, cam_angle_deg=100.0)
    cfg = OrderTrackerConfig(tacho=tacho, orders=(1.0, 1.5), channels=("a0", "a1"))
    tracker = OrderTracker.from_layout(bench.layout, cfg)
    frames = []
    for item in bench.items(1.5):
        frames += tracker.process(item)[0]
    signs = []
    for f in frames:
        exact = bench.contents[0].at(f.rpm)[0]
        x = f.amplitude(1.5, "a0") / exact[bench.contents[0].orders.index(1.5)]
        signs.append(round(x.real))
        assert abs(f.amplitude(1.0, "a0") / exact[1] - 1) < 1e-4
        assert abs(abs(x) - 1) < 1e-4
        if reference != "none":
            assert abs(f.crank_angle_rad - ramp.phi(f.time_s)) < 1e-9
    return signs, frames


@pytest.mark.parametrize("phi0", [0.0, 2 * math.pi])
@pytest.mark.parametrize("reference", ["cam", "pressure"])
def test_a_cam_or_pressure_reference_fixes_the_cycle(reference, phi0):
    signs, frames = _half_order_signs(reference, phi0)
    assert len(frames) > 50 and set(signs) == {1}
    assert not any("cycle_ambiguous" in f.flags for f in frames)


def test_without_a_reference_the_cycle_is_flagged_and_may_be_off_by_360_deg():
    signs, frames = _half_order_signs("none", 2 * math.pi)  # first gap in the second revolution
    assert set(signs) == {-1}  # half orders flipped, integer orders right
    assert all("cycle_ambiguous" in f.flags for f in frames)
    signs, _ = _half_order_signs("none", 0.0)
    assert set(signs) == {1}


def test_pulses_without_gap_track_orders_and_flag_the_angle():
    ramp = Ramp(3000.0, 3000.0, 1.0)
    bench = _bench(ramp, missing=0)
    cfg = OrderTrackerConfig(
        tacho=TachoConfig(kind="pulses", teeth=60, tdc_after_gap_deg=TDC), orders=(1.0, 2.0)
    )
    tracker = OrderTracker.from_layout(bench.layout, cfg)
    frames = []
    for item in bench.items(1.0):
        frames += tracker.process(item)[0]
    assert len(frames) > 30
    for f in frames:
        assert "angle_ambiguous" in f.flags
        exact = bench.contents[0].at(f.rpm)[0]
        # magnitudes are right; phases only up to the unknown pulse (k * 6 deg)
        assert abs(abs(f.amplitude(2.0, "a0")) / abs(exact[3]) - 1) < 1e-4


def test_angle_at_one_time_gives_the_lookup_bits():
    """dsp.angle.angle_at_one (the tracker's check whether samples can wait) against
    dsp.angle.lookup, time by time: the same angle where lookup has one, NaN where not
    (before the first knot, between two wheel runs)."""
    rng = np.random.default_rng(5)
    table = ang.AngleTable()
    t0 = 0.0
    for run in range(2):
        t = t0 + np.cumsum(rng.uniform(0.9, 1.1, 300) * 60.0 / 3000.0 / 58)
        phi = 100.0 * run + np.arange(t.size) * (2 * np.pi / 60)
        table = ang.add_knots(table, t, phi, np.full(t.size, run, dtype=np.int64))
        t0 = t[-1] + 0.01
    times = np.sort(rng.uniform(-0.01, table.t_end - 1e-9, 400))
    for t in times:
        ok, phi, _, _ = ang.lookup(table, np.array([t]))
        got = ang.angle_at_one(table, float(t))
        assert (got == phi[0]) if ok[0] else np.isnan(got)
    assert sum(np.isnan(ang.angle_at_one(table, float(t))) for t in times) > 5
