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

Issue 24 (ninth wave): the row count is kept in the kernel (``rows_after`` of
``np.diff(bounds)`` was 0.8 ms a minute of Python around it). The sums by
:func:`estimator.whiten_lanes.rows_products` (eight columns a vector, two rows at a time;
the same bits) were tried: 6.6-6.8 -> 6.1-6.2 ms a minute on the 60 s log's calls, but
LLVM inlines that helper at each of its six call sites (5.6 s of compilation against
1.0 s), and with one call site the kernel was slower than these loops (7.8 ms), so the
loops stay (fused multiply-adds, tried too, gained 0.3 ms and would change the bits).
"""

from __future__ import annotations

import numpy as np

from estimator.hypotheses import Accumulator
from estimator.rls import RlsState
from estimator.row_kernels import jit


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
    info_f = np.empty((m, m))
    vec_f = np.empty(m)
    sens_f = np.empty((m, n_sys))
    a = np.empty((n, n))  # one pair's H^T H (upper triangle), H^T y, H^T dr
    v = np.empty(n)
    s = np.empty((n, n_sys))
    for f in range(bounds.shape[0] - 1):
        info_f[:, :] = 0.0
        vec_f[:] = 0.0
        sens_f[:, :] = 0.0
        yty_f = 0.0
        for p in range(bounds[f], bounds[f + 1]):
            a[:, :] = 0.0
            v[:] = 0.0
            s[:, :] = 0.0
            for r in range(12):
                row = H[p, r]
                d_row = dr[p, r]
                yr = y[p, r]
                yty_f += yr * yr
                for i in range(n_tail):  # (the pair's own sums: the tail's are scaled from them)
                    hi = row[i]
                    v[i] += hi * yr
                    a_i = a[i]
                    for j in range(i, n):
                        a_i[j] += hi * row[j]
                    s_i = s[i]
                    for j in range(n_sys):
                        s_i[j] += hi * d_row[j]
                for i in range(n_tail, n):  # (the frame's sums, directly)
                    hi = row[i]
                    vec_f[i] += hi * yr
                    info_i = info_f[i]
                    for j in range(i, n):
                        info_i[j] += hi * row[j]
                    sens_i = sens_f[i]
                    for j in range(n_sys):
                        sens_i[j] += hi * d_row[j]
            ph = phi[p]
            ph2 = ph * ph
            for i in range(n_tail):
                vec_f[i] += v[i]
                for j in range(i, n):
                    info_f[i, j] += a[i, j]
                for j in range(n_tail):  # theta x tail: phi H_i^T H_j
                    info_f[i, n + j] += ph * (a[i, j] if i <= j else a[j, i])
                for j in range(n_sys):
                    sens_f[i, j] += s[i, j]
                vec_f[n + i] += ph * v[i]
                for j in range(i, n_tail):  # tail x tail: phi^2 H_i^T H_j
                    info_f[n + i, n + j] += ph2 * a[i, j]
                for j in range(n_sys):
                    sens_f[n + i, j] += ph * s[i, j]
            for i in range(n_tail, n):
                for j in range(n_tail):
                    info_f[i, n + j] += ph * a[j, i]
        for i in range(m):
            for j in range(i + 1, m):
                info_f[j, i] = info_f[i, j]
        for i in range(m):
            vec[i] = lam * vec[i] + vec_f[i]
            for j in range(m):
                info[i, j] = lam * info[i, j] + info_f[i, j]
            for j in range(n_sys):
                sens[i, j] = lam * sens[i, j] + sens_f[i, j]
        yty[0] = lam * yty[0] + yty_f
        if lam != 1.0:
            rows[0] = lam * rows[0] + 12.0 * (bounds[f + 1] - bounds[f])
    if lam == 1.0:
        rows[0] = rows[0] + 12.0 * (bounds[bounds.shape[0] - 1] - bounds[0])
