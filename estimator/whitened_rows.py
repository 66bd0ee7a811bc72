"""Compiled whitening of the (frame, order) pairs' rows: :func:`whiten_pairs`, the second
half of :func:`estimator.compiled_rows.kernel_rows` (the raw rows come from
:func:`estimator.row_kernels.pair_rows`).

Per pair: the row covariance ``D diag(C, C) D^T``, its Cholesky factor ``L`` and
``W = L^-1``, then ``W`` applied to the raw rows, the residual, ``D`` and the model
inputs' rows at once, and the whitened sensitivities ``W D dm``. What numpy does with
``cholesky``, ``inv`` and batched matmuls (:func:`estimator.equations.frame_rows`),
the same arithmetic as the loops that were in :func:`pair_rows` before (issue 24: the
same bits, tested against the interpreter's run of this module).

Why it is laid out so (issue 24): numba's loops over two indices (``hp[a, j] += c *
raw[k, j]``) stayed scalar (the machine code had no packed multiply); numba's own
vectorised loops over row views, short as these are (12 terms, 12-34 columns), spend
their time on overlap and remainder tests and on storing the sums at every term; the
Cholesky factorisation and inverse of one pair is a chain of square roots and divisions
that waits on their latency; and a call of a compiled helper with three arrays costs
~20 ns. So the compiled kernel takes three helpers from :mod:`estimator.whiten_lanes`
(``LANE_HELPERS``; this module's own loops are the reference the interpreter runs):
:func:`covariance_lanes` and :func:`factor_lanes` form and factor eight pairs'
covariances at once, a pair a vector lane, and :func:`rows_products` multiplies eight
columns a vector, the sums kept in registers: ``W`` times the right-hand sides gathered
in one (12, n + 12 + n_model + 1) block (raw rows, ``D``, model rows, residual) in one
call, ``(W D sign)`` times ``sens`` in another. Every entry is the sum of the same
products in the same order as the scalar loops that were in
:func:`estimator.row_kernels.pair_rows`: the compiled rows are the same bits as before
(the 60 s log's 4494 pairs, and the compiled default run, checked).

Measured on those pairs (54 calls captured from ``/tmp/prof/stage_prof.py est``; CPU
best of 30, load 2-7 on the 2 cores, against 4adcb8f's kernel on the same calls): the rows
(raw and whitened) 16.6-18.5 -> 9.0-10.3 ms a minute; step by step: the whitening's sums
a vector at a time 18.1 -> 13.3, eight pairs' covariances and factors a lane each ->
10.9-11.8, one call for each matrix product -> 10.2-10.5, two rows at a time -> 9.0-10.1,
the raw rows' complex-by-real products part by part (:mod:`estimator.row_kernels`) ->
9.2-9.9. The whitening alone about 6.7 (its ``W D sign sens`` 2.0 of it: the vector
additions' throughput; fused multiply-adds would change the bits).
"""

from __future__ import annotations

import numpy as np

# the helpers estimator.row_kernels.jit replaces by their compiled eight-lane versions
# (this file's own ones stay the reference the interpreter runs)
LANES_MODULE = "estimator.whiten_lanes"
LANE_HELPERS = ("rows_products", "covariance_lanes", "factor_lanes")
# numba's cache watches this file only: the sha256 of the files the compiled helpers come
# from (tests/estimator/test_whitened_rows.py recomputes it and prints the new value), so
# an edit of theirs changes this file too and a stale cache is never loaded
HELPERS = ("estimator/whiten_lanes.py", "dsp/vec8.py")
HELPERS_SHA256 = "50538c14f5892461c61398db6a9fa4f9591acc1a7ab2c7366c7aed174f239b1b"


def whiten_pairs(
    var: np.ndarray,
    cov_unit: np.ndarray,
    sign: np.ndarray,
    sens: np.ndarray,
    model: np.ndarray,
    H: np.ndarray,
    y: np.ndarray,
    d_meas: np.ndarray,
    dr: np.ndarray,
) -> None:
    """Whiten P pairs' raw rows in place: ``H`` (P, 12, n) and ``y`` (P, 12) on entry the
    raw rows and residuals, ``d_meas`` (P, 12, 12) d residual / d measurement (real form),
    on return ``H`` and ``y`` whitened and ``dr`` (P, 12, n_sys) the whitened
    sensitivities ``W D sign sens`` with ``W model`` added on its last n_model columns.
    ``var`` (P,) the channel noise, ``cov_unit`` (P, 6, 6) the motion's unit covariance,
    ``sign`` (P,), ``sens`` (P, 12, n_sys) d motion / d systematic parameters (its model
    columns unused), ``model`` (P, 12, n_model) the model inputs' raw rows."""
    n_p, _, n = H.shape
    n_sys = sens.shape[2]
    n_model = model.shape[2]
    n_s = n_sys - n_model
    m = n + 12 + n_model + 1  # raw rows | D | model rows | residual
    rhs = np.empty((12, m))
    rhs_f = rhs.reshape(12 * m)
    out = np.empty(12 * m)
    # eight pairs' D, C = var cov_unit, D[:, :6] C, row covariances, Cholesky factors and
    # their inverses W (lower triangles), entry (i, j) of the pair in lane l at
    # (columns i + j) 8 + l
    dm_l = np.empty(144 * 8)
    cu_l = np.empty(36 * 8)
    dcu_l = np.empty(72 * 8)
    cov = np.zeros(144 * 8)
    low = np.empty(144 * 8)
    inv = np.empty(144 * 8)
    coef = np.empty(144)  # W D sign
    sens_f = sens.reshape(sens.size)
    dr_f = dr.reshape(dr.size)
    for first in range(0, n_p, 8):
        lanes = min(8, n_p - first)
        for lane in range(lanes, 8):  # (lanes without a pair: D and C the identity)
            for a in range(144):
                dm_l[8 * a + lane] = 1.0 if a % 13 == 0 else 0.0
            for a in range(36):
                cu_l[8 * a + lane] = 1.0 if a % 7 == 0 else 0.0
        for lane in range(lanes):
            p = first + lane
            dm = d_meas[p]
            for a in range(12):
                for b in range(12):
                    dm_l[(12 * a + b) * 8 + lane] = dm[a, b]
            for a in range(6):
                for b in range(6):
                    cu_l[(6 * a + b) * 8 + lane] = cov_unit[p, a, b] * var[p]
        covariance_lanes(dm_l, cu_l, dcu_l, cov)
        factor_lanes(cov, low, inv)
        for lane in range(lanes):
            p = first + lane
            dm = d_meas[p]
            for k in range(12):  # (copies by loops: numba's slice assignment is slower)
                r = rhs[k]
                h_k = H[p, k]
                for j in range(n):
                    r[j] = h_k[j]
                dm_k = dm[k]
                for j in range(12):
                    r[n + j] = dm_k[j]
                model_k = model[p, k]
                for j in range(n_model):
                    r[n + 12 + j] = model_k[j]
                r[m - 1] = y[p, k]
            # W times every right-hand side: row a sums W[a, k] rhs[k] for k <= a, in order
            out[:] = 0.0
            rows_products(inv, lane, 96, 8, 12, 12, True, rhs_f, 0, 0, m, m, out, 0, m)
            for a in range(12):
                h_a = H[p, a]
                for j in range(n):
                    h_a[j] = out[m * a + j]
                y[p, a] = out[m * a + m - 1]
            # dr = (W D) sign sens (sens's model columns skipped: zero), then W model
            for a in range(12):
                for k in range(12):
                    coef[12 * a + k] = out[m * a + n + k] * sign[p]
            at = p * 12 * n_sys
            for j in range(12 * n_sys):
                dr_f[at + j] = 0.0
            rows_products(coef, 0, 12, 1, 12, 12, False, sens_f, at, 0, n_sys, n_s, dr_f, at, n_sys)
            for a in range(12):
                for j in range(n_model):
                    dr_f[at + a * n_sys + n_s + j] += out[m * a + n + 12 + j]


def covariance_lanes(dm: np.ndarray, cu: np.ndarray, dcu: np.ndarray, cov: np.ndarray) -> None:
    """Eight pairs' row covariances ``D diag(C, C) D^T`` (C = var cov_unit), each in its
    lane (``dm`` (12, 12), ``cu`` (6, 6), ``dcu`` work space (12, 6), ``cov`` (12, 12),
    lower triangle, entry (i, j) of lane l at (columns i + j) 8 + l), with the jitter on
    the diagonal. D = [[R, -I], [I, R]]: D[:, 6:] C is D[:, :6] C with its row blocks
    swapped, the upper one negated (exact), and the lower right block the upper left one
    (R C R^T + I C I^T, its two sums added in the other order: exact): the same bits as
    both halves in full, 2/3 of the products. Compiled,
    :func:`estimator.whiten_lanes.covariance_lanes` runs in its place (the same operations
    lane by lane)."""
    for lane in range(8):
        for a in range(12):
            for b in range(6):
                acc = 0.0
                for k in range(6):
                    acc += dm[(12 * a + k) * 8 + lane] * cu[(6 * k + b) * 8 + lane]
                dcu[(6 * a + b) * 8 + lane] = acc
        for a in range(12):  # (the lower triangle: all the Cholesky factor reads)
            for b in range(a + 1 if a < 6 else 6):
                acc_r = 0.0
                for k in range(6):
                    acc_r += dcu[(6 * a + k) * 8 + lane] * dm[(12 * b + k) * 8 + lane]
                acc_i = 0.0
                for k in range(6):
                    if a < 6:  # (- dcu[6 + a, k] dm[b, 6 + k], as a difference: exact)
                        acc_i -= dcu[(6 * a + 36 + k) * 8 + lane] * dm[(12 * b + 6 + k) * 8 + lane]
                    else:
                        acc_i += dcu[(6 * a - 36 + k) * 8 + lane] * dm[(12 * b + 6 + k) * 8 + lane]
                # (the halves added as they were)
                cov[(12 * a + b) * 8 + lane] = (0.0 + acc_r) + acc_i
        for a in range(6, 12):
            for b in range(6, a + 1):
                cov[(12 * a + b) * 8 + lane] = cov[(12 * a + b - 78) * 8 + lane]
        trace = 0.0
        for a in range(12):
            trace += cov[104 * a + lane]
        jitter = 1e-12 * trace / 12 + 1e-300
        for a in range(12):
            cov[104 * a + lane] += jitter


def factor_lanes(cov: np.ndarray, low: np.ndarray, inv: np.ndarray) -> None:
    """The Cholesky factors ``L`` (``L L^T = cov``) and their inverses ``W`` of eight
    (12, 12) matrices at once, each in its lane (entry (i, j) of lane l at (12 i + j) 8 +
    l; lower triangles read and written). Compiled,
    :func:`estimator.whiten_lanes.factor_lanes` (the eight lanes a vector) runs in its
    place: the same operations in the same order."""
    for lane in range(8):
        for j in range(12):
            acc = cov[104 * j + lane]
            for k in range(j):
                acc -= low[(12 * j + k) * 8 + lane] * low[(12 * j + k) * 8 + lane]
            d = np.sqrt(acc)
            low[104 * j + lane] = d
            for i in range(j + 1, 12):
                acc = cov[(12 * i + j) * 8 + lane]
                for k in range(j):
                    acc -= low[(12 * i + k) * 8 + lane] * low[(12 * j + k) * 8 + lane]
                low[(12 * i + j) * 8 + lane] = acc / d
        for j in range(12):
            inv[104 * j + lane] = 1.0 / low[104 * j + lane]
            for i in range(j + 1, 12):
                acc = 0.0
                for k in range(j, i):
                    acc -= low[(12 * i + k) * 8 + lane] * inv[(12 * k + j) * 8 + lane]
                inv[(12 * i + j) * 8 + lane] = acc / low[104 * i + lane]


def rows_products(
    c: np.ndarray,
    c_off: int,
    c_row: int,
    c_col: int,
    n_rows: int,
    n_terms: int,
    lower: bool,
    src: np.ndarray,
    s_off: int,
    s_row: int,
    s_stride: int,
    width: int,
    dst: np.ndarray,
    d_off: int,
    d_stride: int,
) -> None:
    """``dst[d_off + a d_stride + j] += C[a, k] src[s_off + a s_row + k s_stride + j]`` for rows a <
    ``n_rows``, terms k < ``n_terms`` (``lower``: k <= a) in order, each product added to
    the running sum, columns j < ``width``; ``C[a, k] = c[c_off + a c_row + k c_col]``
    (1-d arrays). Compiled, :func:`estimator.whiten_lanes.rows_products` (eight columns a
    vector) runs in its place: the same operations in the same order."""
    for a in range(n_rows):
        for j in range(width):
            acc = dst[d_off + a * d_stride + j]
            for k in range(a + 1 if lower else n_terms):
                acc += c[c_off + a * c_row + k * c_col] * src[s_off + a * s_row + k * s_stride + j]
            dst[d_off + a * d_stride + j] = acc


# (the references the compiled lanes are tested against)
rows_products_loops = rows_products
covariance_lanes_loops = covariance_lanes
factor_lanes_loops = factor_lanes
