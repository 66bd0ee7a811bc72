"""The compiled segment sums (dsp.kernels) against the numpy reference (dsp.sums)."""

from __future__ import annotations

import hashlib
import importlib
import itertools
import os
from pathlib import Path

import numpy as np
import pytest

from dsp import angle as ang
from dsp import cycle, kernels
from dsp.leakage import SLOPE_PERIODS, _slopes
from dsp.ramp_slopes import ramp_slopes
from dsp.sum_rows import unpack
from dsp.sum_sets import SumSet
from dsp.sums import add_sample_sets

pytestmark = pytest.mark.skipif(not kernels.AVAILABLE, reason="numba is not installed")


def _signal(seed: int, n: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    phi = 50.0 + np.cumsum(rng.uniform(0.004, 0.02, n))  # a few dozen segments
    omega = rng.uniform(150.0, 500.0, n)
    x = rng.standard_normal((4, n)) * 2.0
    x[:, rng.integers(0, n, 5)] = 9.0  # some clipped samples
    spectrum = rng.standard_normal((1, n))
    return phi, omega, x, spectrum


def _sums(compiled: bool, phi, omega, x, spectrum, cuts, clip, k2, sk2, fpr):
    pieces = [x[:, a:b] for a, b in itertools.pairwise(cuts)]
    spec = [spectrum[:, a:b] for a, b in itertools.pairwise(cuts)]
    sets = [SumSet({}, pieces, k2, clip), SumSet({}, spec, sk2, tracked=False)]
    return add_sample_sets(sets, phi, omega, 1001, 25_600.0, fpr, 45.0, compiled=compiled)


def _assert_rows_close(want: dict, have: dict, n_ch: int, no: int) -> None:
    """Each part of every row (sums, taper sums, mean squares, weights, counts) within
    1e-12 of that part's own largest finite value (a row's largest entry is its sum of
    squares, hundreds of times its sums: a bound on the whole row would hide a sums error),
    non-finite entries where numpy has them."""
    assert want.keys() == have.keys()
    for m, row in want.items():
        np.testing.assert_array_equal(np.isfinite(have[m]), np.isfinite(row))
        parts = zip(unpack(row[None], n_ch, no), unpack(have[m][None], n_ch, no), strict=True)
        for ref, got in parts:
            ref, got = np.asarray(ref).ravel(), np.asarray(got).ravel()
            fine = np.isfinite(ref)
            if not fine.any():
                continue
            scale = np.abs(ref[fine]).max()
            np.testing.assert_allclose(got[fine], ref[fine], rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("seed", range(6))
def test_compiled_rows_agree_with_numpy_on_random_block_splits(seed):
    """Every row (sums, weights, mean square, counts, clip flags) within 1e-12 of each
    part's largest value, for random block cuts, order sets (with and without the
    mean) and frames per revolution."""
    rng = np.random.default_rng(100 + seed)
    n = 4000
    phi, omega, x, spectrum = _signal(seed, n)
    inner = sorted(rng.choice(np.arange(1, n), size=rng.integers(0, 6), replace=False).tolist())
    cuts = [0, *inner, n]
    k2 = np.unique(rng.integers(0 if seed % 2 else 1, 13, size=4))
    sk2 = np.arange(0, 15)
    fpr = int(rng.choice([1, 2, 4]))
    clip = None if seed == 3 else 8.5
    ref = _sums(False, phi, omega, x, spectrum, cuts, clip, k2, sk2, fpr)
    got = _sums(True, phi, omega, x, spectrum, cuts, clip, k2, sk2, fpr)
    _assert_rows_close(ref[0], got[0], x.shape[0], k2.size)
    _assert_rows_close(ref[1], got[1], 1, sk2.size)
    # the clip flags and counts are exact, and some segment was clipped
    n_track = x.shape[0]
    counts = np.array([row[-n_track:] for row in ref[0].values()])
    assert np.array_equal(counts, np.array([row[-n_track:] for row in got[0].values()]))
    assert (counts.sum() > 0) == (clip is not None)


def test_compiled_sums_are_block_invariant_like_numpy():
    """Pieces summed in one call round as one call per piece, on the compiled path too."""
    phi, omega, x, spectrum = _signal(9, 3000)
    cuts = [0, 37, 39, 1900, 3000]
    k2, sk2 = np.arange(1, 9), np.arange(0, 9)
    together = _sums(True, phi, omega, x, spectrum, cuts, 1.5, k2, sk2, 1)
    rows: list[dict] = [{}, {}]
    for a, b in itertools.pairwise(cuts):
        sets = [
            SumSet(rows[0], [x[:, a:b]], k2, 1.5),
            SumSet(rows[1], [spectrum[:, a:b]], sk2, tracked=False),
        ]
        rows = add_sample_sets(
            sets, phi[a:b], omega[a:b], 1001 + a, 25_600.0, 1, 45.0, compiled=True
        )
    for want, have in zip(rows, together, strict=True):
        assert want.keys() == have.keys()
        for m, row in want.items():
            np.testing.assert_array_equal(have[m], row)


@pytest.mark.parametrize("seed", range(3))
def test_compiled_angle_lookup_gives_the_numpy_bits(seed, monkeypatch):
    """dsp.angle.lookup and time_at compiled (kernels.USE) give the numpy path's angles,
    times and speeds bit for bit, over two wheel runs, before, between and after them."""
    rng = np.random.default_rng(200 + seed)
    table = ang.AngleTable()
    t0 = 0.0
    for run in range(2):
        rpm = rng.uniform(1000.0, 5000.0)
        t = t0 + np.cumsum(rng.uniform(0.9, 1.1, 600) * 60.0 / rpm / 58)
        phi = 100.0 * run + np.arange(t.size) * (2 * np.pi / 60)
        table = ang.add_knots(table, t, phi, np.full(t.size, run, dtype=np.int64))
        t0 = t[-1] + 0.01
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


@pytest.mark.parametrize("seed", range(4))
def test_compiled_ramps_agree_with_numpy(seed):
    """The leakage correction's ramps (dsp.ramp_slopes, run through numba and as plain
    Python) against the numpy reference: the same frames and channels corrected, the
    ramps within 1e-12; with skipped frames, two parity chains, NaN amplitudes and
    tacho stretches."""
    rng = np.random.default_rng(300 + seed)
    period, n_int, n_ch = 2 * int(rng.integers(1, 3)), 8, 5
    all_j = (
        np.sort(rng.choice(np.arange(40), size=30, replace=False)) if seed % 2 else np.arange(30)
    )
    all_c = (all_j >= 17).astype(np.int64)  # a re-sync: a new chain from frame 17 on
    all_x = rng.standard_normal((30, n_int, n_ch)) + 1j * rng.standard_normal((30, n_int, n_ch))
    all_x[rng.integers(0, 30, 6), rng.integers(0, n_int, 6), rng.integers(0, n_ch, 6)] = np.nan
    f = 12
    js, chains = all_j[-f:], all_c[-f:]
    tacho_bad = rng.random(f) < 0.2
    want_b, want_good = _slopes(all_j, all_c, all_x, js, chains, tacho_bad, period)
    assert want_good.sum() > 10 and (~want_good).sum() > 5
    for fn in (ramp_slopes, kernels.ramp_slopes):
        b = np.empty((f, n_int, n_ch), complex)
        good = np.empty((f, n_ch), bool)
        fn(all_j, all_c, all_x, js, chains, tacho_bad, period, SLOPE_PERIODS, b, good)
        np.testing.assert_array_equal(good, want_good)
        np.testing.assert_allclose(b, want_b, rtol=1e-12, atol=0)


@pytest.mark.parametrize(
    ("n_ch", "k2"),
    [
        (1, [2]),
        (3, [0, 1, 2, 3]),
        (5, list(range(1, 10))),
        (9, list(range(1, 9))),
        (10, list(range(0, 17))),
    ],
)
def test_compiled_rows_agree_with_numpy_for_any_channel_count_and_order_set(n_ch, k2):
    """The vectorised pass sums four channels at a time and the rest one by one, rows in
    chunks of 16 (Re and Im of up to 8 orders each): channel counts off those multiples,
    one order, the mean and 17 orders (three chunks) all give the numpy rows within 1e-12
    and its clip flags exactly."""
    rng = np.random.default_rng(n_ch)
    n = 2500
    phi, omega, _, spectrum = _signal(n_ch, n)
    x = rng.standard_normal((n_ch, n)) * 2.0
    x[rng.integers(0, n_ch, 4), rng.integers(0, n, 4)] = -9.0
    x[0, rng.integers(0, n, 3)] = np.nan  # a NaN sample: NaN sums, never a clip by itself
    cuts = [0, 700, 701, n]
    k2a = np.array(k2)
    ref = _sums(False, phi, omega, x, spectrum, cuts, 8.5, k2a, k2a, 2)
    got = _sums(True, phi, omega, x, spectrum, cuts, 8.5, k2a, k2a, 2)
    _assert_rows_close(ref[0], got[0], n_ch, k2a.size)
    _assert_rows_close(ref[1], got[1], 1, k2a.size)
    counts = np.array([row[-n_ch:] for row in ref[0].values()])
    assert np.array_equal(counts, np.array([row[-n_ch:] for row in got[0].values()]))
    assert counts.sum() > 0


def test_vector_transpose_puts_rows_in_columns():
    """dsp.fused_sums.vtranspose8: eight rows of eight lanes land as eight columns of a
    wider array, at an offset, and nothing else is written."""
    from numba import njit

    from dsp.fused_sums import vtranspose8

    @njit
    def transpose(src, dst):
        vtranspose8(src, 8, dst, 3, 11)

    src = np.arange(72.0)
    dst = np.full(3 + 7 * 11 + 8 + 5, -1.0)
    transpose(src, dst)
    want = np.full_like(dst, -1.0)
    for lane in range(8):
        want[3 + 11 * lane : 3 + 11 * lane + 8] = src[8 + lane : 72 : 8]
    np.testing.assert_array_equal(dst, want)


@pytest.mark.parametrize("fpr", [1, 2, 4])
def test_compiled_segment_cuts_are_the_numpy_ones(fpr):
    """dsp.kernels.segment_cuts (the compiled path's segments) against dsp.sums._segments
    piece by piece and the numpy path's angles from the frame angle: the same integers and
    the same bits (and their halves in single precision), with segments split between
    pieces and pieces inside one segment."""
    from dsp.sums import _segments

    phi, _, _, _ = _signal(fpr, 5000)
    cuts = [0, 3, 40, 41, 2600, 5000]
    spacing, half = 2 * np.pi / fpr, 0.5 * np.radians(45.0)
    got = kernels.segment_cuts(phi, np.array(cuts, dtype=np.int64), spacing, half)
    parts = [_segments(phi, p0, p1, spacing, half) for p0, p1 in itertools.pairwise(cuts)]
    for have, want in zip(got[:4], zip(*parts, strict=True), strict=True):
        np.testing.assert_array_equal(have, np.concatenate(want))
    assert got[4] == [part[0].size for part in parts]
    mu, starts, ends = got[0], got[1], got[2]
    np.testing.assert_array_equal(got[5], phi - np.repeat(mu * spacing, ends - starts))
    assert got[6].dtype == np.float32  # the carriers' half angles, as dsp.sum_sets.base_parts
    np.testing.assert_array_equal(got[6], (0.5 * got[5]).astype(np.float32))
    assert len(set(mu.tolist())) < mu.size  # a segment split between pieces


def test_the_default_path_never_imports_numba():
    """A tracker run without PTINERTIA_NUMBA (a subprocess: this one has numba loaded)
    leaves numba, llvmlite and the compiled modules unimported: their import alone costs
    a short run more than the kernels save."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import numpy as np\n"
        "from dsp.config import OrderTrackerConfig\n"
        "from dsp.orders import OrderTracker\n"
        "from dsp.synthetic import Ramp, SyntheticBench, random_content\n"
        "from dsp.tacho import TachoConfig\n"
        "rng = np.random.default_rng(0)\n"
        "bench = SyntheticBench(Ramp(2000.0, 3000.0, 1.0), [random_content(rng) for _ in range(3)], "
        "tdc_after_gap_deg=84.0)\n"
        "config = OrderTrackerConfig(tacho=TachoConfig(tdc_after_gap_deg=84.0), orders=(1.0, 2.0))\n"
        "tracker = OrderTracker.from_layout(bench.layout, config)\n"
        "frames = [f for item in bench.items(1.0, block_s=0.1) for f in tracker.process(item)[0]]\n"
        "assert frames\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite') "
        "or m in ('dsp.fused_sums', 'dsp.vec8', 'dsp.fused_segments', 'dsp.spectrum_lanes')))\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PTINERTIA_NUMBA"}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, check=False
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_compiled_sums_take_read_only_samples():
    """A block over a bytes buffer (np.frombuffer: read-only) sums as a writable copy does,
    as on the numpy path (the compiled signature once refused it with numba's TypeError)."""
    phi, omega, x, spectrum = _signal(4, 2000)
    frozen = np.frombuffer(x.tobytes(), float).reshape(x.shape)
    assert not frozen.flags.writeable
    k2, sk2 = np.arange(1, 5), np.arange(0, 5)
    want = _sums(True, phi, omega, x, spectrum, [0, 2000], 8.5, k2, sk2, 1)
    got = _sums(True, phi, omega, frozen, spectrum, [0, 2000], 8.5, k2, sk2, 1)
    for a, b in zip(want, got, strict=True):
        assert a.keys() == b.keys()
        assert all(np.array_equal(a[m], b[m], equal_nan=True) for m in a)


@pytest.mark.parametrize("name", ["fused_sums", "fused_ramps"])
def test_the_compiled_sums_name_their_helpers_hash(name):
    """numba's cache watches only a kernel module's own bytes (dsp.fused_sums,
    dsp.fused_ramps): the hash of the helpers it inlines is written in it, so editing a
    helper must change it (else a warm cache runs the old machine code and every test
    here compares that, not the edit)."""
    module = importlib.import_module(f"dsp.{name}")
    digest = hashlib.sha256()
    for helper in module.HELPERS:
        digest.update(
            helper.encode() + b"\0" + (Path(module.__file__).parent / helper).read_bytes()
        )
    assert digest.hexdigest() == module.HELPERS_SHA256, (
        f"a helper of dsp/{name}.py changed: set HELPERS_SHA256 there to "
        f"{digest.hexdigest()!r} so numba's cache is rebuilt"
    )


@pytest.mark.parametrize("seed", range(3))
def test_compiled_grid_lookup_gives_the_numpy_bits(seed, monkeypatch):
    """dsp.angle.lookup_grid compiled (one pass over samples and pieces) gives the numpy
    path's times, flags, angles, speeds and runs bit for bit: blocks before the first
    knot, across the first, inside a run, across the stretch between two runs, at the end."""
    rng = np.random.default_rng(300 + seed)
    table = ang.AngleTable()
    t0 = 0.013
    for run in range(2):
        rpm = rng.uniform(1000.0, 5000.0)
        t = t0 + np.cumsum(rng.uniform(0.9, 1.1, 600) * 60.0 / rpm / 58)
        phi = 100.0 * run + np.arange(t.size) * (2 * np.pi / 60)
        table = ang.add_knots(table, t, phi, np.full(t.size, run, dtype=np.int64))
        t0 = t[-1] + 0.01
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


def test_compiled_channel_sums_do_not_depend_on_the_channel_blocks():
    """Nine channels are summed as a block of four and one of five, four as one block of
    four, five as one of five, seven as four and four from the fourth: every channel's
    sums, mean square and clip flag are the same bits whichever block it was in."""
    phi, omega, _, spectrum = _signal(9, 3000)
    x = np.random.default_rng(9).standard_normal((9, 3000)) * 3.0
    k2 = np.arange(1, 9)

    def per_channel(rows_x):
        (rows, _) = _sums(True, phi, omega, rows_x, spectrum, [0, 1200, 3000], 8.5, k2, k2, 1)
        n_ch = rows_x.shape[0]
        parts = [unpack(np.array(list(rows.values())), n_ch, k2.size)[i] for i in (0, 1, 2, 6)]
        return [[np.asarray(p)[:, c] for p in parts] for c in range(n_ch)]

    whole = per_channel(x)
    for lo, hi in ((0, 4), (4, 9), (2, 9)):
        for c, got in enumerate(per_channel(x[lo:hi])):
            for have, want in zip(got, whole[lo + c], strict=True):
                np.testing.assert_array_equal(have, want)


def test_compiled_wheel_decoding_gives_the_numpy_knots_and_state(monkeypatch):
    """dsp.wheel.decode_edges with its interval pass compiled (dsp.kernels.wheel_intervals)
    gives the numpy path's knots, events and decoder state bit for bit, block after block,
    over a sweep with a missed edge, an extra edge, a filled hole and a dropout."""
    from dsp.synthetic import Ramp, SyntheticBench, random_content
    from dsp.tacho import TachoConfig
    from dsp.wheel import DecoderState, decode_edges

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
