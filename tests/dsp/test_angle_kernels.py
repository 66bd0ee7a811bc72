"""The compiled angle-table kernels (dsp.angle_loops, dsp.wheel_intervals, the pressure
votes' sums) against the numpy path: the same bits."""

from __future__ import annotations

import numpy as np
import pytest

from dsp import angle as ang
from dsp import cycle, kernels
from dsp.synthetic import Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig
from dsp.wheel import DecoderState, decode_edges

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed")


def _two_runs(rng: np.random.Generator, t0: float) -> ang.AngleTable:
    """An angle table of two wheel runs of 600 knots (random speeds), 10 ms apart."""
    table = ang.AngleTable()
    for run in range(2):
        rpm = rng.uniform(1000.0, 5000.0)
        t = t0 + np.cumsum(rng.uniform(0.9, 1.1, 600) * 60.0 / rpm / 58)
        phi = 100.0 * run + np.arange(t.size) * (2 * np.pi / 60)
        table = ang.add_knots(table, t, phi, np.full(t.size, run, dtype=np.int64))
        t0 = t[-1] + 0.01
    return table


@pytest.mark.parametrize("seed", range(3))
def test_compiled_angle_lookup_gives_the_numpy_bits(seed, monkeypatch):
    """dsp.angle.lookup and time_at compiled (kernels.USE) give the numpy path's angles,
    times and speeds bit for bit, over two wheel runs, before, between and after them."""
    rng = np.random.default_rng(200 + seed)
    table = _two_runs(rng, 0.0)
    times = np.sort(rng.uniform(-0.01, table.t_end - 1e-9, 5000))
    monkeypatch.setattr(kernels, "USE", False)
    want = ang.lookup(table, times)
    monkeypatch.setattr(kernels, "USE", True)
    got = ang.lookup(table, times)
    assert want[0].sum() > 4000  # most samples lie inside a run
    for w, g in zip(want, got, strict=True):
        np.testing.assert_array_equal(g, w)
    # and back: the times and speeds at angles, NaN before, between and after the runs
    phis = rng.uniform(-1.0, table.phi_hi[-1] + 1.0, 3000)
    monkeypatch.setattr(kernels, "USE", False)
    want = ang.time_at(table, phis)
    monkeypatch.setattr(kernels, "USE", True)
    got = ang.time_at(table, phis)
    assert 100 < np.isnan(want[0]).sum() < 1000
    for w, g in zip(want, got, strict=True):
        np.testing.assert_array_equal(g, w)


@pytest.mark.parametrize("seed", range(3))
def test_compiled_grid_lookup_gives_the_numpy_bits(seed, monkeypatch):
    """dsp.angle.lookup_grid compiled (one pass over samples and pieces) gives the numpy
    path's times, flags, angles, speeds and runs bit for bit: blocks before the first
    knot, across the first, inside a run, across the stretch between two runs, at the end."""
    rng = np.random.default_rng(300 + seed)
    table = _two_runs(rng, 0.013)
    rate, clock0 = 25_600.0, rng.uniform(-0.01, 0.01)
    last = int((table.t_end - clock0) * rate) - 1  # the last index before the table's end
    gap = int((table.t_lo[table.run == 1][0] - clock0) * rate)
    blocks = [(0, 50), (10, 1), (0, 9000), (300, 1)]  # before the first knot, across it
    blocks += [(first, int(rng.integers(1, 9000))) for first in (gap - 700, gap - 5, last - 8000)]
    blocks += [(last - 900, 901), (last, 1)]  # up to the table's end
    seen = set()
    for first, n in blocks:
        idx = np.arange(first, min(first + n, last + 1), dtype=np.int64)
        monkeypatch.setattr(kernels, "USE", False)
        want = ang.lookup_grid(table, clock0, rate, idx)
        monkeypatch.setattr(kernels, "USE", True)
        got = ang.lookup_grid(table, clock0, rate, idx)
        for w, g in zip(want, got, strict=True):
            assert g.dtype == w.dtype
            np.testing.assert_array_equal(g, w)
        seen.add((bool(want[1].all()), bool(want[1].any()), len(set(want[4][want[1]]))))
    # every case met: none inside, some inside, all inside one run, both runs
    assert {(False, False, 0), (False, True, 1), (True, True, 1)} <= seen
    assert any(runs == 2 for _, _, runs in seen)


@pytest.mark.parametrize("seed", range(3))
def test_compiled_knots_and_pressure_sums_give_the_numpy_bits(seed, monkeypatch):
    """dsp.angle.add_knots compiled (dsp.angle_loops.append_knots: one pass) and the
    compiled dsp.cycle.pressure_sums give the numpy path's tables and candidate sums bit
    for bit: knots in blocks of 1 to 60 across runs of 2 to 200 knots (stretches too
    short to form an interval, a tail carried over a run change), pressure with NaN
    samples, a wheel's candidates and four pulses', a block that meets no candidate."""
    rng = np.random.default_rng(400 + seed)
    lengths = [200, 2, 3, 5, 120, 1, 4, 90]
    t = np.cumsum(rng.uniform(0.9, 1.1, sum(lengths)) * 1e-3)
    phi = np.cumsum(rng.uniform(0.09, 0.11, t.size))
    run = np.repeat(np.arange(len(lengths)), lengths)
    tables = {False: ang.AngleTable(), True: ang.AngleTable()}
    a = 0
    while a < t.size:
        b = min(a + int(rng.integers(1, 61)), t.size)
        for compiled in tables:
            monkeypatch.setattr(kernels, "USE", compiled)
            tables[compiled] = ang.add_knots(tables[compiled], t[a:b], phi[a:b], run[a:b])
        for name in ang._COLUMNS:
            want, got = getattr(tables[False], name), getattr(tables[True], name)
            assert got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)
        a = b
    assert np.unique(tables[True].run).size == 5  # the runs of four knots or more
    phi_w = 3.0 + np.cumsum(rng.uniform(0.001, 0.004, 20_000))  # some 9 revolutions
    pressure = rng.uniform(-2.0, 50.0, phi_w.size)
    pressure[rng.integers(0, phi_w.size, 40)] = np.nan
    for steps, sl in ((1, slice(None)), (4, slice(None)), (1, slice(100, 200))):
        monkeypatch.setattr(kernels, "USE", False)
        want = cycle.pressure_sums(phi_w[sl], pressure[sl], steps)
        monkeypatch.setattr(kernels, "USE", True)
        got = cycle.pressure_sums(phi_w[sl], pressure[sl], steps)
        assert want[0].size == 0 if sl.stop else want[0].size >= 8  # candidates met
        for w, g in zip(want, got, strict=True):
            assert g.dtype == w.dtype
            np.testing.assert_array_equal(g, w)


def test_compiled_wheel_decoding_gives_the_numpy_knots_and_state(monkeypatch):
    """dsp.wheel.decode_edges with its interval pass compiled (dsp.kernels.wheel_intervals)
    gives the numpy path's knots, events and decoder state bit for bit, block after block,
    over a sweep with a missed edge, an extra edge, a filled hole and a dropout."""
    cfg = TachoConfig(tdc_after_gap_deg=84.0)
    rng = np.random.default_rng(12)
    bench = SyntheticBench(Ramp(1500.0, 3500.0, 4.0), [random_content(rng)], tdc_after_gap_deg=84.0)
    times = bench.edge_times(4.0)
    extra = times[2500] + 0.3 * (times[2501] - times[2500])
    times = np.sort(np.append(np.delete(times, [1000, 4000, 4001]), extra))
    times = np.concatenate((times[times < 3.0], times[times > 3.2]))  # a dropout
    blocks = np.split(times, np.sort(rng.integers(0, times.size, 40)))

    def decode(compiled):
        monkeypatch.setattr(kernels, "USE", compiled)
        state, out = DecoderState(), []
        for block in blocks:
            state, knots, events = decode_edges(state, block, cfg)
            out.append((knots, [(e.kind, e.message) for e in events], state))
        return out

    want, got = decode(False), decode(True)
    kinds = {kind for _, events, _ in want for kind, _ in events}
    assert {"tacho_missing_edge", "tacho_extra_edge", "tacho_filled", "no_tacho"} <= kinds
    for (wk, we, ws), (gk, ge, gs) in zip(want, got, strict=True):
        assert ge == we and gk.runs == wk.runs
        for name in ("t_s", "n", "run"):
            np.testing.assert_array_equal(getattr(gk, name), getattr(wk, name))
        for name, value in ws.__dict__.items():
            np.testing.assert_array_equal(getattr(gs, name), value)
