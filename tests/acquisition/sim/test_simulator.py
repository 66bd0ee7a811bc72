"""The simulated bench: order content, tacho angles, interpolation, noise, determinism, blocks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from acquisition.sim import kernels
from acquisition.sim.amplitude_table import AmplitudeTable
from acquisition.sim.simulator import SimulatedBench
from acquisition.sim.sweep import RpmProfile, hold, ramp
from acquisition.sim.synthesis import half_orders, synthesize_accel
from acquisition.stream import EdgeBlock, SampleBlock, SourceError
from ptinertia.config import ElasticMode, Tacho, parse_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.sources import open_source
from ptinertia.to_acquisition import tacho_spec
from ptinertia.to_physics import build_simulated_model

W = 2 * math.pi / 60
I3 = EXAMPLES_DIR / "i3-bench.toml"


class FakeModel:
    """Mass line through a rigid-body mode plus a sharp elastic resonance, every channel."""

    def __init__(self, n_ch: int = 4, f_el: float = 150.0, zeta: float = 0.01) -> None:
        rng = np.random.default_rng(0)
        self.channel_names = tuple(f"ch{i}" for i in range(n_ch))
        self._a = rng.normal(size=(24, n_ch)) + 1j * rng.normal(size=(24, n_ch))
        self._b = rng.normal(size=(24, n_ch)) + 1j * rng.normal(size=(24, n_ch))
        self.f_el, self.zeta = f_el, zeta

    def channel_amplitudes(self, rpm: np.ndarray, orders: np.ndarray) -> np.ndarray:
        h = np.asarray(orders, dtype=float)
        w = np.asarray(rpm, dtype=float)[:, None] * W * h[None, :]
        idx = np.round(2 * h).astype(int) - 1
        wr, wn = 2 * np.pi * 10.0, 2 * np.pi * self.f_el
        rigid = w**2 / (w**2 - wr**2 * (1 + 0.12j))
        elastic = w**2 / (wn**2 - w**2 + 2j * self.zeta * wn * w)
        return rigid[..., None] * self._a[idx][None] + elastic[..., None] * self._b[idx][None]

    def pressure(self, phi: np.ndarray) -> None:
        return None


def collect(source) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Concatenate every group's samples and every edge channel's times (checking contiguity)."""
    samples: dict[str, list[np.ndarray]] = {}
    edges: dict[str, list[np.ndarray]] = {}
    next_index: dict[str, int] = {}
    for item in source:
        if isinstance(item, SampleBlock):
            assert item.first_index == next_index.get(item.group, 0)
            next_index[item.group] = item.first_index + item.n_samples
            samples.setdefault(item.group, []).append(item.data)
        elif isinstance(item, EdgeBlock):
            edges.setdefault(item.channel, []).append(item.times_s)
    return (
        {k: np.concatenate(v, axis=1) for k, v in samples.items()},
        {k: np.concatenate(v) for k, v in edges.items()},
    )


def test_order_content_at_a_hold_equals_the_model(i3) -> None:
    # ramp then hold: the hold starts at an angle that the test computes in closed form
    r0, r1, t_ramp = 1500.0, 3000.0, 0.5
    profile = RpmProfile([ramp(r0, r1, t_ramp), hold(r1, 0.6)])
    src = open_source("sim", i3, accel_rate_hz=8192, profile=profile)
    data, _ = collect(src)
    x = data["accel"]
    t = np.arange(x.shape[1]) / 8192
    phi_hold0 = 0.5 * (r0 + r1) * W * t_ramp
    cycle = 4 * math.pi / (r1 * W)  # 720 deg
    sel = (t >= t_ramp) & (t < t_ramp + 10 * cycle)
    phi = phi_hold0 + r1 * W * (t[sel] - t_ramp)
    h = half_orders(6.0)
    design = np.concatenate([np.cos(np.outer(phi, h)), -np.sin(np.outer(phi, h))], axis=1)
    coef, *_ = np.linalg.lstsq(design, x[:, sel].T, rcond=None)
    fitted = coef[: h.size] + 1j * coef[h.size :]
    exact = src.exact_amplitudes(np.array([r1]), h)[0]
    rel = np.abs(fitted - exact).max(axis=0) / np.abs(exact).max(axis=0)
    assert rel.max() < 1e-6
    # and it is not trivially small: every channel carries several orders
    assert np.all((np.abs(exact) > 1e-3 * np.abs(exact).max(axis=0)).sum(axis=0) >= 3)


@pytest.mark.parametrize("model_kind", ["fake", "real_elastic"])
def test_table_interpolation_error_below_1e9(model_kind: str, i3) -> None:
    if model_kind == "fake":
        model = FakeModel()
    else:
        sim = i3.simulation.model_copy(
            update={"elastic_mode": ElasticMode(frequency_hz=180.0, damping_ratio=0.01)}
        )
        model, _ = build_simulated_model(i3, sim)
    profile = RpmProfile([ramp(1500, 4500, 10.0), hold(4500, 1.0), ramp(4500, 900, 3.0)])
    orders = half_orders(6.0)
    table = AmplitudeTable(model, orders, profile)
    rng = np.random.default_rng(3)
    for seg, (lo, hi) in enumerate([(1500, 4500), (4500, 4500), (900, 4500)]):
        rpm = np.concatenate([rng.uniform(lo, hi, 4000), [lo, hi]])
        exact = model.channel_amplitudes(rpm, orders)
        got = table.evaluate(seg, rpm)
        rel = np.abs(got - exact).max(axis=1) / np.abs(exact).max(axis=1)
        assert rel.max() < 1e-9, (seg, rel.max())
        if lo == hi:
            assert np.array_equal(got, exact)  # a hold is exact


def test_table_refuses_a_rough_model() -> None:
    class Rough(FakeModel):
        def channel_amplitudes(self, rpm, orders):
            x = super().channel_amplitudes(rpm, orders)
            return x * (1 + 1e-7 * np.sin(1e6 * np.asarray(rpm)))[:, None, None]

    with pytest.raises(SourceError, match="not smooth in rpm"):
        AmplitudeTable(
            Rough(), half_orders(2.0), RpmProfile([ramp(1500, 2000, 1.0)]), max_intervals=500
        )


@pytest.mark.parametrize(
    "compiled",
    [
        False,
        pytest.param(
            True, marks=pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed")
        ),
    ],
)
def test_synthesised_samples_match_the_direct_sum(i3, compiled: bool) -> None:
    """x(t) = sum_h Re{X_h(rpm(t)) exp(i h phi(t))} with X straight from the model (numpy
    path and compiled kernels)."""
    model = FakeModel(n_ch=3)
    profile = RpmProfile([ramp(1200, 4800, 4.0)])
    orders = half_orders(6.0)
    table = AmplitudeTable(model, orders, profile)
    t = np.sort(np.random.default_rng(4).uniform(0, 4.0, 3000))
    phi, rpm = profile.phi(t), profile.rpm(t)
    x_model = model.channel_amplitudes(rpm, orders)  # (n, n_o, n_ch)
    direct = np.einsum("noc,no->cn", x_model, np.exp(1j * np.outer(phi, orders))).real
    got = synthesize_accel(table, profile, t, compiled=compiled)
    scale = np.abs(x_model).sum(axis=1).max(axis=0)  # (n_ch,) peak possible amplitude
    assert np.max(np.abs(got - direct) / scale[:, None]) < 1e-9


def _tacho_source(i3, **tacho):
    profile = RpmProfile([ramp(800, 6000, 1.5), ramp(6000, 2000, 0.5)])
    return open_source("sim", i3, tacho=tacho, profile=profile, accel_rate_hz=2048)


@pytest.mark.parametrize(("teeth", "missing", "tdc"), [(60, 2, 84.0), (36, 1, -17.5)])
def test_wheel_teeth_at_their_angles(i3, teeth: int, missing: int, tdc: float) -> None:
    src = _tacho_source(i3, kind="wheel", teeth=teeth, missing=missing, tdc_after_gap_deg=tdc)
    _, edges = collect(src)
    te = edges["tacho"]
    assert np.all(np.diff(te) > 0)
    theta_w = np.degrees(src.profile.phi(te)) + tdc  # recomputed from the profile
    pitch = 360.0 / teeth
    tooth = np.round(theta_w / pitch)
    assert np.max(np.abs(theta_w - tooth * pitch)) < 1e-8  # deg
    j = np.mod(tooth, teeth).astype(int)
    assert set(j) == set(range(teeth - missing))  # the gap's teeth never appear
    # every tooth exactly once per revolution: consecutive edges are one pitch apart, or the gap
    steps = np.diff(tooth)
    assert set(steps) == {1.0, float(missing + 1)}
    assert np.all(j[1:][steps > 1] == 0)  # the first tooth after the gap is tooth 0
    # and none is lost at the end: the last edge is within one gap of the end
    t_end = src.profile.duration_s
    assert (
        te[-1] < t_end
        and np.degrees(src.profile.phi(np.array([t_end]))[0]) + tdc - theta_w[-1]
        < (missing + 1) * pitch
    )


def test_pulses_rpm_and_cam_edges(i3) -> None:
    src = _tacho_source(
        i3,
        kind="pulses",
        teeth=4,
        tdc_after_gap_deg=10.0,
        phase_reference="cam",
        cam_angle_deg=123.0,
    )
    _, edges = collect(src)
    th = np.degrees(src.profile.phi(edges["tacho"])) + 10.0
    assert np.max(np.abs(th - 90.0 * np.round(th / 90.0))) < 1e-8
    assert set(np.diff(np.round(th / 90.0))) == {1.0}
    cam = np.degrees(src.profile.phi(edges["cam"]))
    assert np.max(np.abs(cam - 123.0 - 720.0 * np.round((cam - 123.0) / 720.0))) < 1e-8
    assert set(np.diff(np.round((cam - 123.0) / 720.0))) == {1.0}

    src = _tacho_source(i3, kind="rpm", tdc_offset_deg=-6.0)
    _, edges = collect(src)
    th = np.degrees(src.profile.phi(edges["tacho"])) + 6.0
    assert np.max(np.abs(th - 360.0 * np.round(th / 360.0))) < 1e-8
    assert set(np.diff(np.round(th / 360.0))) == {1.0}


def test_sampled_tacho_edges_recovered_by_interpolation(i3) -> None:
    src = open_source(
        "sim",
        i3,
        profile=RpmProfile([ramp(1500, 4500, 0.4)]),
        accel_rate_hz=2048,
        tacho={"delivery": "sampled", "sample_rate_hz": 100_000.0, "phase_reference": "cam"},
    )
    g = src.layout.group("tacho")
    assert [c.name for c in g.channels] == ["tacho", "cam"]
    data, edges = collect(src)
    assert not edges
    v = data["tacho"][0]
    assert v.min() == 0.0 and v.max() == 5.0
    t = np.arange(v.size) / g.rate_hz
    k = np.flatnonzero((v[:-1] < 2.5) & (v[1:] >= 2.5))  # rising crossings
    tc = t[k] + (2.5 - v[k]) / (v[k + 1] - v[k]) / g.rate_hz
    theta_w = np.degrees(src.profile.phi(tc)) + i3.tacho.tdc_after_gap_deg
    assert np.max(np.abs(theta_w - 6.0 * np.round(theta_w / 6.0))) < 1e-6  # deg: sub-sample exact
    assert set(np.diff(np.round(theta_w / 6.0))) == {1.0, 3.0}
    # half a pitch high: the falling crossings sit 3 deg after the rising ones
    kf = np.flatnonzero((v[:-1] >= 2.5) & (v[1:] < 2.5))
    tf = t[kf] + (v[kf] - 2.5) / (v[kf] - v[kf + 1]) / g.rate_hz
    thf = np.degrees(src.profile.phi(tf)) + i3.tacho.tdc_after_gap_deg
    assert np.max(np.abs(thf - 3.0 - 6.0 * np.round((thf - 3.0) / 6.0))) < 1e-6


def test_same_seed_same_data_other_seed_differs(i3) -> None:
    def run(seed: int) -> np.ndarray:
        src = open_source("sim", i3, duration_s=0.5, noise_snr_db=30.0, seed=seed)
        return collect(src)[0]["accel"]

    a, b, c = run(7), run(7), run(8)
    assert np.array_equal(a, b)
    assert not np.allclose(a, c, rtol=1e-3, atol=0)


def test_noise_snr_as_configured(i3) -> None:
    kw = {"duration_s": 8.0, "accel_rate_hz": 4096, "seed": 5}
    clean_src = open_source("sim", i3, **kw)
    noisy_src = open_source("sim", i3, noise_snr_db=25.0, **kw)
    clean = collect(clean_src)[0]["accel"]
    noise = collect(noisy_src)[0]["accel"] - clean
    snr = 20 * np.log10(np.sqrt(np.mean(clean**2, axis=1)) / np.std(noise, axis=1))
    assert np.max(np.abs(snr - 25.0)) < 0.1  # dB, measured per channel
    # white: no correlation between consecutive samples
    r1 = np.sum(noise[:, 1:] * noise[:, :-1], axis=1) / np.sum(noise**2, axis=1)
    assert np.max(np.abs(r1)) < 0.03
    # independent channels
    cc = np.corrcoef(noise)
    assert np.max(np.abs(cc - np.eye(len(cc)))) < 0.03


@pytest.mark.parametrize("delivery", ["edges", "sampled"])
def test_block_split_does_not_change_the_stream(i3, delivery: str) -> None:
    tacho = {"phase_reference": "pressure", "delivery": delivery}
    kw = {"duration_s": 0.7, "noise_snr_db": 35.0, "tacho": tacho}
    a_s, a_e = collect(open_source("sim", i3, block_s=0.1, **kw))
    b_s, b_e = collect(open_source("sim", i3, block_s=0.0137, **kw))
    c_s, c_e = collect(open_source("sim", i3, block_s=0.7, **kw))
    groups = {"accel", "pressure", "rpm"} | ({"tacho"} if delivery == "sampled" else set())
    for other_s, other_e in ((b_s, b_e), (c_s, c_e)):
        assert set(other_s) == set(a_s) == groups
        for g in a_s:
            scale = np.abs(a_s[g]).max()
            np.testing.assert_allclose(other_s[g], a_s[g], rtol=1e-12, atol=1e-12 * scale)
        assert set(other_e) == set(a_e)
        for ch in a_e:
            assert np.array_equal(other_e[ch], a_e[ch])


def test_stream_contract(i3) -> None:
    src = open_source("sim", i3, duration_s=0.35, block_s=0.05, tacho={"phase_reference": "cam"})
    layout = src.layout
    assert layout.edge_channels == ("tacho", "cam")
    assert [g.name for g in layout.groups] == ["accel", "rpm"]
    assert layout.group("accel").channels[0].unit == "m/s^2"
    assert layout.metadata["truth"]["mass_kg"] == pytest.approx(110.0)
    # the bench as simulated (overrides applied) travels with the data
    built = parse_bench(layout.metadata["bench"])
    assert built.powertrain == i3.powertrain and built.sensors == i3.sensors
    assert built.tacho.phase_reference == "cam" and built.simulation.duration_s == 0.35
    start_prev = -1.0
    ends: dict[str, float] = {}
    for item in src:
        if isinstance(item, SampleBlock):
            g = layout.group(item.group)
            start = item.first_index / g.rate_hz
            assert item.data.shape[0] == len(g.channels)
            ends[item.group] = (item.first_index + item.n_samples - 1) / g.rate_hz
        else:
            start = float(item.times_s[0])
            assert np.all(np.diff(item.times_s) > 0)
        assert start >= start_prev  # time order across groups
        start_prev = start
    assert max(ends.values()) < 0.35
    src.close()
    src.close()  # idempotent
    assert list(src) == []


def test_close_stops_the_stream(i3) -> None:
    with open_source("sim", i3, duration_s=1.0, block_s=0.1) as src:
        n = 0
        for _ in src:
            n += 1
            if n == 3:
                src.close()
        assert n == 3


def test_pressure_channel_peaks_after_firing_tdc(i3) -> None:
    src = open_source(
        "sim", i3, profile=RpmProfile([hold(2000, 0.3)]), tacho={"phase_reference": "pressure"}
    )
    data, _ = collect(src)
    p = data["pressure"][0]
    assert src.layout.group("pressure").channels[0].unit == "bar"
    t = np.arange(p.size) / src.layout.group("pressure").rate_hz
    phi_deg = np.mod(np.degrees(2000 * W * t), 720.0)
    peaks = phi_deg[p > 0.98 * p.max()]
    assert np.all((peaks > 0.0) & (peaks < 40.0))
    # the same as the model's pressure, in bar
    np.testing.assert_allclose(p, src.model.pressure(np.radians(phi_deg)) / 1e5, rtol=1e-9)


def test_pressure_reference_without_a_pressure_model() -> None:
    with pytest.raises(SourceError, match="needs a cylinder pressure"):
        SimulatedBench(
            FakeModel(),
            tacho=tacho_spec(Tacho(phase_reference="pressure")),
            accel_rate_hz=4096,
            profile=RpmProfile([hold(2000, 0.1)]),
        )


def test_aliasing_order_refused() -> None:
    with pytest.raises(SourceError, match="aliases"):
        SimulatedBench(
            FakeModel(),
            tacho=tacho_spec(Tacho()),
            accel_rate_hz=400,
            profile=RpmProfile([hold(3000, 0.1)]),
        )


def test_unknown_sim_option(i3) -> None:
    with pytest.raises(SourceError, match="unknown option 'durations'"):
        open_source("sim", i3, durations=3)


class FakeClock:
    """Monotonic seconds that move only when the source sleeps."""

    def __init__(self, start: float = 100.0) -> None:
        self.now = start
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now += seconds


def test_paced_stream_follows_the_clock(i3) -> None:
    clock = FakeClock()
    src = open_source(
        "sim", i3, duration_s=0.3, block_s=0.1, paced=True, clock=clock, sleep=clock.sleep
    )
    yielded = []
    with src:
        for item in src:
            yielded.append((clock.now - 100.0, item))
    # one wait per 0.1 s window, and no sample before the clock has reached it
    assert clock.sleeps == pytest.approx([0.1, 0.1, 0.1])
    for t, item in yielded:
        if isinstance(item, SampleBlock):
            rate = src.layout.group(item.group).rate_hz
            assert (item.first_index + item.n_samples - 1) / rate <= t + 1e-12
        elif isinstance(item, EdgeBlock):
            assert item.times_s[-1] <= t + 1e-12
