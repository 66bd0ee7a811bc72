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

from typing import Any

import numpy as np
from numba import njit
from numba.core import cgutils
from numba.extending import intrinsic

from dsp.vec8 import vadd, vec8, vload, vmul, vsplat, vstore, vsub

_V8 = cgutils.ir.VectorType(cgutils.ir.DoubleType(), 8)


def _vdiv(typingctx, a, b):
    """Lane by lane ``a / b`` (IEEE: each lane the scalar division's bits)."""

    def codegen(context, builder, sig, args):
        return builder.fdiv(args[0], args[1])

    return vec8(vec8, vec8), codegen


def _vsqrt(typingctx, a):
    """Lane by lane square root (``llvm.sqrt``: correctly rounded, as ``np.sqrt``)."""

    def codegen(context, builder, sig, args):
        fn = cgutils.get_or_insert_function(
            builder.module, cgutils.ir.FunctionType(_V8, [_V8]), "llvm.sqrt.v8f64"
        )
        return builder.call(fn, args)

    return vec8(vec8), codegen


vdiv: Any = intrinsic(_vdiv)
vsqrt: Any = intrinsic(_vsqrt)


@njit(cache=True, nogil=True)
def covariance_lanes(dm: np.ndarray, cu: np.ndarray, dcu: np.ndarray, cov: np.ndarray) -> None:
    """:func:`estimator.whitened_rows.covariance_lanes`: eight pairs' row covariances, a
    lane each, the reference's operations lane by lane."""
    zero = vsplat(0.0)
    for a in range(12):
        for b in range(6):
            acc = zero
            for k in range(6):
                acc = vadd(acc, vmul(vload(dm, (12 * a + k) * 8), vload(cu, (6 * k + b) * 8)))
            vstore(dcu, (6 * a + b) * 8, acc)
    for a in range(12):
        for b in range(a + 1 if a < 6 else 6):
            acc_r = zero
            for k in range(6):
                acc_r = vadd(acc_r, vmul(vload(dcu, (6 * a + k) * 8), vload(dm, (12 * b + k) * 8)))
            acc_i = zero
            for k in range(6):
                im = vload(dm, (12 * b + 6 + k) * 8)
                if a < 6:
                    acc_i = vsub(acc_i, vmul(vload(dcu, (6 * a + 36 + k) * 8), im))
                else:
                    acc_i = vadd(acc_i, vmul(vload(dcu, (6 * a - 36 + k) * 8), im))
            vstore(cov, (12 * a + b) * 8, vadd(vadd(zero, acc_r), acc_i))
    for a in range(6, 12):
        for b in range(6, a + 1):
            vstore(cov, (12 * a + b) * 8, vload(cov, (12 * a + b - 78) * 8))
    trace = zero
    for a in range(12):
        trace = vadd(trace, vload(cov, 104 * a))
    jitter = vadd(vdiv(vmul(vsplat(1e-12), trace), vsplat(12.0)), vsplat(1e-300))
    for a in range(12):
        vstore(cov, 104 * a, vadd(vload(cov, 104 * a), jitter))


@njit(cache=True, nogil=True)
def factor_lanes(cov: np.ndarray, low: np.ndarray, inv: np.ndarray) -> None:
    """:func:`estimator.whitened_rows.factor_lanes`: eight matrices' Cholesky factors and
    their inverses, a lane each, the reference's operations lane by lane."""
    for j in range(12):
        acc = vload(cov, 104 * j)
        for k in range(j):
            ljk = vload(low, (12 * j + k) * 8)
            acc = vsub(acc, vmul(ljk, ljk))
        d = vsqrt(acc)
        vstore(low, 104 * j, d)
        for i in range(j + 1, 12):
            acc = vload(cov, (12 * i + j) * 8)
            for k in range(j):
                acc = vsub(acc, vmul(vload(low, (12 * i + k) * 8), vload(low, (12 * j + k) * 8)))
            vstore(low, (12 * i + j) * 8, vdiv(acc, d))
    for j in range(12):
        vstore(inv, 104 * j, vdiv(vsplat(1.0), vload(low, 104 * j)))
        for i in range(j + 1, 12):
            acc = vsplat(0.0)
            for k in range(j, i):
                acc = vsub(acc, vmul(vload(low, (12 * i + k) * 8), vload(inv, (12 * k + j) * 8)))
            vstore(inv, (12 * i + j) * 8, vdiv(acc, vload(low, 104 * i)))


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
    k s_stride + j]``, k in order. Below eight columns one by one; otherwise in blocks of
    two or four vectors, the last vector of the last block starting early enough to end
    at ``width`` (its lanes overlap the block's previous vector: both computed from the
    same loaded sums, the same bits, stored after)."""
    if width < 8:
        for j in range(width):
            acc = dst[d_off + j]
            for k in range(n_terms):
                acc += c[k] * src[s_off + k * s_stride + j]
            dst[d_off + j] = acc
        return
    j = 0
    while width - j > 32:
        if width - j >= 40:
            _block4(c, n_terms, src, s_off + j, s_stride, dst, d_off + j, 8, 16, 24)
            j += 32
        else:  # (32 < rest < 40: two vectors, leaving 17-23 columns for four)
            _block2(c, n_terms, src, s_off + j, s_stride, dst, d_off + j, 8)
            j += 16
    rest = width - j
    if rest <= 16:
        _block2(c, n_terms, src, s_off + j, s_stride, dst, d_off + j, rest - 8)
    else:
        _block4(c, n_terms, src, s_off + j, s_stride, dst, d_off + j, 8, rest - 16, rest - 8)


@njit(cache=True, nogil=True)
def _block2(c, n_terms, src, s_off, s_stride, dst, d_off, o1):
    """Columns 0-7 and o1 .. o1 + 7 (o1 <= 8) of :func:`add_products`, from ``d_off``."""
    a0 = vload(dst, d_off)
    a1 = vload(dst, d_off + o1)
    for k in range(n_terms):
        ck = vsplat(c[k])
        at = s_off + k * s_stride
        a0 = vadd(a0, vmul(ck, vload(src, at)))
        a1 = vadd(a1, vmul(ck, vload(src, at + o1)))
    vstore(dst, d_off, a0)
    vstore(dst, d_off + o1, a1)


@njit(cache=True, nogil=True)
def _block4(c, n_terms, src, s_off, s_stride, dst, d_off, o1, o2, o3):
    """Columns 0-7, o1.., o2.., o3 .. o3 + 7 of :func:`add_products`, from ``d_off``."""
    a0 = vload(dst, d_off)
    a1 = vload(dst, d_off + o1)
    a2 = vload(dst, d_off + o2)
    a3 = vload(dst, d_off + o3)
    for k in range(n_terms):
        ck = vsplat(c[k])
        at = s_off + k * s_stride
        a0 = vadd(a0, vmul(ck, vload(src, at)))
        a1 = vadd(a1, vmul(ck, vload(src, at + o1)))
        a2 = vadd(a2, vmul(ck, vload(src, at + o2)))
        a3 = vadd(a3, vmul(ck, vload(src, at + o3)))
    vstore(dst, d_off, a0)
    vstore(dst, d_off + o1, a1)
    vstore(dst, d_off + o2, a2)
    vstore(dst, d_off + o3, a3)
