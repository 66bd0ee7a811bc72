"""The compiled whitening (estimator/whitened_rows.py with its eight-lane sums,
estimator/whiten_lanes.py): its eight-lane sums the same bits as the loops the interpreter runs, and the
hash that keeps numba's cache of it honest. (The whole kernel against its interpreted run and the numpy
reference: tests/estimator/test_row_kernels.py.)"""

from __future__ import annotations

import hashlib
import importlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from estimator import row_kernels, whitened_rows

NUMBA = pytest.mark.skipif(not row_kernels.AVAILABLE, reason="numba not installed")
ROOT = Path(whitened_rows.__file__).parent.parent


@pytest.mark.parametrize("module", ["whitened_rows", "whiten_lanes"])
def test_the_kernels_name_their_helpers_hash(module: Any) -> None:
    """numba's cache watches a kernel's own file's bytes only: the sha256 of the helpers
    the compiled kernel takes from elsewhere is written in it, so editing one changes it."""
    if module == "whiten_lanes" and not row_kernels.AVAILABLE:
        pytest.skip("numba not installed")
    module = importlib.import_module(f"estimator.{module}")
    digest = hashlib.sha256()
    for helper in module.HELPERS:
        digest.update(helper.encode() + b"\0" + (ROOT / helper).read_bytes())
    assert digest.hexdigest() == module.HELPERS_SHA256, (
        f"a helper of {module.__name__} changed: set HELPERS_SHA256 there to "
        f"{digest.hexdigest()!r} so numba's cache is rebuilt"
    )


@NUMBA
@pytest.mark.parametrize("width", [0, 3, 8, 13, 16, 17, 32, 34, 45, 77])
def test_eight_lane_sums_are_the_loops_bits(width: int) -> None:
    from estimator.whiten_lanes import rows_products

    rng = np.random.default_rng(width)
    # (rows two at a time where the source rows are shared: an odd count leaves one)
    for n_terms, lower, s_row, n_rows in (
        (0, False, 0, 12),
        (1, False, 1, 12),
        (5, True, 0, 12),
        (12, False, 0, 12),
        (1, True, 5, 12),
        (12, True, 0, 11),
        (7, False, 0, 9),
    ):
        c = rng.normal(size=200)
        stride = width + 3
        size = 2 + stride * 12 + 60
        src = rng.normal(size=size) * 10.0 ** rng.integers(-8, 8, size)
        start = rng.normal(size=4 + 12 * (width + 1))
        want, got = start.copy(), start.copy()
        args = (c, 3, 14, 1, n_rows, n_terms, lower, src, 2, s_row, stride, width)
        whitened_rows.rows_products_loops(*args, want, 4, width + 1)
        rows_products(*args, got, 4, width + 1)
        assert np.array_equal(got, want)


def _pairs(n_p: int, n: int, n_sys: int, n_model: int) -> list[np.ndarray]:
    """whiten_pairs' arguments for ``n_p`` random pairs: D of the real form
    [[R, -I], [I, R]] of a complex (6, 6), C positive definite."""
    rng = np.random.default_rng(n_p + n + n_sys)
    d_c = rng.normal(size=(n_p, 6, 6)) + 1j * rng.normal(size=(n_p, 6, 6))
    d_meas = np.block([[d_c.real, -d_c.imag], [d_c.imag, d_c.real]])
    a = rng.normal(size=(n_p, 6, 6))
    return [
        10.0 ** rng.uniform(-6, -3, n_p),  # var
        a @ a.transpose(0, 2, 1) + 0.1 * np.eye(6),  # cov_unit
        rng.choice([-1.0, 1.0], n_p),  # sign
        rng.normal(size=(n_p, 12, n_sys)),  # sens
        rng.normal(size=(n_p, 12, n_model)),  # model
        rng.normal(size=(n_p, 12, n)),  # H (raw)
        rng.normal(size=(n_p, 12)),  # y (raw)
        np.ascontiguousarray(d_meas),
        np.zeros((n_p, 12, n_sys)),  # dr
    ]


@NUMBA
@pytest.mark.parametrize("shape", [(11, 12, 34, 7), (3, 9, 20, 0), (17, 13, 8, 2)])
def test_compiled_whitening_is_the_interpreted_loops_bits(shape) -> None:
    want, got = _pairs(*shape), _pairs(*shape)
    whitened_rows.whiten_pairs(*want)
    row_kernels.jit(whitened_rows.whiten_pairs)(*got)
    for a, b in zip(want[5:], got[5:], strict=True):
        assert np.array_equal(a, b)
    # and W whitens: W (raw rows) has the covariance-weighted norm of the raw rows
    var, cov_unit, _, _, _, raw_h, _, d_meas, _ = _pairs(*shape)
    c = var[:, None, None] * cov_unit
    cov = d_meas @ np.block([[c, 0 * c], [0 * c, c]]) @ d_meas.transpose(0, 2, 1)
    gram = raw_h.transpose(0, 2, 1) @ np.linalg.solve(cov, raw_h)
    assert np.allclose(got[5].transpose(0, 2, 1) @ got[5], gram, rtol=1e-6)


@NUMBA
@pytest.mark.filterwarnings("ignore:invalid value encountered in sqrt:RuntimeWarning")
@pytest.mark.parametrize("n_p", [0, 1, 7, 8, 9])
def test_compiled_whitening_at_the_lane_edges_and_a_failed_pivot(n_p: int) -> None:
    """Pair counts around the eight lanes, a covariance with a negative pivot (NaN rows, as
    the loops give) and one of extreme scale beside ordinary ones, which stay unaffected:
    the same bits, NaNs where the loops put them, arrays sized exactly."""
    want, got = _pairs(n_p, 10, 12, 3), _pairs(n_p, 10, 12, 3)
    if n_p > 1:
        for args in (want, got):
            args[1][0] = -np.eye(6)  # var * cov_unit negative definite: no Cholesky factor
            args[0][-1] = 1e290
    whitened_rows.whiten_pairs(*want)
    row_kernels.jit(whitened_rows.whiten_pairs)(*got)
    for a, b in zip(want[5:], got[5:], strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    if n_p > 1:
        assert np.isnan(got[5][0]).all() and np.isfinite(got[5][1:-1]).all()
