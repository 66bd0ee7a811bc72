"""Order amplitudes against exact truth: closed-form signals and the simulated i3 bench.

Relative errors are taken against ``max(|X|, 1e-3 max_h |X_h|)`` per channel:
an order more than 60 dB below the channel's strongest (the i3's half orders
are exactly zero, some channels carry H1.5 66 dB below H1) is judged on its
absolute error at that -60 dB level, the neighbour rejection the tracker is
specified for; phases are checked where the order is above that level.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from support.tracking import frames_and_events

from acquisition.sim.sweep import RpmProfile, hold, ramp
from acquisition.stream import EdgeBlock, SampleBlock, StreamItem
from dsp.config import OrderTrackerConfig
from dsp.frames import noise_std
from dsp.synthetic import OrderContent, Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig
from ptinertia.sources import open_source
from ptinertia.to_dsp import tracker_config

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
FLOOR = 1e-3  # -60 dB


def _with_tacho(bench, **kw):
    return bench.model_copy(update={"tacho": bench.tacho.model_copy(update=kw)})


def _config(bench, orders, **kw) -> OrderTrackerConfig:
    return replace(tracker_config(bench, tuple(orders)), rpm_min=500.0, rpm_max=6000.0, **kw)


def _track(layout, config, items: Iterable[StreamItem]):
    return frames_and_events(layout, items, config)


def _errors(frames, exact):
    """Amplitude (relative) and phase (deg) errors, floored at -60 dB: (n_frames, n_orders, n_ch)."""
    x = np.array([f.amplitudes for f in frames])
    floor = FLOOR * np.abs(exact).max(axis=1, keepdims=True)
    scale = np.maximum(np.abs(exact), floor)
    amp = np.abs(np.abs(x) - np.abs(exact)) / scale
    phase = np.degrees(np.abs(np.angle(x / exact)))
    phase = np.where(np.abs(exact) >= floor, phase, 0.0)
    return amp, phase


def _sim(bench, profile, **kw):
    return open_source("sim", bench, profile=profile, block_s=0.1, **kw)


def _clean(frames):
    return [f for f in frames if not f.flags - {"cycle_ambiguous"}]


# -- closed-form signals -----------------------------------------------------------------------


@pytest.mark.parametrize("rpm", [1500.0, 3000.0, 4500.0])
def test_constant_speed_closed_form_orders_half_to_four(rpm):
    rng = np.random.default_rng(int(rpm))
    contents = [random_content(rng, power_range=(0.0, 0.0)) for _ in range(2)]  # orders 0.5 .. 6
    bench = SyntheticBench(Ramp(rpm, rpm, 1.0), contents, tdc_after_gap_deg=84.0)
    orders = tuple(np.arange(0.5, 4.01, 0.5))
    config = OrderTrackerConfig(tacho=TachoConfig(tdc_after_gap_deg=84.0), orders=orders)
    frames, _ = _track(bench.layout, config, bench.items(1.0))
    assert len(frames) > rpm / 60 - 6  # sync, its confirmation and the first window take 4 rev
    exact = np.stack(
        [np.stack([c.at(f.rpm)[0][: len(orders)] for c in contents], 1) for f in frames]
    )
    amp, phase = _errors(frames, exact)
    assert amp.max() <= 5e-4 and phase.max() <= 0.05


# -- the simulated bench -----------------------------------------------------------------------


@pytest.mark.parametrize("rpm", [1500.0, 3000.0, 4500.0])
def test_constant_speed_simulated_bench_orders_half_to_four(i3, rpm):
    orders = tuple(np.arange(0.5, 4.01, 0.5))
    src = _sim(i3, RpmProfile([hold(rpm, 1.0)]))
    frames, _ = _track(src.layout, _config(i3, orders), src)
    frames = _clean(frames)
    assert len(frames) > rpm / 60 - 6  # sync, its confirmation and the first window take 4 rev
    amp, phase = _errors(frames, src.exact_amplitudes([f.rpm for f in frames], orders))
    assert amp.max() <= 5e-4, amp.max(axis=(0, 2))
    assert phase.max() <= 0.05, phase.max(axis=(0, 2))


@pytest.mark.parametrize("delivery", ["edges", "sampled"])
def test_sweep_50_rpm_per_s_simulated_bench(i3, delivery):
    bench = _with_tacho(i3, delivery=delivery)
    orders = (1.0, 1.5, 2.0)
    src = _sim(bench, RpmProfile([ramp(1500.0, 4500.0, 60.0)]))
    frames, events = _track(src.layout, _config(bench, orders), src)
    assert [e.kind for e in events] == ["tacho_sync"]
    # only the first two frames lack the frame one cycle earlier that the leakage correction needs
    assert [("leakage_uncorrected" in f.flags) for f in frames[:3]] == [True, True, False]
    frames = _clean(frames)
    assert len(frames) > 2990
    amp, phase = _errors(frames, src.exact_amplitudes([f.rpm for f in frames], orders))
    assert amp.max() <= 1e-3, amp.max(axis=(0, 2))
    assert phase.max() <= 0.1, phase.max(axis=(0, 2))


def test_sweep_100_rpm_per_s_holds_above_2000_rpm(i3):
    # the stated limit: at twice the rate the 0.1 % holds from 2000 rpm (ramp leakage ~ rate^2 / rpm^3)
    orders = (1.0, 1.5, 2.0)
    src = _sim(i3, RpmProfile([ramp(1500.0, 4500.0, 30.0)]))
    frames = _clean(_track(src.layout, _config(i3, orders), src)[0])
    frames = [f for f in frames if f.rpm >= 2000.0]
    amp, phase = _errors(frames, src.exact_amplitudes([f.rpm for f in frames], orders))
    assert amp.max() <= 1e-3 and phase.max() <= 0.1


def test_noise_scatter_matches_the_window_prediction(i3):
    """40 dB SNR: std of Re and Im of X_h about the exact value vs ``frames.noise_std``.

    Frames one cycle apart do not overlap, so every other frame gives independent samples.
    """
    orders = (1.0, 1.5, 2.0)
    rpm = 3000.0
    src = _sim(i3, RpmProfile([hold(rpm, 24.0)]), noise_snr_db=40.0, seed=4)
    frames = _clean(_track(src.layout, _config(i3, orders), src)[0])[::2]
    x = np.array([f.amplitudes for f in frames])
    err = x - src.exact_amplitudes([f.rpm for f in frames], orders)
    sigma = np.array([src.layout.metadata["noise_std"][c] for c in frames[0].channels])
    predicted = np.array([noise_std(s, 5120.0, rpm, 45.0) for s in sigma])  # per channel
    measured = np.sqrt(0.5 * np.mean(np.abs(err) ** 2, axis=0))  # (n_orders, n_ch)
    ratio = measured / predicted[None, :]
    assert len(frames) > 550
    assert ratio.min() > 1 / 1.5 and ratio.max() < 1.5, ratio.round(2)
    # amplitude and phase scatter follow: |X| by the same std, phase by std / |X| (rad)
    exact = src.exact_amplitudes([rpm], orders)[0]
    big = np.abs(exact) > 20 * predicted[None, :]
    amp_std = np.std(np.abs(x), axis=0)[big]
    ph_std = np.std(np.angle(x / exact[None]), axis=0)[big]
    pred = np.broadcast_to(predicted, exact.shape)[big]
    assert np.all(np.abs(np.log(amp_std / pred)) < math.log(1.5))
    assert np.all(np.abs(np.log(ph_std * np.abs(exact[big]) / pred)) < math.log(1.5))


def _faulty(items: Iterator[StreamItem], t_missing: float, t_extra: float):
    """Drop the first tacho edge after ``t_missing``; add one 40 % into the pitch after ``t_extra``."""
    done = [False, False]
    for item in items:
        if isinstance(item, EdgeBlock) and item.channel == "tacho":
            t = item.times_s
            if not done[0] and t[-1] > t_missing:
                k = int(np.searchsorted(t, t_missing))
                t = np.delete(t, k)
                done[0] = True
            if not done[1] and t[-1] > t_extra and t.size > 2:
                k = int(np.searchsorted(t, t_extra))
                k = min(k, t.size - 2)
                t = np.sort(np.append(t, t[k] + 0.4 * (t[k + 1] - t[k])))
                done[1] = True
            item = EdgeBlock(item.channel, t)
        yield item


def test_missing_and_spurious_edges_in_a_sweep_are_reported_and_healed(i3):
    orders = (1.0, 1.5, 2.0)
    src = _sim(i3, RpmProfile([ramp(1500.0, 4500.0, 60.0)]))
    frames, events = _track(src.layout, _config(i3, orders), _faulty(iter(src), 20.0, 40.0))
    kinds = [e.kind for e in events]
    assert kinds == [
        "tacho_sync",
        "tacho_missing_edge",
        "tacho_sync",
        "tacho_extra_edge",
        "tacho_sync",
    ]
    assert all("uncertain" not in e.message for e in events)
    for t_fault in (20.0, 40.0):
        hit = [f for f in frames if "tacho_resync" in f.flags and abs(f.time_s - t_fault) < 0.2]
        assert hit and all(np.isnan(f.amplitudes).all() and not f.channel_ok.any() for f in hit)
        # no frame centred inside the stretch without angle
        assert all(abs(f.time_s - t_fault) > 0.005 for f in frames)
    good = _clean(frames)
    assert len(good) > 2970  # a handful lost around each fault, out of ~3000
    amp, phase = _errors(good, src.exact_amplitudes([f.rpm for f in good], orders))
    assert amp.max() <= 1e-3 and phase.max() <= 0.1


def test_sampled_tacho_with_a_missing_tooth_resyncs(i3):
    bench = _with_tacho(i3, delivery="sampled")
    orders = (1.0, 1.5, 2.0)
    src = _sim(bench, RpmProfile([ramp(2500.0, 2700.0, 4.0)]))

    def blank_one_tooth(items):
        done = False
        for item in items:
            if (
                isinstance(item, SampleBlock)
                and item.group == "tacho"
                and not done
                and item.first_index >= 400_000
            ):
                data = item.data.copy()
                high = np.flatnonzero(data[0] > 2.5)
                start = high[
                    np.flatnonzero(np.diff(high) > 1)[0] + 1
                ]  # a tooth's first high sample
                end = start + np.flatnonzero(data[0, start:] < 2.5)[0]
                data[0, start - 3 : end + 3] = 0.0
                item = SampleBlock(item.group, item.first_index, data)
                done = True
            yield item

    frames, events = _track(src.layout, _config(bench, orders), blank_one_tooth(iter(src)))
    assert [e.kind for e in events] == ["tacho_sync", "tacho_missing_edge", "tacho_sync"]
    good = _clean(frames)
    amp, phase = _errors(good, src.exact_amplitudes([f.rpm for f in good], orders))
    assert amp.max() <= 1e-3 and phase.max() <= 0.1


@pytest.mark.parametrize("reference", ["cam", "pressure"])
def test_simulated_cam_or_pressure_fixes_the_half_order_sign(i3, reference):
    bench = _with_tacho(i3, phase_reference=reference, cam_angle_deg=30.0)
    orders = (1.0, 1.5)
    # start half a cycle in: the wheel's first gap comes in the exhaust revolution
    src = _sim(bench, RpmProfile([hold(2000.0, 1.5)], phi0_rad=3 * math.pi))
    frames, _ = _track(src.layout, _config(bench, orders), src)
    assert frames and not any("cycle_ambiguous" in f.flags for f in frames)
    amp, phase = _errors(frames, src.exact_amplitudes([f.rpm for f in frames], orders))
    assert amp.max() <= 5e-4 and phase.max() <= 0.05


@pytest.mark.parametrize("kind", ["rpm", "pulses"])
def test_rpm_channel_with_tdc_pulse_and_plain_pulses(i3, kind):
    bench = _with_tacho(i3, kind=kind, teeth=1 if kind == "rpm" else 60, missing=0)
    orders = (1.0, 1.5, 2.0)
    src = _sim(bench, RpmProfile([ramp(2000.0, 2300.0, 6.0)]))
    config = replace(_config(bench, orders), rpm_min=500.0)
    frames = _track(src.layout, config, src)[0]
    frames = [f for f in frames if not f.flags - {"cycle_ambiguous", "angle_ambiguous"}]
    assert len(frames) > 200
    exact = src.exact_amplitudes([f.rpm for f in frames], orders)
    amp, phase = _errors(frames, exact)
    assert amp.max() <= 1e-3
    if kind == "rpm":
        assert phase.max() <= 0.1


@pytest.mark.parametrize("correct", [True, False])
def test_neighbouring_half_orders_rejected_by_60_db_in_a_sweep(correct):
    """Strong H1 and H2 growing as rpm^2, nothing at the half orders: what shows there is leakage."""
    content = OrderContent((1.0, 2.0), (1000.0 + 0j, 600.0j), (2.0, 2.0))
    bench = SyntheticBench(Ramp(1500.0, 4500.0, 60.0), [content], tdc_after_gap_deg=84.0)
    orders = (0.5, 1.0, 1.5, 2.0, 2.5)
    config = OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=84.0), orders=orders, leakage_correction=correct
    )
    frames, _ = _track(bench.layout, config, bench.items(60.0, block_s=0.5))
    frames = [f for f in frames if "leakage_uncorrected" not in f.flags]
    x = np.array([f.amplitudes[:, 0] for f in frames])
    strongest = np.abs(x[:, 1])
    leak = np.abs(x[:, [0, 2, 4]]).max(axis=1) / strongest
    figure = np.array([f.leakage[0] for f in frames])
    if correct:
        assert leak.max() < 1e-4  # 80 dB during the sweep
        # nothing outside the corrected orders: what shows is the error of the power estimate
        assert figure.max() < 2e-4
    else:
        # 1500 rpm, 50 rpm/s: H1 and H2 ramp by 0.5 % per cycle; 1/(2 pi) of that leaks
        assert 1e-4 < leak.max() < 2e-3
        # the frame's leakage figure bounds what leaked, and not loosely
        assert np.all(leak <= figure) and np.all(figure < 2 * leak)


def test_a_bending_amplitude_is_corrected_from_two_earlier_cycles():
    """H1.5 growing as rpm^8 at 60 rpm/s bends by ~1.5 % of itself per cycle (second
    difference): the chord of the previous cycle lags half a cycle and leaks that bend into H1
    and H2; the parabola through two earlier cycles places the ramp at the window's centre."""
    content = OrderContent((1.5,), (1000.0 + 0j,), (8.0,), rpm_ref=600.0)
    bench = SyntheticBench(Ramp(600.0, 900.0, 5.0), [content], tdc_after_gap_deg=84.0)
    config = OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=84.0), orders=(1.0, 1.5, 2.0), rpm_min=300.0
    )
    frames, _ = _track(bench.layout, config, bench.items(5.0, block_s=0.5))
    frames = [f for f in frames if "leakage_uncorrected" not in f.flags]
    x = np.array([f.amplitudes[:, 0] for f in frames])
    leak = np.abs(x[:, [0, 2]]).max(axis=1) / np.abs(x[:, 1])
    # the stream's second cycle has one earlier cycle: the chord, 1.4e-3
    assert np.all(leak[:2] > 1e-3)
    # from then on the parabola: 1.9e-4 at worst (the chord throughout: 1.35e-3)
    assert leak[2:].max() < 3e-4
