"""The compiled segment sums (dsp.kernels) against the numpy reference (dsp.sums)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dsp import kernels
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


@pytest.mark.parametrize("seed", range(6))
def test_compiled_rows_agree_with_numpy_on_random_block_splits(seed):
    """Every row (sums, weights, mean square, counts, clip flags) within 1e-12 of the
    segment's largest value, for random block cuts, order sets (with and without the
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
    for want, have in zip(ref, got, strict=True):
        assert want.keys() == have.keys()
        for m, row in want.items():
            np.testing.assert_allclose(have[m], row, rtol=0, atol=1e-12 * np.abs(row).max())
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
