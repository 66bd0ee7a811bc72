"""Eight float64 lanes as one numba value (LLVM's ``<8 x double>``) and what the compiled
segment sums (:mod:`dsp.fused_sums`) do with them.

Imported only by the compiled kernels (it imports numba and llvmlite: never on the
default path). Each function is a numba intrinsic, callable from compiled code only;
the arithmetic carries no fast-math flags (IEEE, no contraction), so a lane rounds as
the scalar operation would. numba's cache does not watch this file: after changing it,
set anew the ``HELPERS_SHA256`` of every module that inlines it, each with cached
functions of its own (:mod:`dsp.fused_sums`, :mod:`dsp.fused_ramps`,
:mod:`dsp.spectrum_lanes`, :mod:`estimator.whiten_lanes`, :mod:`estimator.whitened_rows`;
their tests print the values), so no cached machine code of the old one is loaded.
"""

from __future__ import annotations

from typing import Any

from numba.core import cgutils, types
from numba.extending import intrinsic, models, register_model

# llvmlite's IR builder as numba itself imports it: llvmlite comes with numba, pinned by
# it, and the fast extra stays one package (numba)
ir = cgutils.ir

_V8 = ir.VectorType(ir.DoubleType(), 8)
_MASK = ir.VectorType(ir.IntType(32), 8)


class Vec8Type(types.Type):
    """Eight float64 lanes, held as LLVM's ``<8 x double>``."""

    def __init__(self) -> None:
        super().__init__(name="Vec8")


vec8 = Vec8Type()


@register_model(Vec8Type)
class _Vec8Model(models.PrimitiveModel):
    def __init__(self, dmm, fe_type):
        super().__init__(dmm, fe_type, _V8)


def _is_f8(arr: types.Type) -> bool:
    return isinstance(arr, types.Array) and arr.dtype == types.float64 and arr.layout == "C"


def _ptr(context, builder, aryty, ary, idx):
    """``&ary[idx]`` as a pointer to eight lanes (unaligned: 8-byte alignment only)."""
    data = context.make_array(aryty)(context, builder, ary).data
    return builder.bitcast(builder.gep(data, [idx]), _V8.as_pointer())


def _vzero(typingctx):
    """Eight zeros."""
    return vec8(), lambda context, builder, sig, args: ir.Constant(_V8, [0.0] * 8)


vzero: Any = intrinsic(_vzero)


def _vsplat(typingctx, x):
    """``x`` in every lane."""

    def codegen(context, builder, sig, args):
        one = builder.insert_element(ir.Constant(_V8, ir.Undefined), args[0], ir.IntType(32)(0))
        return builder.shuffle_vector(one, ir.Constant(_V8, ir.Undefined), _MASK([0] * 8))

    return vec8(types.float64), codegen


vsplat: Any = intrinsic(_vsplat)


def _vload(typingctx, arr, i):
    """``arr[i : i + 8]`` (1-d float64, C order; no bounds check)."""
    if not _is_f8(arr) or arr.ndim != 1:
        return None

    def codegen(context, builder, sig, args):
        return builder.load(_ptr(context, builder, sig.args[0], args[0], args[1]), align=8)

    return vec8(arr, types.intp), codegen


vload: Any = intrinsic(_vload)


def _vstore(typingctx, arr, i, v):
    """``arr[i : i + 8] = v`` (1-d float64, C order; no bounds check)."""
    if not _is_f8(arr) or arr.ndim != 1:
        return None

    def codegen(context, builder, sig, args):
        builder.store(args[2], _ptr(context, builder, sig.args[0], args[0], args[1]), align=8)
        return context.get_dummy_value()

    return types.none(arr, types.intp, vec8), codegen


vstore: Any = intrinsic(_vstore)


def _binary(op: str) -> Any:
    """The lane-by-lane ``op`` (``fadd``, ``fsub``, ``fmul``) of two vectors."""

    def typer(typingctx, a, b):
        def codegen(context, builder, sig, args):
            # no fast-math flags: IEEE, and LLVM contracts no multiply-add
            return getattr(builder, op)(args[0], args[1])

        return vec8(vec8, vec8), codegen

    typer.__name__ = typer.__qualname__ = "v" + op[1:]  # one name per intrinsic
    return intrinsic(typer)


vadd: Any = _binary("fadd")
vsub: Any = _binary("fsub")
vmul: Any = _binary("fmul")


def _vfma(typingctx, a, b, c):
    """``a * b + c`` rounded once (``llvm.fma``: the same bits with or without FMA hardware)."""

    def codegen(context, builder, sig, args):
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(_V8, [_V8] * 3), "llvm.fma.v8f64"
        )
        return builder.call(fn, args)

    return vec8(vec8, vec8, vec8), codegen


vfma: Any = intrinsic(_vfma)


def _shuffle(builder, a, b, mask):
    return builder.shuffle_vector(a, b, _MASK(mask))


def _vtranspose8(typingctx, src, src_off, dst, dst_off, dst_stride):
    """``dst[dst_off + l dst_stride + j] = src[src_off + 8 j + l]`` for j, l in 0..7: eight
    rows of eight lanes stored as eight columns (three rounds of shuffles, 24 in all)."""
    if not (_is_f8(src) and _is_f8(dst) and src.ndim == dst.ndim == 1):
        return None

    def codegen(context, builder, sig, args):
        s_ary, s_off, d_ary, d_off, d_stride = args
        rows = [
            builder.load(
                _ptr(context, builder, sig.args[0], s_ary, builder.add(s_off, s_off.type(8 * j))),
                align=8,
            )
            for j in range(8)
        ]
        # pairs of rows: even lanes of both, odd lanes of both
        even, odd = [0, 8, 2, 10, 4, 12, 6, 14], [1, 9, 3, 11, 5, 13, 7, 15]
        pairs = [
            (_shuffle(builder, r0, r1, even), _shuffle(builder, r0, r1, odd))
            for r0, r1 in zip(rows[0::2], rows[1::2], strict=True)
        ]
        # quads of rows: lanes (0, 4), (1, 5), (2, 6), (3, 7) of four rows
        low, high = [0, 1, 8, 9, 4, 5, 12, 13], [2, 3, 10, 11, 6, 7, 14, 15]
        quads = []
        for lo, hi in (pairs[0:2], pairs[2:4]):
            quads.append(
                [
                    _shuffle(builder, lo[0], hi[0], low),
                    _shuffle(builder, lo[1], hi[1], low),
                    _shuffle(builder, lo[0], hi[0], high),
                    _shuffle(builder, lo[1], hi[1], high),
                ]
            )
        for lane in range(4):
            first = _shuffle(builder, quads[0][lane], quads[1][lane], [0, 1, 2, 3, 8, 9, 10, 11])
            second = _shuffle(builder, quads[0][lane], quads[1][lane], [4, 5, 6, 7, 12, 13, 14, 15])
            for at, v in ((lane, first), (lane + 4, second)):
                off = builder.add(d_off, builder.mul(d_stride, d_stride.type(at)))
                builder.store(v, _ptr(context, builder, sig.args[2], d_ary, off), align=8)
        return context.get_dummy_value()

    return types.none(src, types.intp, dst, types.intp, types.intp), codegen


vtranspose8: Any = intrinsic(_vtranspose8)


def _vprefetch(typingctx, arr, i, j):
    """A hint to bring the cache line of ``arr[i, j]`` (2-d, any layout; no bounds check)
    closer for reading (``llvm.prefetch``: no effect on any value).

    :func:`dsp.fused_sums.piece_sums` asks for each segment's samples of every tracked
    channel while it makes the segment's carriers, which do not read them: nine rows a
    segment are more streams than the hardware's prefetcher follows from a standing
    start. Issue 24 (the run's 60 s log, the kernel's calls over the samples of a
    replay, CPU best of 9, load 2): the tracked channels' calls 23.4-23.7 -> 19.5-19.7 ms
    a minute, the same bits."""
    if not (isinstance(arr, types.Array) and arr.ndim == 2):
        return None

    def codegen(context, builder, sig, args):
        ary = context.make_array(sig.args[0])(context, builder, args[0])
        ptr = cgutils.get_item_pointer(context, builder, sig.args[0], ary, [args[1], args[2]])
        i32 = ir.IntType(32)
        fn = cgutils.get_or_insert_function(
            builder.module, ir.FunctionType(ir.VoidType(), [ptr.type, i32, i32, i32]),
            "llvm.prefetch.p0",
        )  # fmt: skip
        builder.call(fn, [ptr, i32(0), i32(3), i32(1)])  # read, keep close, data cache
        return context.get_dummy_value()

    return types.none(arr, types.intp, types.intp), codegen


vprefetch: Any = intrinsic(_vprefetch)
