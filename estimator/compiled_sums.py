"""The compiled RLS sums of consecutive frames' rows, their elastic-tail columns included.

With ``PTINERTIA_NUMBA=1`` :func:`estimator.elastic_tail.add_with_tail` adds a flush's
rows to a sign hypothesis's state by :func:`tail_sums` (numba) instead of
:func:`estimator.elastic_tail.with_tail` and :func:`estimator.hypotheses.add_frames`
(numpy, the default and the reference).

The tail's columns of a pair are its first ``ELASTIC_TERMS`` columns times
``phi = (f / ELASTIC_F_REF_HZ)^2``: a pair's sums over them are ``phi`` (or ``phi^2``)
times sums the pair has already formed over theta's columns. So the sums of a pair's
first ``ELASTIC_TERMS`` rows of ``H^T H``, ``H^T y`` and ``H^T dr`` are formed on their
own, over theta's n columns, and the tail's blocks scaled from them, rather than formed
over n + 9 columns of a widened copy of H (12 x 12 x 34 instead of 12 x 21 x 34
multiplications for a pair's ``H^T dr``, the widest sum); the other rows go straight
into the frame's sums, as before. Measured on the 60 s log (``/tmp/prof/est_prof2.py``'s
blocks: 4494 pairs in 128 flushes; CPU time best of 9, load 7 on the 2 cores): the
kernel 9.2-9.5 -> 6.5-7.1 ms a minute, and the widened copy (``with_tail``, 1.5 ms) is
not made; the compiled estimator in blocks 65-67 -> 59-60 us per used frame (same load).

How close: a tail entry is ``phi`` times the pair's sum where numpy sums the products
of the scaled columns, and each frame's sums over the first rows are the sums of its
pairs' (numpy: of all its rows at once, BLAS ordering them its own way): the same
values within rounding (tests/estimator/test_row_kernels.py); the tail enters an
estimate only once an elastic mode is confirmed. Summing those rows pair by pair rather
than row by row moves the compiled estimate by rounding alike: in the 1 %-noise runs of
tests/estimator/test_compiled_runs.py (seeds 2-9) the largest difference from numpy, in
1e-12 of the value or interval of a near-zero unbalance, is 0.2-1.6 here and 0.2-1.6
before. ``ptinertia run --realistic`` (compiled against numpy): every estimate and
interval within 1e-13 relative (3.2e-13 before), a principal axis component 1.7e-13
(1.4e-12 before); the half-order residual ratio 1.7e-11 (4.4e-11).
Frame by frame or in blocks, the state gets the same bits.

Issue 24: a pair's sums are three calls of :func:`estimator.whitened_rows.rows_products`
per group of rows (H^T H, H^T y, H^T dr; row i's coefficients column i of the pair's H),
compiled as :func:`estimator.whiten_lanes.rows_products` (eight columns a vector, two rows
at a time), and the tail's scaled blocks three more; every sum the same products in the
same order as the loops before (the 60 s log's 54 calls: the same bits). The row count
is kept in the kernel (``rows_after`` of ``np.diff(bounds)`` was 0.8 ms a minute of Python
around it). Kernel on the 60 s log's calls (CPU best of 50, load 2.5): 6.56-6.75 -> 6.13-6.20
ms a minute; the sums are bound by the vector additions (fused multiply-adds, tried,
gained 0.3 ms and would change the bits).
"""

from __future__ import annotations

import numpy as np

from estimator.hypotheses import Accumulator
from estimator.rls import RlsState
from estimator.row_kernels import jit
from estimator.whitened_rows import rows_products

# estimator.row_kernels.jit compiles tail_sums with the eight-lane rows_products (the
# loops' bits); numba's cache watches this file only: the helpers' sha256 (tested)
LANES_MODULE = "estimator.whiten_lanes"
LANE_HELPERS = ("rows_products",)
HELPERS = ("estimator/whiten_lanes.py", "dsp/vec8.py")
HELPERS_SHA256 = "7dcf35261a4e1a1a649e12240f19768cf656697a59c676fbfb7e03d343d6e79b"


def kernel_tail_sums(
    acc: Accumulator,
    H: np.ndarray,
    y: np.ndarray,
    dr: np.ndarray,
    bounds: np.ndarray,
    forgetting: float,
    phi: np.ndarray,
    n_tail: int,
    compiled: bool = True,
) -> Accumulator:
    """``acc`` (over theta's n and the tail's ``n_tail`` columns) after consecutive frames'
    rows: :func:`estimator.hypotheses.add_frames` of the rows widened by
    :func:`estimator.elastic_tail.with_tail` (``phi`` (P,) the pairs' tail factors), by
    :func:`tail_sums`. H (P, 12, n) without the tail; frame f's rows are
    ``H[bounds[f]:bounds[f + 1]]``, ``y`` and ``dr`` alike. New arrays; ``compiled=False``:
    the loops run by the interpreter (tests without numba)."""
    st = acc.state
    info, vec, sens = st.info.copy(), st.vec.copy(), acc.sens.copy()
    yty = np.array([st.yty])
    rows = np.array([st.rows])
    (jit(tail_sums) if compiled else tail_sums)(
        np.ascontiguousarray(H),
        np.ascontiguousarray(y),
        np.ascontiguousarray(dr),
        np.ascontiguousarray(phi, float),
        np.asarray(bounds, np.int64),
        float(forgetting),
        n_tail,
        info,
        vec,
        yty,
        sens,
        rows,
    )
    return Accumulator(RlsState(info, vec, float(yty[0]), float(rows[0])), sens)


def tail_sums(
    H: np.ndarray,
    y: np.ndarray,
    dr: np.ndarray,
    phi: np.ndarray,
    bounds: np.ndarray,
    lam: float,
    n_tail: int,
    info: np.ndarray,
    vec: np.ndarray,
    yty: np.ndarray,
    sens: np.ndarray,
    rows: np.ndarray,
) -> None:
    """Per frame ``Lambda <- lam Lambda + Ha^T Ha``, ``eta <- lam eta + Ha^T y``, ``yty <-
    lam yty + y^T y``, ``S <- lam S + Ha^T dr`` in place, ``Ha`` the rows H (pairs, 12, n)
    with their tail columns (a pair's first ``n_tail`` columns times its ``phi``): each
    frame's sums formed pair by pair (in row order), its pairs' then added, and then the
    frame's added to the state in stream order (the state does not depend on how the
    frames were batched). ``info`` (n + n_tail, n + n_tail), ``vec``, ``sens`` likewise;
    ``rows`` (1,) the row count, as :func:`estimator.hypotheses.rows_after` counts it (the
    same operations: one sum without forgetting, else frame by frame)."""
    n = H.shape[2]
    n_sys = dr.shape[2]
    m = n + n_tail
    # a row of the sums: H^T H over theta's columns, H^T y, H^T dr, the tail's columns
    t0 = n + 1 + n_sys
    w = t0 + n_tail
    pair = np.empty(n_tail * w)  # a pair's sums over its first n_tail columns of H
    frame = np.empty(m * w)  # the frame's sums
    scale = np.empty(3)  # 1, phi and phi^2 of a pair
    scale[0] = 1.0
    h_f, y_f, dr_f = H.reshape(H.size), y.reshape(y.size), dr.reshape(dr.size)
    for f in range(bounds.shape[0] - 1):
        frame[:] = 0.0
        yty_f = 0.0
        for p in range(bounds[f], bounds[f + 1]):
            for r in range(12):
                yty_f += y[p, r] * y[p, r]
            # H^T H, H^T y, H^T dr of the pair, row i from column i of H (C[i, r] =
            # H[p, r, i]), its rows' terms in row order; whole rows (the lower
            # triangles' entries are never read): rows below n_tail the pair's own (the
            # tail's sums are scaled from them), the others straight into the frame's
            pair[:] = 0.0
            hp, yp, dp = p * 12 * n, p * 12, p * 12 * n_sys
            for i0 in (0, n_tail):
                dst = pair if i0 == 0 else frame
                n_i = n_tail if i0 == 0 else n - n_tail
                d0 = i0 * w
                rows_products(h_f, hp + i0, 1, n, n_i, 12, False, h_f, hp, 0, n, n, dst, d0, w)
                rows_products(h_f, hp + i0, 1, n, n_i, 12, False, y_f, yp, 0, 1, 1, dst, d0 + n, w)
                rows_products(h_f, hp + i0, 1, n, n_i, 12, False, dr_f, dp, 0, n_sys, n_sys,
                              dst, d0 + n + 1, w)  # fmt: skip
            phi_p = phi[p]
            scale[1] = phi_p
            scale[2] = phi_p * phi_p
            for i in range(n_tail):
                for j in range(n_tail):  # theta x tail: phi H_i^T H_j
                    pair[i * w + t0 + j] = phi_p * (pair[i * w + j] if i <= j else pair[j * w + i])
            for i in range(n_tail, n):
                for j in range(n_tail):
                    frame[i * w + t0 + j] += phi_p * pair[j * w + i]
            # the pair's rows into the frame's; the tail's: phi^2 H_i^T H_j, phi H_i^T y,
            # phi H_i^T dr
            rows_products(scale, 0, 0, 0, 1, 1, False, pair, 0, 0, 0, n_tail * w, frame, 0, 0)
            rows_products(scale, 2, 0, 0, n_tail, 1, False, pair, 0, w, 0, n_tail, frame,
                          n * w + t0, w)  # fmt: skip
            rows_products(scale, 1, 0, 0, n_tail, 1, False, pair, n, w, 0, 1 + n_sys, frame,
                          n * w + n, w)  # fmt: skip
        for i in range(m):
            vec[i] = lam * vec[i] + frame[i * w + n]
            for j in range(m):  # (the upper triangle mirrored)
                a, b = (i, j) if i <= j else (j, i)
                info[i, j] = lam * info[i, j] + frame[a * w + (b if b < n else t0 + b - n)]
            for j in range(n_sys):
                sens[i, j] = lam * sens[i, j] + frame[i * w + n + 1 + j]
        yty[0] = lam * yty[0] + yty_f
        if lam != 1.0:
            rows[0] = lam * rows[0] + 12.0 * (bounds[f + 1] - bounds[f])
    if lam == 1.0:
        rows[0] = rows[0] + 12.0 * (bounds[bounds.shape[0] - 1] - bounds[0])
