"""Whole frames of the compiled dsp against the numpy path's (dsp.kernels, PTINERTIA_NUMBA=1):
the same flags and angles, amplitudes within 1e-12, whatever the blocks; lost samples, a
repeated tacho edge and the window times as the numpy path gives them. (The kernels one by
one: tests/dsp/test_frame_kernels.py.)"""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.stream import SampleBlock
from dsp import kernels
from dsp.config import OrderTrackerConfig
from dsp.driver import track_items
from dsp.frames import OrderFrame
from dsp.synthetic import Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed")


def test_compiled_frames_agree_with_numpy_in_any_blocks(monkeypatch):
    """Whole frames, the compiled path (every kernel: sums, lookup, window times, window
    sums, ramps) against the numpy path on the same blocks: times, speeds, flags and
    channel flags the same, amplitudes, spectrum and leakage figure within 1e-12 of the
    frame's largest; and the compiled frames of random blocks as those of 0.1 s blocks."""
    rng = np.random.default_rng(5)
    contents = [random_content(rng) for _ in range(3)]
    bench = SyntheticBench(Ramp(1500.0, 3000.0, 2.0), contents, tdc_after_gap_deg=84.0)
    config = OrderTrackerConfig(
        tacho=TachoConfig(tdc_after_gap_deg=84.0), orders=(1.0, 1.5, 2.0), spectrum_channel="a2"
    )

    def frames(compiled, items):
        monkeypatch.setattr(kernels, "USE", compiled)
        return [x for x in track_items(bench.layout, items, config) if isinstance(x, OrderFrame)]

    want = frames(False, bench.items(3.0, block_s=0.1))
    got = frames(True, bench.items(3.0, block_s=0.1))
    split = frames(True, bench.items(3.0, block_s=0.03, rng_blocks=np.random.default_rng(8)))
    assert len(want) > 30 and len(got) == len(want) == len(split)
    for w, g in zip(want, got, strict=True):
        assert (g.time_s, g.rpm, g.crank_angle_rad, g.flags) == (
            w.time_s,
            w.rpm,
            w.crank_angle_rad,
            w.flags,
        )
        np.testing.assert_array_equal(g.channel_ok, w.channel_ok)
        for name in ("amplitudes", "spectrum", "leakage"):
            ref = getattr(w, name)
            scale = np.abs(ref).max()
            np.testing.assert_allclose(getattr(g, name), ref, rtol=0, atol=1e-12 * scale)
    for g, s in zip(got, split, strict=True):
        assert (s.crank_angle_rad, s.flags) == (g.crank_angle_rad, g.flags)
        scale = np.abs(g.amplitudes).max()
        np.testing.assert_allclose(s.amplitudes, g.amplitudes, rtol=0, atol=1e-9 * scale)


def test_compiled_frames_fill_lost_samples_as_numpy(monkeypatch):
    """Samples lost in the tracked channels (NaN, and one infinite), each found by the
    compiled path from one sum a channel (dsp.segments.accumulate): the same frames as
    the numpy path, which checks every sum: flags, channel flags and variance factors
    equal, amplitudes within 1e-12 of the frame's largest."""
    rng = np.random.default_rng(11)
    contents = [random_content(rng) for _ in range(3)]
    bench = SyntheticBench(Ramp(1500.0, 3000.0, 2.0), contents, tdc_after_gap_deg=84.0)
    config = OrderTrackerConfig(tacho=TachoConfig(tdc_after_gap_deg=84.0), orders=(1.0, 2.0))
    items = []
    for item in bench.items(2.5, block_s=0.1):
        if isinstance(item, SampleBlock) and item.data.shape[0] >= 3:
            data = np.array(item.data, dtype=float)
            row = int(rng.integers(0, data.shape[0]))
            data[row, rng.integers(0, data.shape[1], 3)] = np.nan
            if item.first_index == 12_800:
                data[row, 7] = np.inf
            item = SampleBlock(item.group, item.first_index, data)
        items.append(item)

    def frames(compiled):
        monkeypatch.setattr(kernels, "USE", compiled)
        return [x for x in track_items(bench.layout, items, config) if isinstance(x, OrderFrame)]

    want, got = frames(False), frames(True)
    assert len(want) > 20 and len(got) == len(want)
    assert any(w.variance_factor is not None for w in want)
    for w, g in zip(want, got, strict=True):
        assert (g.time_s, g.crank_angle_rad, g.flags) == (w.time_s, w.crank_angle_rad, w.flags)
        np.testing.assert_array_equal(g.channel_ok, w.channel_ok)
        if w.variance_factor is None:
            assert g.variance_factor is None
        else:
            np.testing.assert_allclose(g.variance_factor, w.variance_factor, rtol=1e-12)
        scale = np.nanmax(np.abs(w.amplitudes))
        np.testing.assert_allclose(g.amplitudes, w.amplitudes, rtol=0, atol=1e-12 * scale)


def test_a_repeated_tacho_edge_is_survived_by_the_compiled_wheel_decoder(monkeypatch):
    """Two edges at the same time (a logger's duplicate): a zero interval, whose ratio to
    the next is a division by zero. The numpy path flags a re-sync and goes on; the compiled
    decoder did the same division with numba's Python error model and raised."""
    rng = np.random.default_rng(0)
    clean = SyntheticBench(Ramp(1500.0, 3000.0, 3.0), [random_content(rng) for _ in range(2)])
    twice = float(clean.edge_times(3.0)[400])
    bench = SyntheticBench(Ramp(1500.0, 3000.0, 3.0), clean.contents, extra_edges_s=(twice,))
    config = OrderTrackerConfig(tacho=TachoConfig(tdc_after_gap_deg=84.0))
    items = list(bench.items(3.0))

    def frames(compiled):
        monkeypatch.setattr(kernels, "USE", compiled)
        return [x for x in track_items(bench.layout, items, config) if isinstance(x, OrderFrame)]

    want, got = frames(False), frames(True)
    assert len(want) > 20 and any("tacho_resync" in w.flags for w in want)
    assert [(g.time_s, g.crank_angle_rad, g.flags) for g in got] == [
        (w.time_s, w.crank_angle_rad, w.flags) for w in want
    ]


@pytest.mark.parametrize("compiled", [True, False])
def test_compiled_window_times_give_the_numpy_bits(compiled, monkeypatch):
    """The times and speeds at the windows' start, centre and end (dsp.window_times through
    dsp.kernels, compiled and as plain loops) against dsp.angle.time_at of the angles
    (numpy path): the same bits, NaN before, between and after two wheel runs, and
    whether all are finite."""
    from dsp import angle as ang

    rng = np.random.default_rng(17)
    table, t0 = ang.AngleTable(), 0.0
    for run in range(2):
        t = t0 + np.cumsum(rng.uniform(0.9, 1.1, 300) * 60.0 / 3000.0 / 58)
        phi = 60.0 * run + np.arange(t.size) * (2 * np.pi / 60)
        table = ang.add_knots(table, t, phi, np.full(t.size, run, dtype=np.int64))
        t0 = t[-1] + 0.01
    n, spacing = 4, 2 * np.pi / 4
    cols = (table.t_lo, table.t_hi, table.phi_lo, table.phi_hi, table.c1, table.c2, table.c3)
    if not compiled:
        monkeypatch.setattr(kernels, "_jit", lambda fn, numpy_division=False: fn)
    monkeypatch.setattr(kernels, "USE", False)
    nan_seen = 0
    for j0, f in ((-3, 10), (5, 10), (10, 20), (43, 10), (50, 20)):
        js = np.arange(j0, j0 + f)
        span = np.arange(j0 - n, j0 + f + n)
        want_t, want_w = ang.time_at(table, span * spacing)
        at = (np.arange(f)[:, None] + np.array([0, n, 2 * n])).ravel()
        times, omegas = np.empty((f, 3)), np.empty((f, 3))
        finite = kernels.window_times(js, n, spacing, *cols, times, omegas)
        assert times.tobytes() == want_t[at].reshape(f, 3).tobytes()
        assert omegas.tobytes() == want_w[at].reshape(f, 3).tobytes()
        assert finite == bool(np.isfinite(want_t).all())
        nan_seen += not finite
    assert nan_seen == 3  # before, across the gap, after; two inside a run
