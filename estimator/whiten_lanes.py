"""The eight-lane code of :func:`estimator.whitened_rows.whiten_pairs`, compiled only.

Imported only where the compiled path runs (:func:`estimator.row_kernels.jit`, for the
kernels that name it): it imports numba and :mod:`dsp.vec8`. Each function does what
its namesake in :mod:`estimator.whitened_rows` (the loops, the reference) does, with
LLVM's ``<8 x double>`` (:mod:`dsp.vec8`, plus a division and a square root here, both
correctly rounded): the same operations in the same order lane by lane, no fused
multiply-add, so the same bits (tested). :func:`covariance_lanes` and
:func:`factor_lanes` hold eight pairs, a pair a lane (the factorisation is a chain of
square roots and divisions: one pair at a time it waited on their latency);
:func:`rows_products` eight columns a vector, four vectors kept in registers while the
terms are added. Why not numba's own loops: the two-index ones stayed scalar, and the
vectorised ones over row views reload and store the sums at every term and test for
overlap and remainders at every call, on rows of 12-34 columns (measured in
:mod:`estimator.whitened_rows`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit
from numba.core import cgutils
from numba.extending import intrinsic

from dsp.vec8 import vadd, vec8, vload, vmul, vsplat, vstore, vsub

# numba's cache watches this file only, and its functions are cached on their own: the
# sha256 of the intrinsics they inline (tests/estimator/test_whitened_rows.py prints a new
# value; estimator.whitened_rows' covers this file and those)
HELPERS = ("dsp/vec8.py",)
HELPERS_SHA256 = "802c7d9e173a37e0c2a708d61c8ccf89719d6eeb491775652c8b984c379a676f"

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
    """:func:`estimator.whitened_rows.rows_products`, each row's products rounded and
    added in order (the loops' bits), eight columns a vector: below eight columns one by
    one; otherwise blocks of four vectors (two for 16 columns or fewer), the last vector of
    the last block starting early enough to end at ``width`` (its lanes overlap the
    block's previous vector: both computed from the same loaded sums, the same bits,
    stored after). All in one function: a call of a compiled helper with three arrays
    costs ~20 ns, as much as a block's arithmetic."""
    a = 0
    while a < n_rows:
        nt = a + 1 if lower else n_terms
        ca = c_off + a * c_row
        sa = s_off + a * s_row
        da = d_off + a * d_stride
        if s_row == 0 and a + 1 < n_rows and 8 <= width <= 40:
            nt1 = (a + 2) if lower else n_terms
            if width <= 16:
                _two_rows2(c, ca, c_row, c_col, nt, nt1, src, s_off, s_stride, width, dst,
                           da, d_stride)  # fmt: skip
            elif width <= 32:
                _two_rows(c, ca, c_row, c_col, nt, nt1, src, s_off, s_stride, width, dst,
                          da, d_stride)  # fmt: skip
            else:
                _two_rows5(c, ca, c_row, c_col, nt, nt1, src, s_off, s_stride, width, dst,
                           da, d_stride)  # fmt: skip
            a += 2
            continue
        a += 1
        if width < 8:
            for j in range(width):
                acc = dst[da + j]
                for k in range(nt):
                    acc += c[ca + k * c_col] * src[sa + k * s_stride + j]
                dst[da + j] = acc
            continue
        j = 0
        while j < width:
            # (a block's vectors: 2 up to 16 columns, 4 up to 32, 5 up to 40, else the
            # first 32 columns in 4; the last vector ends at the block's last column)
            rest = width - j
            last = min(rest, 40 if rest <= 40 else 32) - 8
            o1 = min(8, last)
            o2, o3 = (16, 24) if rest > 32 else (rest - 16, rest - 8)
            d0 = da + j
            a0 = vload(dst, d0)
            a1 = vload(dst, d0 + o1)
            if rest <= 16:
                for k in range(nt):
                    ck = vsplat(c[ca + k * c_col])
                    at = sa + k * s_stride + j
                    a0 = vadd(a0, vmul(ck, vload(src, at)))
                    a1 = vadd(a1, vmul(ck, vload(src, at + o1)))
            elif rest <= 32 or rest > 40:
                a2 = vload(dst, d0 + o2)
                a3 = vload(dst, d0 + o3)
                for k in range(nt):
                    ck = vsplat(c[ca + k * c_col])
                    at = sa + k * s_stride + j
                    a0 = vadd(a0, vmul(ck, vload(src, at)))
                    a1 = vadd(a1, vmul(ck, vload(src, at + o1)))
                    a2 = vadd(a2, vmul(ck, vload(src, at + o2)))
                    a3 = vadd(a3, vmul(ck, vload(src, at + o3)))
                vstore(dst, d0 + o2, a2)
                vstore(dst, d0 + o3, a3)
            else:
                a2 = vload(dst, d0 + 16)
                a3 = vload(dst, d0 + 24)
                a4 = vload(dst, d0 + last)
                for k in range(nt):
                    ck = vsplat(c[ca + k * c_col])
                    at = sa + k * s_stride + j
                    a0 = vadd(a0, vmul(ck, vload(src, at)))
                    a1 = vadd(a1, vmul(ck, vload(src, at + 8)))
                    a2 = vadd(a2, vmul(ck, vload(src, at + 16)))
                    a3 = vadd(a3, vmul(ck, vload(src, at + 24)))
                    a4 = vadd(a4, vmul(ck, vload(src, at + last)))
                vstore(dst, d0 + 16, a2)
                vstore(dst, d0 + 24, a3)
                vstore(dst, d0 + last, a4)
            vstore(dst, d0, a0)
            vstore(dst, d0 + o1, a1)
            j += rest if rest <= 40 else 32


@njit(cache=True, nogil=True, inline="always")
def _two_rows(c, ca, c_row, c_col, nt0, nt1, src, s_off, s_stride, width, dst, da, d_stride):
    """Two consecutive rows of :func:`rows_products` (``nt0`` and ``nt1`` >= ``nt0`` terms,
    17-32 columns, the same source rows): their sums interleaved, each in its own order
    (two chains for the latency of an addition to hide behind), each source vector loaded
    once for both."""
    o2, o3 = width - 16, width - 8
    db = da + d_stride
    cb = ca + c_row
    a0, a1, a2, a3 = vload(dst, da), vload(dst, da + 8), vload(dst, da + o2), vload(dst, da + o3)
    b0, b1, b2, b3 = vload(dst, db), vload(dst, db + 8), vload(dst, db + o2), vload(dst, db + o3)
    for k in range(nt0):
        at = s_off + k * s_stride
        x0, x1, x2, x3 = (
            vload(src, at),
            vload(src, at + 8),
            vload(src, at + o2),
            vload(src, at + o3),
        )
        ka = vsplat(c[ca + k * c_col])
        kb = vsplat(c[cb + k * c_col])
        a0 = vadd(a0, vmul(ka, x0))
        b0 = vadd(b0, vmul(kb, x0))
        a1 = vadd(a1, vmul(ka, x1))
        b1 = vadd(b1, vmul(kb, x1))
        a2 = vadd(a2, vmul(ka, x2))
        b2 = vadd(b2, vmul(kb, x2))
        a3 = vadd(a3, vmul(ka, x3))
        b3 = vadd(b3, vmul(kb, x3))
    for k in range(nt0, nt1):  # (the second row's last terms, lower triangular)
        at = s_off + k * s_stride
        kb = vsplat(c[cb + k * c_col])
        b0 = vadd(b0, vmul(kb, vload(src, at)))
        b1 = vadd(b1, vmul(kb, vload(src, at + 8)))
        b2 = vadd(b2, vmul(kb, vload(src, at + o2)))
        b3 = vadd(b3, vmul(kb, vload(src, at + o3)))
    vstore(dst, da, a0)
    vstore(dst, da + 8, a1)
    vstore(dst, da + o2, a2)
    vstore(dst, da + o3, a3)
    vstore(dst, db, b0)
    vstore(dst, db + 8, b1)
    vstore(dst, db + o2, b2)
    vstore(dst, db + o3, b3)


@njit(cache=True, nogil=True, inline="always")
def _two_rows2(c, ca, c_row, c_col, nt0, nt1, src, s_off, s_stride, width, dst, da, d_stride):
    """:func:`_two_rows` for 8-16 columns (two vectors a row)."""
    o1 = width - 8
    db = da + d_stride
    cb = ca + c_row
    a0, a1 = vload(dst, da), vload(dst, da + o1)
    b0, b1 = vload(dst, db), vload(dst, db + o1)
    for k in range(nt0):
        at = s_off + k * s_stride
        x0, x1 = vload(src, at), vload(src, at + o1)
        ka = vsplat(c[ca + k * c_col])
        kb = vsplat(c[cb + k * c_col])
        a0 = vadd(a0, vmul(ka, x0))
        b0 = vadd(b0, vmul(kb, x0))
        a1 = vadd(a1, vmul(ka, x1))
        b1 = vadd(b1, vmul(kb, x1))
    for k in range(nt0, nt1):
        at = s_off + k * s_stride
        kb = vsplat(c[cb + k * c_col])
        b0 = vadd(b0, vmul(kb, vload(src, at)))
        b1 = vadd(b1, vmul(kb, vload(src, at + o1)))
    vstore(dst, da, a0)
    vstore(dst, da + o1, a1)
    vstore(dst, db, b0)
    vstore(dst, db + o1, b1)


@njit(cache=True, nogil=True, inline="always")
def _two_rows5(c, ca, c_row, c_col, nt0, nt1, src, s_off, s_stride, width, dst, da, d_stride):
    """:func:`_two_rows` for 33-40 columns (five vectors a row)."""
    o4 = width - 8
    db = da + d_stride
    cb = ca + c_row
    a0, a1, a2, a3 = vload(dst, da), vload(dst, da + 8), vload(dst, da + 16), vload(dst, da + 24)
    b0, b1, b2, b3 = vload(dst, db), vload(dst, db + 8), vload(dst, db + 16), vload(dst, db + 24)
    a4, b4 = vload(dst, da + o4), vload(dst, db + o4)
    for k in range(nt0):
        at = s_off + k * s_stride
        x0, x1, x2, x3 = (
            vload(src, at),
            vload(src, at + 8),
            vload(src, at + 16),
            vload(src, at + 24),
        )
        x4 = vload(src, at + o4)
        ka = vsplat(c[ca + k * c_col])
        kb = vsplat(c[cb + k * c_col])
        a0 = vadd(a0, vmul(ka, x0))
        b0 = vadd(b0, vmul(kb, x0))
        a1 = vadd(a1, vmul(ka, x1))
        b1 = vadd(b1, vmul(kb, x1))
        a2 = vadd(a2, vmul(ka, x2))
        b2 = vadd(b2, vmul(kb, x2))
        a3 = vadd(a3, vmul(ka, x3))
        b3 = vadd(b3, vmul(kb, x3))
        a4 = vadd(a4, vmul(ka, x4))
        b4 = vadd(b4, vmul(kb, x4))
    for k in range(nt0, nt1):
        at = s_off + k * s_stride
        kb = vsplat(c[cb + k * c_col])
        b0 = vadd(b0, vmul(kb, vload(src, at)))
        b1 = vadd(b1, vmul(kb, vload(src, at + 8)))
        b2 = vadd(b2, vmul(kb, vload(src, at + 16)))
        b3 = vadd(b3, vmul(kb, vload(src, at + 24)))
        b4 = vadd(b4, vmul(kb, vload(src, at + o4)))
    vstore(dst, da, a0)
    vstore(dst, da + 8, a1)
    vstore(dst, da + 16, a2)
    vstore(dst, da + 24, a3)
    vstore(dst, da + o4, a4)
    vstore(dst, db, b0)
    vstore(dst, db + 8, b1)
    vstore(dst, db + 16, b2)
    vstore(dst, db + 24, b3)
    vstore(dst, db + o4, b4)
