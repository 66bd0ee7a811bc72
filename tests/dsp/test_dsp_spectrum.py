"""The full half-order spectrum of one channel (``OrderTrackerConfig.spectrum_channel``).

Against independent results: the closed-form order content of :mod:`dsp.synthetic`
signals, and, at constant speed, the FFT of the signal resampled onto a uniform
crank-angle grid over one 720 deg cycle (band-limited interpolation of a record that
holds a whole number of cycles: exact for these signals, and sharing nothing with
the tracker's window, carriers or sums).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest
from support.spectrum_streams import (
    N_SPEC,
    TDC,
    SpectrumStream,
    fft_of_the_angle_grid,
    frame_fields,
    pressure_like,
    spectrum_config,
    spectrum_truth,
    track_frames,
)

from acquisition.stream import (
    ChannelSpec,
    SampleBlock,
    SampleGroup,
    StreamItem,
    StreamLayout,
)
from dsp.config import OrderTrackerConfig
from dsp.errors import DspConfigError
from dsp.orders import OrderTracker
from dsp.synthetic import OrderContent, Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig

# -- constant speed ------------------------------------------------------------------------------


@pytest.mark.parametrize("placement", ["accel", "own"])
def test_constant_speed_spectrum_is_the_truth_and_the_fft_of_the_angle_grid(placement):
    rng = np.random.default_rng(2)
    content = pressure_like(rng)
    # 2500 rpm: a cycle is 245.76 samples at 5120 Hz; 25 cycles are 6144 samples exactly
    stream = SpectrumStream(Ramp(2500.0, 2500.0, 1.2), content, placement, own_rate_hz=6400.0)
    frames = track_frames(stream.layout, stream.items(1.2), spectrum_config())
    frames = [f for f in frames if not f.flags]
    assert len(frames) > 30
    truth = spectrum_truth(content, 2500.0)
    scale = np.abs(truth[1:]).max()
    err = max(np.abs(f.spectrum - truth).max() for f in frames) / scale
    assert all(f.spectrum.shape == (N_SPEC,) and f.spectrum_channel == "p" for f in frames)
    assert all(f.spectrum[0].imag == 0.0 for f in frames)
    fft = fft_of_the_angle_grid(stream, 25, 10)
    fft_err = max(np.abs(f.spectrum - fft).max() for f in frames) / scale
    print(f"\nconstant speed ({placement}): {err:.1e} from the truth, {fft_err:.1e} from the FFT")
    assert np.abs(fft - truth).max() < 1e-9 * scale  # the reference is exact for this signal
    # measured 1.1e-6 at 5120 Hz, growing with the order (0.5 .. 6: 2e-8 .. 1.1e-6): the
    # single-precision carrier angle, ~1e-7 rad times the order (2e-7 at 25.6 kHz)
    assert err < 2e-6
    assert fft_err < 2e-6


@pytest.mark.parametrize("correct", [False, True])
def test_a_constant_gives_its_value_at_index_zero(correct):
    """The mean has the window's own normalisation: exact to rounding. The other orders
    show the carriers' single-precision angle (~3e-7 of the constant); the sweep
    correction passes a little of that, as ramps, back to the mean."""
    content = OrderContent((0.0,), (3.25 + 0j,), (0.0,))
    stream = SpectrumStream(Ramp(1800.0, 3600.0, 2.0), content)
    config = spectrum_config(leakage_correction=correct)
    frames = track_frames(stream.layout, stream.items(2.0), config)
    frames = [f for f in frames if not f.flags - {"leakage_uncorrected"}]
    assert len(frames) > 70
    for f in frames:
        assert f.spectrum[0].imag == 0.0
        assert abs(f.spectrum[0].real - 3.25) < (3e-8 if correct else 1e-14) * 3.25
        assert np.abs(f.spectrum[1:]).max() < 1e-6 * 3.25
        assert f.spectrum_at(0.0) == f.spectrum[0] and f.spectrum_at(6.0) == f.spectrum[-1]


# -- sweep ---------------------------------------------------------------------------------------


def _sweep_errors(correct: bool, content: OrderContent, placement: str = "accel") -> np.ndarray:
    """Worst error of each frame over the spectrum, relative to its largest harmonic."""
    stream = SpectrumStream(Ramp(1500.0, 4500.0, 20.0), content, placement)
    config = spectrum_config(leakage_correction=correct)
    frames = track_frames(stream.layout, stream.items(20.0, block_s=0.5), config)
    frames = [f for f in frames if not f.flags - {"leakage_uncorrected"}]
    if correct:
        frames = frames[2:]  # the two frames that take a chord (the 2nd) or nothing (the 1st)
    assert len(frames) > 900
    out = []
    for f in frames:
        truth = spectrum_truth(content, f.rpm)
        out.append(np.abs(f.spectrum - truth).max() / np.abs(truth[1:]).max())
    return np.array(out)


@pytest.mark.parametrize("placement", ["accel", "own"])
def test_sweep_1500_to_4500_rpm_in_20_s_with_ramping_harmonics(placement):
    """Amplitudes ramp as rpm^0 .. rpm^2: 150 rpm/s, at 1500 rpm 1.6 % per cycle. Measured:
    6e-5 of the largest harmonic at worst (at 1500 rpm; median 9e-6), 1.4e-2 uncorrected."""
    content = pressure_like(np.random.default_rng(3), powers=(0.0, 2.0))
    corrected = _sweep_errors(True, content, placement)
    raw = _sweep_errors(False, content, placement)
    print(f"\nsweep ({placement}): worst {corrected.max():.2e} corrected, {raw.max():.2e} not")
    assert corrected.max() < 1e-4
    assert raw.max() > 1e-3  # what the correction is for
    assert raw.max() > 50 * corrected.max()


def test_a_ramping_mean_and_order_half_do_not_leak_into_each_other():
    """A large mean growing as rpm^2 (a pressure offset) beside a small order 0.5, and the
    other way round: order 0 is corrected and corrects, as any half order."""
    for mean, half in ((100.0, 1.0), (1.0, 100.0)):
        content = OrderContent((0.0, 0.5), (mean + 0j, half * 1j), (2.0, 2.0))
        stream = SpectrumStream(Ramp(1500.0, 4500.0, 20.0), content)
        for correct, bound in ((True, 2e-5), (False, 1.0)):
            frames = track_frames(
                stream.layout,
                stream.items(20.0, block_s=0.5),
                spectrum_config(leakage_correction=correct),
            )
            frames = [f for f in frames if not f.flags - {"leakage_uncorrected"}][2:]
            small = 0 if mean < half else 1  # the index that the other one leaks into
            err = max(
                abs(f.spectrum[small] - spectrum_truth(content, f.rpm)[small])
                / abs(spectrum_truth(content, f.rpm)[small])
                for f in frames
            )
            if correct:
                assert err < bound, (mean, half, err)
            else:
                assert err > 0.05, (mean, half, err)  # 2 x 0.16 of a 1.6 % ramp of 100


# -- the other fields stay as they were ----------------------------------------------------------


def test_existing_fields_are_bit_identical_with_and_without_a_spectrum():
    """Pressure as the cycle reference, in a sweep; the spectrum on that very channel, on
    an accelerometer, and on a channel of a group of its own."""
    rng = np.random.default_rng(4)
    bench = SyntheticBench(
        Ramp(1500.0, 4500.0, 4.0), [random_content(rng) for _ in range(3)],
        tdc_after_gap_deg=TDC, pressure=True,
    )  # fmt: skip
    own = SampleGroup("cyl", 6000.0, (ChannelSpec("p2", "bar"),))
    layout = StreamLayout((*bench.layout.groups, own), bench.layout.edge_channels)

    def items() -> Iterator[StreamItem]:
        done = 0
        for item in bench.items(4.0, block_s=0.1):
            yield item
            if isinstance(item, SampleBlock):
                upto = math.ceil((item.first_index + item.n_samples) / bench.rate_hz * 6000.0)
                t = np.arange(done, upto) / 6000.0
                yield SampleBlock("cyl", done, bench.pressure_bar(t)[None, :])
                done = upto

    config = OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=TDC, phase_reference="pressure"),
        orders=(0.5, 1.0, 1.5, 2.0),
        channels=("a0", "a1", "a2"),
    )
    reference = [frame_fields(f) for f in track_frames(layout, items(), config)]
    assert len(reference) > 150
    for channel in ("p_cyl1", "a1", "p2"):
        frames = track_frames(layout, items(), replace(config, spectrum_channel=channel))
        assert [frame_fields(f) for f in frames] == reference, channel
        assert all(f.spectrum is not None and f.spectrum_channel == channel for f in frames)
    for f in frames:
        assert f.spectrum is None or np.isfinite(f.spectrum).all()


def test_random_block_splits_give_the_same_spectrum():
    content = pressure_like(np.random.default_rng(5), powers=(0.0, 2.0))
    stream = SpectrumStream(Ramp(1500.0, 3000.0, 2.0), content, "own")
    one = list(stream.items(2.0, block_s=2.0))
    reference = track_frames(stream.layout, one, spectrum_config())
    rng = np.random.default_rng(8)
    split: list[StreamItem] = []
    for item in stream.items(2.0, block_s=0.05):
        if isinstance(item, SampleBlock):
            cuts = np.sort(rng.choice(np.arange(1, item.n_samples), 6, replace=False))
            for a, b in zip([0, *cuts], [*cuts, item.n_samples], strict=True):
                split.append(SampleBlock(item.group, item.first_index + a, item.data[:, a:b]))
        else:
            split.append(item)
    frames = track_frames(stream.layout, split, spectrum_config())
    assert len(frames) == len(reference) > 40
    for a, b in zip(frames, reference, strict=True):
        assert a.crank_angle_rad == b.crank_angle_rad
        np.testing.assert_allclose(a.spectrum, b.spectrum, rtol=0, atol=1e-9 * 3)


# -- faults --------------------------------------------------------------------------------------


@pytest.mark.parametrize("placement", ["accel", "own"])
def test_nan_samples_or_a_gap_nan_the_spectrum_of_their_frames_only(placement):
    content = pressure_like(np.random.default_rng(6))
    stream = SpectrumStream(Ramp(3000.0, 3000.0, 2.0), content, placement)
    clean = list(stream.items(2.0))
    group = "accel" if placement == "accel" else "cyl"
    row = 2 if placement == "accel" else 0
    rate = stream.bench.rate_hz if placement == "accel" else stream.own_rate_hz
    faulty: list[StreamItem] = []
    t_nan, t_gap = 0.6, 1.3
    for item in clean:
        if isinstance(item, SampleBlock) and item.group == group:
            t0, t1 = item.first_index / rate, (item.first_index + item.n_samples) / rate
            if t0 <= t_nan < t1:
                data = item.data.copy()
                data[row, round((t_nan - t0) * rate)] = np.nan
                item = SampleBlock(item.group, item.first_index, data)
            if placement == "own" and t0 <= t_gap + 0.05 < t1:
                continue  # a lost block of the spectrum's own group
        faulty.append(item)
    reference = track_frames(stream.layout, clean, spectrum_config())
    frames = track_frames(stream.layout, faulty, spectrum_config())
    assert [frame_fields(f) for f in frames] == [
        frame_fields(f) for f in reference
    ]  # nothing else moved
    half = (360 + 45 / 2) / (3000 * 6)  # the window reaches 360 deg + taper/2 each side (s)
    gaps = [(t_nan, half)]
    if placement == "own":
        gaps.append((t_gap + 0.05, 0.05 + half))  # the block [1.3, 1.4) s
    margin = 1e-3  # s: frames whose window ends that near a fault are not judged
    n_hit = 0
    for f in frames:
        d = min(abs(f.time_s - t) - w for t, w in gaps)
        if d < -margin:
            assert np.isnan(f.spectrum).all()
            n_hit += 1
        elif d > margin and not f.flags:
            assert np.isfinite(f.spectrum).all()
    assert n_hit >= (2 if placement == "accel" else 8)
    last = frames[-1]
    assert last.time_s > 1.8 and np.isfinite(last.spectrum).all()  # and the stream went on


def test_a_spectrum_group_that_starts_late_gives_nan_until_it_covers_the_window():
    content = pressure_like(np.random.default_rng(7))
    stream = SpectrumStream(Ramp(3000.0, 3000.0, 2.0), content, "own")
    late = [
        i for i in stream.items(2.0) if not (isinstance(i, SampleBlock) and i.group == "cyl")
        or i.first_index / stream.own_rate_hz >= 0.5
    ]  # fmt: skip
    frames = track_frames(stream.layout, late, spectrum_config())
    reference = track_frames(stream.layout, stream.items(2.0), spectrum_config())
    assert [frame_fields(f) for f in frames] == [frame_fields(f) for f in reference]
    for f in frames:
        covered = stream.ramp.t_of_phi(f.crank_angle_rad - math.radians(360 + 22.5)) >= 0.5
        assert np.isfinite(f.spectrum).all() == covered


# -- configuration -------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"spectrum_channel": "p_cyl9"}, r"spectrum channel 'p_cyl9' is not in the source; it has: a0, a1, p"),
        ({"spectrum_max_order": 0.0}, "spectrum_max_order: expected a positive multiple of 0.5, got 0.0"),
        ({"spectrum_max_order": -1.0}, "positive multiple of 0.5, got -1.0"),
        ({"spectrum_max_order": 2.25}, "positive multiple of 0.5, got 2.25"),
        ({"spectrum_max_order": math.nan}, "positive multiple of 0.5, got nan"),
        ({"spectrum_max_order": math.inf}, "positive multiple of 0.5, got inf"),
        ({"spectrum_max_order": 52.0}, "spectrum order 52 at 6000 rpm is 5200.0 Hz, at or above"),
        ({"spectrum_channel": ""}, "spectrum_channel: expected a channel name or None"),
    ],
)  # fmt: skip
def test_spectrum_configurations_that_cannot_work_raise_one_line(kwargs, message):
    stream = SpectrumStream(Ramp(3000.0, 3000.0, 1.0), pressure_like(np.random.default_rng(0)))
    with pytest.raises(DspConfigError, match=message) as info:
        OrderTracker.from_layout(stream.layout, spectrum_config(**kwargs))
    assert "\n" not in str(info.value)


def test_without_a_spectrum_channel_frames_carry_none():
    stream = SpectrumStream(Ramp(3000.0, 3000.0, 1.0), pressure_like(np.random.default_rng(0)))
    frames = track_frames(stream.layout, stream.items(1.0), spectrum_config(spectrum_channel=None))
    assert frames and all(f.spectrum is None and f.spectrum_channel is None for f in frames)
    with pytest.raises(ValueError, match="no spectrum"):
        frames[0].spectrum_at(1.0)
