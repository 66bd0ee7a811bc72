"""The compiled segment sums (dsp.kernels) against the numpy reference (dsp.sums)."""

from __future__ import annotations

import hashlib
import importlib
import itertools
import os
from pathlib import Path

import numpy as np
import pytest

from dsp import kernels
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
    """dsp.kernels.segment_cuts (the compiled path's q and segments) against the numpy
    path's q, dsp.sums._segments piece by piece, its frame angles and its angles from the
    frame angle: the same integers and the same bits (and their halves in single precision), with segments split between
    pieces and pieces inside one segment; and the zones' falling taper, made once for
    every set on the cut (dsp.fused_segments.zone_falls): the numpy path's taper weights
    bit for bit, their sums with q (added in sample order, numpy's reduceat pairwise)
    within 1e-12."""
    from dsp.sum_sets import Segments, zones
    from dsp.sums import _segments

    phi, omega, _, _ = _signal(fpr, 5000)
    cuts = [0, 3, 40, 41, 2600, 5000]
    spacing, half = 2 * np.pi / fpr, 0.5 * np.radians(45.0)
    got = kernels.segment_cuts(phi, omega, 25600.0, np.array(cuts, dtype=np.int64), spacing, half)
    q = omega * (1.0 / 25600.0)  # the numpy path's q, bit for bit
    np.testing.assert_array_equal(got[8], q)
    parts = [_segments(phi, p0, p1, spacing, half) for p0, p1 in itertools.pairwise(cuts)]
    for have, want in zip(got[:4], zip(*parts, strict=True), strict=True):
        np.testing.assert_array_equal(have, np.concatenate(want))
    assert got[4] == [part[0].size for part in parts]
    mu, starts, ends = got[0], got[1], got[2]
    np.testing.assert_array_equal(got[5], phi - np.repeat(mu * spacing, ends - starts))
    assert got[6].dtype == np.float32  # the carriers' half angles, as dsp.sum_sets.base_parts
    np.testing.assert_array_equal(got[6], (0.5 * got[5]).astype(np.float32))
    assert len(set(mu.tolist())) < mu.size  # a segment split between pieces
    np.testing.assert_array_equal(got[7], mu * spacing)  # the frame angles
    seg = Segments(mu, starts, ends, got[3], cuts, got[4], mu * spacing, half)
    _, _, z, fall, _, wd = zones(seg, phi, q)
    assert z.size > 100 and np.all(wd[got[3] > starts] > 0)  # zones with samples
    np.testing.assert_array_equal(got[9][0][z], fall)
    np.testing.assert_allclose(got[9][1], wd, rtol=1e-12, atol=0.0)


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


@pytest.mark.parametrize("name", ["fused_sums", "fused_ramps", "spectrum_lanes", "fused_frames"])
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
