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
from support.mcap_logs import BENCH_TEXT, make_outcome

from acquisition.stream import (
    ChannelSpec,
    SampleBlock,
    SampleGroup,
    StreamItem,
    StreamLayout,
)
from dsp.config import OrderTrackerConfig
from dsp.errors import DspConfigError
from dsp.frames import OrderFrame
from dsp.orders import OrderTracker
from dsp.synthetic import OrderContent, Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig
from replay import results_codec as codec
from replay import wire
from replay.reader import open_log
from replay.recorder import McapRecorder
from replay.recording_head import RecordingInfo
from replay.schemas import message_class

TDC = 84.0
CAM = 30.0
MAX_ORDER = 6.0
N_SPEC = round(2 * MAX_ORDER) + 1


def _pressure_like(rng: np.random.Generator, powers: tuple[float, float] = (0.0, 0.0)):
    """A mean and every half order 0.5 .. 10, amplitudes falling with the order (as a
    cylinder pressure's do): 3 at order 0.5 down to ~0.1 at order 10."""
    orders = tuple(float(h) for h in np.arange(0.5, 10.01, 0.5))
    amps = (1.0 + 2.0 * rng.random(len(orders))) * np.exp(2j * np.pi * rng.random(len(orders)))
    amps /= 1.0 + 0.5 * np.arange(len(orders))
    pw = tuple(rng.uniform(*powers, len(orders) + 1))
    return OrderContent((0.0, *orders), (5.0 + 0j, *amps), pw)


def _truth(content: OrderContent, rpm: float) -> np.ndarray:
    """The spectrum the tracker should give at ``rpm``: (N_SPEC,) complex."""
    amps = content.at(np.array([rpm]))[0]
    out = np.zeros(N_SPEC, complex)
    for h, a in zip(content.orders, amps, strict=True):
        k = round(2 * h)
        if k < N_SPEC:
            out[k] = a.real if k == 0 else a
    return out


class SpectrumStream:
    """Two accelerometers and a channel ``p`` with ``content``, in the accelerometers'
    group (``placement="accel"``) or in a group ``cyl`` of its own at another rate."""

    def __init__(
        self,
        ramp: Ramp,
        content: OrderContent,
        placement: str = "accel",
        rate_hz: float = 5120.0,
        own_rate_hz: float = 7000.0,
        seed: int = 1,
    ) -> None:
        rng = np.random.default_rng(seed)
        self.ramp, self.content, self.placement = ramp, content, placement
        accel = [random_content(rng) for _ in range(2)]
        contents = [*accel, content] if placement == "accel" else accel
        names = ["a0", "a1", "p"] if placement == "accel" else ["a0", "a1"]
        self.bench = SyntheticBench(
            ramp, contents, rate_hz=rate_hz, tdc_after_gap_deg=TDC, cam_angle_deg=CAM,
            channel_names=names,
        )  # fmt: skip
        self.own_rate_hz = own_rate_hz

    @property
    def layout(self) -> StreamLayout:
        base = self.bench.layout
        if self.placement == "accel":
            return base
        own = SampleGroup("cyl", self.own_rate_hz, (ChannelSpec("p", "bar"),))
        return StreamLayout((*base.groups, own), base.edge_channels)

    def signal(self, t: np.ndarray) -> np.ndarray:
        amps = self.content.at(self.ramp.rpm(t))
        h = np.asarray(self.content.orders)
        return np.real(amps * np.exp(1j * self.ramp.phi(t)[:, None] * h[None, :])).sum(axis=1)

    def items(self, duration: float, block_s: float = 0.1) -> Iterator[StreamItem]:
        done = 0  # samples of the own group sent
        for item in self.bench.items(duration, block_s=block_s):
            yield item
            if self.placement == "accel" or not isinstance(item, SampleBlock):
                continue
            t_end = (item.first_index + item.n_samples) / self.bench.rate_hz
            upto = math.ceil(t_end * self.own_rate_hz)
            if upto > done:
                t = np.arange(done, upto) / self.own_rate_hz
                yield SampleBlock("cyl", done, self.signal(t)[None, :])
                done = upto


def _config(**kw) -> OrderTrackerConfig:
    kw.setdefault("spectrum_channel", "p")
    kw.setdefault("spectrum_max_order", MAX_ORDER)
    return OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=TDC, phase_reference="cam", cam_angle_deg=CAM),
        orders=(1.0, 1.5, 2.0),
        channels=("a0", "a1"),
        rpm_max=6000.0,
        **kw,
    )


def _track(layout: StreamLayout, items, config: OrderTrackerConfig) -> list[OrderFrame]:
    tracker = OrderTracker.from_layout(layout, config)
    frames: list[OrderFrame] = []
    for item in items:
        frames += tracker.process(item)[0]
    return frames


def _fft_of_the_angle_grid(stream: SpectrumStream, n_cycles: int, cycle: int) -> np.ndarray:
    """Spectrum of cycle ``cycle`` (crank angle 720 deg x cycle .. + 720 deg) by resampling.

    At constant speed a record of ``n_cycles`` whole cycles is periodic, so its DFT
    interpolates it exactly (band-limited) at any time: that gives the signal on a
    uniform grid of 512 crank angles over the cycle, whose FFT is the spectrum. The
    grid starts at a multiple of 720 deg, so the phases are those of the absolute
    crank angle, as the tracker's; and any whole cycle of a periodic signal has the
    spectrum of any other.
    """
    ramp = stream.ramp
    rate = stream.bench.rate_hz if stream.placement == "accel" else stream.own_rate_hz
    n = round(n_cycles * 120.0 / ramp.rpm0 * rate)
    assert abs(n - n_cycles * 120.0 / ramp.rpm0 * rate) < 1e-9, "not a whole number of samples"
    x = stream.signal(np.arange(n) / rate)
    c = np.fft.rfft(x) / n
    grid = 512
    phi = 4.0 * math.pi * (cycle + np.arange(grid) / grid)
    t = ramp.t_of_phi(phi)
    bins = np.arange(c.size)
    weight = np.where((bins == 0) | (2 * bins == n), 1.0, 2.0)  # both halves of the spectrum
    on_grid = np.real(np.exp(2j * np.pi * np.outer(t * rate / n, bins)) @ (weight * c))
    f = np.fft.fft(on_grid) / grid
    spectrum = 2.0 * f[:N_SPEC]  # exp(-i (k/2) phi_n) = exp(-2 pi i k n / grid)
    spectrum[0] = f[0].real
    return spectrum


# -- constant speed ------------------------------------------------------------------------------


@pytest.mark.parametrize("placement", ["accel", "own"])
def test_constant_speed_spectrum_is_the_truth_and_the_fft_of_the_angle_grid(placement):
    rng = np.random.default_rng(2)
    content = _pressure_like(rng)
    # 2500 rpm: a cycle is 245.76 samples at 5120 Hz; 25 cycles are 6144 samples exactly
    stream = SpectrumStream(Ramp(2500.0, 2500.0, 1.2), content, placement, own_rate_hz=6400.0)
    frames = _track(stream.layout, stream.items(1.2), _config())
    frames = [f for f in frames if not f.flags]
    assert len(frames) > 30
    truth = _truth(content, 2500.0)
    scale = np.abs(truth[1:]).max()
    err = max(np.abs(f.spectrum - truth).max() for f in frames) / scale
    assert all(f.spectrum.shape == (N_SPEC,) and f.spectrum_channel == "p" for f in frames)
    assert all(f.spectrum[0].imag == 0.0 for f in frames)
    fft = _fft_of_the_angle_grid(stream, 25, 10)
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
    config = _config(leakage_correction=correct)
    frames = _track(stream.layout, stream.items(2.0), config)
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
    config = _config(leakage_correction=correct)
    frames = _track(stream.layout, stream.items(20.0, block_s=0.5), config)
    frames = [f for f in frames if not f.flags - {"leakage_uncorrected"}]
    if correct:
        frames = frames[2:]  # the two frames that take a chord (the 2nd) or nothing (the 1st)
    assert len(frames) > 900
    out = []
    for f in frames:
        truth = _truth(content, f.rpm)
        out.append(np.abs(f.spectrum - truth).max() / np.abs(truth[1:]).max())
    return np.array(out)


@pytest.mark.parametrize("placement", ["accel", "own"])
def test_sweep_1500_to_4500_rpm_in_20_s_with_ramping_harmonics(placement):
    """Amplitudes ramp as rpm^0 .. rpm^2: 150 rpm/s, at 1500 rpm 1.6 % per cycle. Measured:
    6e-5 of the largest harmonic at worst (at 1500 rpm; median 9e-6), 1.4e-2 uncorrected."""
    content = _pressure_like(np.random.default_rng(3), powers=(0.0, 2.0))
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
            frames = _track(
                stream.layout, stream.items(20.0, block_s=0.5), _config(leakage_correction=correct)
            )
            frames = [f for f in frames if not f.flags - {"leakage_uncorrected"}][2:]
            small = 0 if mean < half else 1  # the index that the other one leaks into
            err = max(
                abs(f.spectrum[small] - _truth(content, f.rpm)[small])
                / abs(_truth(content, f.rpm)[small])
                for f in frames
            )
            if correct:
                assert err < bound, (mean, half, err)
            else:
                assert err > 0.05, (mean, half, err)  # 2 x 0.16 of a 1.6 % ramp of 100


# -- the other fields stay as they were ----------------------------------------------------------


def _fields(f: OrderFrame) -> tuple:
    arrays = (f.amplitudes, f.channel_ok, f.leakage)
    return (
        f.time_s, f.rpm, f.crank_angle_rad, f.orders, f.channels, f.rpm_change, f.flags,
        *(np.asarray(a).tobytes() for a in arrays),
    )  # fmt: skip


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
    reference = [_fields(f) for f in _track(layout, items(), config)]
    assert len(reference) > 150
    for channel in ("p_cyl1", "a1", "p2"):
        frames = _track(layout, items(), replace(config, spectrum_channel=channel))
        assert [_fields(f) for f in frames] == reference, channel
        assert all(f.spectrum is not None and f.spectrum_channel == channel for f in frames)
    for f in frames:
        assert f.spectrum is None or np.isfinite(f.spectrum).all()


def test_random_block_splits_give_the_same_spectrum():
    content = _pressure_like(np.random.default_rng(5), powers=(0.0, 2.0))
    stream = SpectrumStream(Ramp(1500.0, 3000.0, 2.0), content, "own")
    one = list(stream.items(2.0, block_s=2.0))
    reference = _track(stream.layout, one, _config())
    rng = np.random.default_rng(8)
    split: list[StreamItem] = []
    for item in stream.items(2.0, block_s=0.05):
        if isinstance(item, SampleBlock):
            cuts = np.sort(rng.choice(np.arange(1, item.n_samples), 6, replace=False))
            for a, b in zip([0, *cuts], [*cuts, item.n_samples], strict=True):
                split.append(SampleBlock(item.group, item.first_index + a, item.data[:, a:b]))
        else:
            split.append(item)
    frames = _track(stream.layout, split, _config())
    assert len(frames) == len(reference) > 40
    for a, b in zip(frames, reference, strict=True):
        assert a.crank_angle_rad == b.crank_angle_rad
        np.testing.assert_allclose(a.spectrum, b.spectrum, rtol=0, atol=1e-9 * 3)


# -- faults --------------------------------------------------------------------------------------


@pytest.mark.parametrize("placement", ["accel", "own"])
def test_nan_samples_or_a_gap_nan_the_spectrum_of_their_frames_only(placement):
    content = _pressure_like(np.random.default_rng(6))
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
    reference = _track(stream.layout, clean, _config())
    frames = _track(stream.layout, faulty, _config())
    assert [_fields(f) for f in frames] == [_fields(f) for f in reference]  # nothing else moved
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
    content = _pressure_like(np.random.default_rng(7))
    stream = SpectrumStream(Ramp(3000.0, 3000.0, 2.0), content, "own")
    late = [
        i for i in stream.items(2.0) if not (isinstance(i, SampleBlock) and i.group == "cyl")
        or i.first_index / stream.own_rate_hz >= 0.5
    ]  # fmt: skip
    frames = _track(stream.layout, late, _config())
    reference = _track(stream.layout, stream.items(2.0), _config())
    assert [_fields(f) for f in frames] == [_fields(f) for f in reference]
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
    stream = SpectrumStream(Ramp(3000.0, 3000.0, 1.0), _pressure_like(np.random.default_rng(0)))
    with pytest.raises(DspConfigError, match=message) as info:
        OrderTracker.from_layout(stream.layout, _config(**kwargs))
    assert "\n" not in str(info.value)


def test_without_a_spectrum_channel_frames_carry_none():
    stream = SpectrumStream(Ramp(3000.0, 3000.0, 1.0), _pressure_like(np.random.default_rng(0)))
    frames = _track(stream.layout, stream.items(1.0), _config(spectrum_channel=None))
    assert frames and all(f.spectrum is None and f.spectrum_channel is None for f in frames)
    with pytest.raises(ValueError, match="no spectrum"):
        frames[0].spectrum_at(1.0)


# -- recording -----------------------------------------------------------------------------------


def _frames_to_record() -> list[OrderFrame]:
    content = _pressure_like(np.random.default_rng(9), powers=(0.0, 2.0))
    stream = SpectrumStream(Ramp(2000.0, 2600.0, 1.0), content)
    frames = _track(stream.layout, stream.items(1.0), _config())[:6]
    edge = np.linspace(-1, 1, N_SPEC) + 1j * np.linspace(1, -1, N_SPEC)
    edge[0], edge[1], edge[2] = complex(-0.0, 0.0), complex(np.nan, np.nan), complex(np.inf, -0.0)
    frames.append(replace(frames[0], spectrum=edge, spectrum_channel="é"))
    frames.append(replace(frames[0], spectrum=None, spectrum_channel=None))
    return frames


def test_frames_with_and_without_spectrum_encode_as_the_protobuf_built_ones():
    cls = message_class("OrderFrame")
    for f in _frames_to_record():
        fast, reference = codec.encode_frame(f), codec.encode_frame_reference(f)
        assert cls.FromString(fast).SerializeToString() == reference
        back = codec.decode_frame(fast)
        assert _fields(back) == _fields(f)
        if f.spectrum is None:
            assert back.spectrum is None and back.spectrum_channel is None
        else:
            assert back.spectrum.tobytes() == np.asarray(f.spectrum, complex).tobytes()
            assert back.spectrum_channel == f.spectrum_channel


def test_a_frame_without_spectrum_is_the_bytes_of_a_recording_made_before_it_existed():
    f = replace(_frames_to_record()[0], spectrum=None, spectrum_channel=None)
    fast = codec.encode_frame(f)
    msg = message_class("OrderFrame").FromString(fast)
    assert not msg.spectrum_re and not msg.spectrum_im and not msg.spectrum_channel
    # an old writer's message: no field past 12
    old = message_class("OrderFrame")()
    old.CopyFrom(msg)
    old.ClearField("spectrum_channel")
    assert old.SerializeToString() == fast
    assert codec.decode_frame(old.SerializeToString()).spectrum is None


def test_a_spectrum_of_the_wrong_length_is_refused():
    f = _frames_to_record()[0]
    codec.encode_frame(f)
    with pytest.raises(ValueError, match="spectrum of shape"):
        wire.frame_wire(f.orders, f.channels, "p", N_SPEC).encode(
            replace(f, spectrum=f.spectrum[:-1])
        )


def test_spectrum_round_trips_through_an_mcap_file(tmp_path):
    frames = _frames_to_record()
    stream = SpectrumStream(Ramp(2000.0, 2600.0, 1.0), _pressure_like(np.random.default_rng(9)))
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path)
    rec.start(RecordingInfo(layout=stream.layout, bench_text=BENCH_TEXT))
    for item in stream.items(0.2):
        rec.on_item(item)
    for f in frames:
        rec.on_frame(f, make_outcome(f, used=True))
    rec.close(None)
    got = list(open_log(path).frames())
    assert len(got) == len(frames)
    for a, b in zip(got, frames, strict=True):
        assert _fields(a) == _fields(b)
        assert a.spectrum_channel == b.spectrum_channel
        if b.spectrum is None:
            assert a.spectrum is None
        else:
            assert a.spectrum.tobytes() == np.asarray(b.spectrum, complex).tobytes()
