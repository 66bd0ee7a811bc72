"""The spectrum tests' streams (tests/dsp/test_dsp_spectrum*.py): a channel with a
cylinder pressure's order content beside two accelerometers, its true spectrum, the
tracker's settings and run, and the independent spectrum of the crank-angle grid."""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np

from acquisition.stream import ChannelSpec, SampleBlock, SampleGroup, StreamItem, StreamLayout
from dsp.config import OrderTrackerConfig
from dsp.frames import OrderFrame
from dsp.orders import OrderTracker
from dsp.synthetic import OrderContent, Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig

TDC = 84.0
CAM = 30.0
MAX_ORDER = 6.0
N_SPEC = round(2 * MAX_ORDER) + 1


def pressure_like(rng: np.random.Generator, powers: tuple[float, float] = (0.0, 0.0)):
    """A mean and every half order 0.5 .. 10, amplitudes falling with the order (as a
    cylinder pressure's do): 3 at order 0.5 down to ~0.1 at order 10."""
    orders = tuple(float(h) for h in np.arange(0.5, 10.01, 0.5))
    amps = (1.0 + 2.0 * rng.random(len(orders))) * np.exp(2j * np.pi * rng.random(len(orders)))
    amps /= 1.0 + 0.5 * np.arange(len(orders))
    pw = tuple(rng.uniform(*powers, len(orders) + 1))
    return OrderContent((0.0, *orders), (5.0 + 0j, *amps), pw)


def spectrum_truth(content: OrderContent, rpm: float) -> np.ndarray:
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


def spectrum_config(**kw) -> OrderTrackerConfig:
    kw.setdefault("spectrum_channel", "p")
    kw.setdefault("spectrum_max_order", MAX_ORDER)
    return OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=TDC, phase_reference="cam", cam_angle_deg=CAM),
        orders=(1.0, 1.5, 2.0),
        channels=("a0", "a1"),
        rpm_max=6000.0,
        **kw,
    )


def track_frames(layout: StreamLayout, items, config: OrderTrackerConfig) -> list[OrderFrame]:
    tracker = OrderTracker.from_layout(layout, config)
    frames: list[OrderFrame] = []
    for item in items:
        frames += tracker.process(item)[0]
    return frames


def fft_of_the_angle_grid(stream: SpectrumStream, n_cycles: int, cycle: int) -> np.ndarray:
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


def frame_fields(f: OrderFrame) -> tuple:
    """Every field of a frame but the spectrum's, arrays as their bytes."""
    arrays = (f.amplitudes, f.channel_ok, f.leakage)
    return (
        f.time_s, f.rpm, f.crank_angle_rad, f.orders, f.channels, f.rpm_change, f.flags,
        *(np.asarray(a).tobytes() for a in arrays),
    )  # fmt: skip
