"""The eight-lane sums of :func:`estimator.whitened_rows.whiten_pairs`, compiled only.

Imported only where the compiled path runs (:func:`estimator.row_kernels.jit`, for the
kernels that name it): it imports numba and :mod:`dsp.vec8`. :func:`add_products` does
what :func:`estimator.whitened_rows.add_products` (the loops, the reference) does, with
eight columns a vector (LLVM's ``<8 x double>``, :mod:`dsp.vec8`) and four vectors kept
in registers while the terms are added: each lane is one column's running sum, the
products added in the same order with the same roundings (no fused multiply-add), so the
same bits (tested). Why not numba's own loops: vectorised, they reload and store the
sums at every term and test for overlap and remainders at every call, and the calls are
short (12 terms, 12-34 columns): most of their time went there (measured in
:mod:`estimator.whitened_rows`).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from dsp.vec8 import vadd, vload, vmul, vsplat, vstore


@njit(cache=True, nogil=True)
def add_products(
    c: np.ndarray,
    n_terms: int,
    src: np.ndarray,
    s_off: int,
    s_stride: int,
    width: int,
    dst: np.ndarray,
    d_off: int,
) -> None:
    """:func:`estimator.whitened_rows.add_products`: ``dst[d_off + j] += c[k] src[s_off +
    k s_stride + j]``, k in order; 32 columns, then 8, a pass, the rest one by one."""
    j = 0
    while j + 32 <= width:
        a0 = vload(dst, d_off + j)
        a1 = vload(dst, d_off + j + 8)
        a2 = vload(dst, d_off + j + 16)
        a3 = vload(dst, d_off + j + 24)
        for k in range(n_terms):
            ck = vsplat(c[k])
            at = s_off + k * s_stride + j
            a0 = vadd(a0, vmul(ck, vload(src, at)))
            a1 = vadd(a1, vmul(ck, vload(src, at + 8)))
            a2 = vadd(a2, vmul(ck, vload(src, at + 16)))
            a3 = vadd(a3, vmul(ck, vload(src, at + 24)))
        vstore(dst, d_off + j, a0)
        vstore(dst, d_off + j + 8, a1)
        vstore(dst, d_off + j + 16, a2)
        vstore(dst, d_off + j + 24, a3)
        j += 32
    while j + 8 <= width:
        a0 = vload(dst, d_off + j)
        for k in range(n_terms):
            a0 = vadd(a0, vmul(vsplat(c[k]), vload(src, s_off + k * s_stride + j)))
        vstore(dst, d_off + j, a0)
        j += 8
    while j < width:
        acc = dst[d_off + j]
        for k in range(n_terms):
            acc += c[k] * src[s_off + k * s_stride + j]
        dst[d_off + j] = acc
        j += 1
