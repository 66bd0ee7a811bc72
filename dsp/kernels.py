"""Compiled per-sample work of the order tracker, and the switch that turns it on.

The numpy code is the default and the reference; :data:`USE` (``PTINERTIA_NUMBA=1``)
sends the tracker through numba instead, for: the segment sums (:func:`compiled_rows`:
:mod:`dsp.fused_sums`, one vectorised pass per piece that makes the carriers of the
orders of each set, sums them, and packs each segment's row), the cutting of the pieces
into segments (:func:`segment_cuts`), the angle lookup of the samples
(:func:`cubic_values`; of a block's consecutive samples with their times, :func:`grid_values`),
the times of the frames' window ends (:func:`cubic_times`; of a batch's windows,
:func:`window_times`), the frames' window sums and
amplitudes (:func:`window_sums`, :func:`group_amplitudes`), their speed and leakage figures,
angles, flags and turned orders (:func:`frame_outputs`), the leakage correction's ramps
and coupling (:func:`ramp_slopes`, :func:`apply_ramps`; both at once,
:func:`correct_ramps`), the angle table's new knots and coefficients (:func:`append_knots`),
the pressure votes' candidate sums (:func:`pressure_sums`) and the wheel decoder's interval
pass (:func:`wheel_intervals`), each releasing the GIL (``nogil=True``).

Why numba, and why off by default. numba (well kept, NumPy's release cadence) over
hand-written C: no build step, and ``cache=True`` keeps the machine code beside the
modules (or in numba's user cache when the package is read-only), so only the first use
after an install compiles. Importing numba and loading the cached code cost about 0.5 s
of CPU per process, which a short ``ptinertia run`` does not earn back; hour-long runs,
campaigns and studies (whose worker processes pay the import once) do. So the kernels
are used only when asked, numba is imported on first use (:mod:`dsp.fused_sums` and
:mod:`dsp.vec8` import it; nothing on the default path imports them), and the default
install works without it.

Measured (issue 24, four passes; 2 cores shared with other work, CPU time, best of 3 or
more; 10 channels at 25.6 kHz, orders 1, 1.5, 2 and the leakage correction's, 8 half
orders, 0.5 s blocks): first pass, a scalar kernel for the sums, 290x -> 320x real time;
second, 224x -> 281x at load 10; third, the lookup, window times and ramps compiled and
the held-back samples of :mod:`dsp.segments`, 306x -> 380x (numpy 274x -> 296x, load 11).
Fourth pass (:mod:`dsp.fused_sums`): the sums in eight-lane vectors, packed rows, the
segments compiled: the kernel's calls 36-38 ms -> 12-13 ms per 30 s, the whole tracker
380-400x -> 550-590x, the run's dsp stage (9 accelerometers + the pressure's spectrum)
270x -> 390-400x (numpy unchanged: 320-330x and 215-235x; load 2-4). The compiled
path's time is now about a fifth sums, a third frame assembly (window sums, correction,
frame objects, :mod:`dsp.assemble`), the rest the per-block Python of segments, lookup
and tacho decoding. ``ptinertia run --duration 5``: 0.9 s of CPU with numpy, 1.35-1.4 s
compiled from a filled numba cache (as before), 7.8 s from an empty one (the first run
after an install; 6.1 s before this pass: the vectorised kernel compiles in about 3 s).

Fifth pass (frame assembly): the window sums of a step's frames in one call (the
2 fpr + 1 rows of each window added element by element in numpy's order), and for a group
without holes, and the spectrum channel, its amplitudes ``2 s / w`` and flags in a second
(numpy's complex-by-real quotient step by step); the frames' rpm, rpm change and leakage figure in one call after
numpy's magnitudes (:mod:`dsp.frame_figures`). All three give the numpy path's bits.
Per step (120 a minute of the run's log): window amplitudes 82 us with numpy, 56 with the
compiled sums, 36 with both; spectrum (before its correction) 50 -> 36 us;
:func:`dsp.assemble._finish` 74 -> 54 us. Profile of the
run's dsp stage compiled before it (cProfile and per-function CPU, load 3-8; 60 s, 2997
frames in 120 steps): frame assembly (:func:`dsp.assemble.emit`) about half of the time,
some 0.55 ms a step in a hundred-odd small numpy operations (window amplitudes 0.14 ms,
frame objects 0.12, spectrum 0.1, correction 0.05: its matrix products BLAS does faster
than a compiled loop, measured, so they stay numpy's), the sums kernel a fifth. After
it (CPU, best of 5, before and after interleaved, load 3): the run's dsp stage compiled
0.138-0.141 s -> 0.126 s a minute (425-433x -> 476x; bench_pipeline's figure 470x at load
6.4 -> 486x at load 3.8), the issue's order-tracking load compiled 613-621x -> 631-693x,
numpy unchanged (231-236x, 352-364x); ``PTINERTIA_NUMBA=1 ptinertia run --duration 5``
1.07-1.22 s of CPU before, 1.10-1.11 after.

Sixth pass (the per-block work around the kernels): the cut of a step's samples made
once for both groups on one clock (:func:`dsp.sums.cut_samples`), a block's times and
lookup in one pass (:func:`grid_values`), the table's coefficients, the candidate sums and
the decoder's intervals compiled, the carriers' half angles made in the segment pass and
their cosine and sine handed over in single precision, nine channels summed as blocks of
four and five (not four, four and four again), fewer record copies
(:func:`dsp.immutable.evolve`); all the numpy path's bits, the frames unchanged. The
run's dsp stage (60 s log, 2997 frames; CPU best of 9, main and this pass interleaved,
load 4-6) compiled 0.129-0.134 s -> 0.100-0.109 s a minute (callgrind, one pass:
1.811 -> 1.550 G instructions; numpy 2.860 -> 2.464 G); the issue's load
(``benchmarks/bench_order_tracking.py``, best of 7, load 11.5) compiled 544-556x ->
685-699x. The kernels are now some half of the compiled time (the sums 30 ms a minute).
``PTINERTIA_NUMBA=1 ptinertia run --duration 5`` 1.46 -> 1.50 s of CPU (three more
cached kernels to load); the default path 0.96 -> 0.95 s.

What stays identical and what does not: the base ``exp(-i delta / 2)`` is made by numpy
in single precision in both paths (its SIMD ``cos``/``sin`` round differently from
libm's); segments, angles, taper weights, carriers, lookups and window times are the
numpy path's bits (the same operations in the same order; numba contracts no
multiply-add without ``fastmath``; tested). The sums round differently: BLAS groups
them its own way, the kernel adds each term with one fused multiply-add in time order
(the spectrum channel: eight partial sums per row, see :mod:`dsp.fused_sums`). The rows
agree with the numpy reference (:func:`dsp.sums.add_sample_sets` with ``compiled=False``)
within 1e-12 of each part's largest value (sums, taper sums, mean squares, weights;
measured on about 5000 random pieces: under 6e-14; ``tests/dsp/test_kernels.py``), and never depend on how the samples were cut into
blocks beyond the pieces themselves (replay = live).
"""

from __future__ import annotations

import functools
import importlib.util
import math
import os
from collections.abc import Callable, Sequence
from typing import Any, TypeVar, cast

import numpy as np

from dsp.angle_loops import append_knots as knots_loops
from dsp.angle_loops import grid_values as grid_loops
from dsp.frame_figures import frame_outputs as outputs_loops
from dsp.frames import RISE_PACKED
from dsp.ramp_slopes import ramp_slopes as slopes_loops
from dsp.sum_rows import (
    add_windows,
    plain_block,
    row_size,
    window_rows,
)
from dsp.sum_sets import POWER_STRIDE, Cut, SumSet
from dsp.wheel_intervals import interval_loops
from dsp.window_times import window_times as times_loops

# numba is optional and imported on first use only: its import and the cached machine
# code cost about 0.5 s of CPU per process, more than the kernel saves on a short run
AVAILABLE = importlib.util.find_spec("numba") is not None
# PTINERTIA_NUMBA=1: the tracker uses the kernel (long runs, campaigns and studies); the
# benchmarks and tests switch it per call
USE = AVAILABLE and os.environ.get("PTINERTIA_NUMBA", "0") == "1"
_compiled: dict[Callable[..., Any], Callable[..., Any]] = {}
_Fn = TypeVar("_Fn", bound=Callable[..., Any])


def piece_sums(*args: Any) -> None:
    """:func:`dsp.fused_sums.piece_sums`: the segment sums of one piece in one vectorised pass."""
    from dsp import fused_sums  # not at the top: it imports numba (0.3 s), never by default

    fused_sums.piece_sums(*args)


def apply_ramps(*args: Any) -> None:
    """:func:`dsp.fused_ramps.apply_ramps`: the leakage correction's coupling applied."""
    from dsp import fused_ramps  # imports numba: see piece_sums

    fused_ramps.apply_ramps(*args)


def segment_cuts(
    phi: np.ndarray, omega: np.ndarray, rate_hz: float, cuts: np.ndarray, spacing: float, half: float
) -> tuple[Any, ...]:  # fmt: skip
    """:func:`dsp.fused_segments.cut_pass` (``q``, the segments, angles, frame angles and the
    zones' taper of a cut in one compiled call): ``mu, starts, ends, zone_end, per_piece``
    (a list), ``delta, half32, c, q, (fall, wd)``, as there."""
    from dsp import fused_segments  # imports numba: see piece_sums

    mu, starts, ends, zone_end, per_piece, *rest, fall, wd = fused_segments.cut_pass(
        phi, omega, 1.0 / rate_hz, cuts, spacing, half, RISE_PACKED
    )
    return (mu, starts, ends, zone_end, per_piece.tolist(), *rest, (fall, wd))


def append_knots(*args: Any) -> tuple[np.ndarray, ...]:
    """:func:`dsp.angle_loops.append_knots` compiled (on the first call, as :func:`piece_sums`),
    with numpy's division (inf or NaN for a zero divisor, as the numpy path's, not Python's
    check before each, which keeps LLVM from vectorising: 2.3 -> 1.5 ms a minute)."""
    return cast(tuple[np.ndarray, ...], _jit(knots_loops, numpy_division=True)(*args))


def pressure_sums(
    phi_w: np.ndarray, pressure: np.ndarray, step: float, half_width: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`dsp.cycle.pressure_sums` in two compiled passes over the samples
    (:func:`_pressure_sums`); ``step`` and ``half_width`` (rad) as there."""
    k_lo, total, count = _jit(_pressure_sums)(phi_w, pressure, step, half_width)
    has = np.flatnonzero(count)
    return has + k_lo, total[has], count[has]


def _pressure_sums(
    phi_w: np.ndarray, pressure: np.ndarray, step: float, half_width: float
) -> tuple[int, np.ndarray, np.ndarray]:
    """The lowest candidate ``k_lo`` and, from it on, the sum and count of the finite
    pressure samples within ``half_width`` of their candidate ``rint(phi_w / step)``: the
    numpy path's tests, each sample added in sample order (as ``np.bincount`` adds its
    weights), so the same bits."""
    found = False
    k_lo = k_hi = 0
    for i in range(phi_w.size):
        k = np.rint(phi_w[i] / step)
        if abs(phi_w[i] - step * k) < half_width and np.isfinite(pressure[i]):
            kk = int(k)
            k_lo = kk if not found or kk < k_lo else k_lo
            k_hi = kk if not found or kk > k_hi else k_hi
            found = True
    total = np.zeros(k_hi - k_lo + 1 if found else 0)
    count = np.zeros(total.size, np.int64)
    for i in range(phi_w.size):
        k = np.rint(phi_w[i] / step)
        if abs(phi_w[i] - step * k) < half_width and np.isfinite(pressure[i]):
            total[int(k) - k_lo] += pressure[i]
            count[int(k) - k_lo] += 1
    return k_lo, total, count


def cubic_values(*args: Any) -> None:
    """:func:`_cubic_values` compiled (on the first call, as :func:`piece_sums`)."""
    _jit(_cubic_values)(*args)


def grid_values(*args: Any) -> None:
    """:func:`dsp.angle_loops.grid_values` compiled (on the first call, as :func:`piece_sums`)."""
    _jit(grid_loops)(*args)


def wheel_intervals(
    buf: np.ndarray, d: np.ndarray, c0: int, teeth: int, gap: int, r_prev: float, tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """:func:`dsp.wheel_intervals.wheel_intervals` in one compiled pass (the same bits)."""
    c, n_rel = np.empty(buf.size, np.int64), np.empty(buf.size, np.int64)
    r, prev, ratio = np.empty(d.size), np.empty(d.size), np.empty(d.size)
    loops = _jit(interval_loops, numpy_division=True)  # a zero interval: inf, as numpy
    b = loops(buf, d, c0, teeth, gap, r_prev, tol, c, n_rel, r, prev, ratio)
    return c, n_rel, r, prev, ratio, b


def ramp_slopes(*args: Any) -> None:
    """:func:`dsp.ramp_slopes.ramp_slopes` compiled (on the first call, as :func:`piece_sums`)."""
    _jit(slopes_loops)(*args)


def window_sums(
    rows: dict[int, np.ndarray], j0: int, j1: int, n: int, n_ch: int, no: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`dsp.sum_rows.window_sums` with its sums in one compiled pass
    (:func:`dsp.sum_rows.add_windows`): the same bits, a fifth of the numpy operations."""
    total, mean_square, h = _window_totals(rows, j0, j1, n, n_ch, no)
    s, w, _, _ = plain_block(total[:, :h], n_ch, no)
    return s, w, mean_square, total[:, h:] > 0


def _window_totals(
    rows: dict[int, np.ndarray], j0: int, j1: int, n: int, n_ch: int, no: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """Frames ``j0 .. j1``'s window sums as :func:`dsp.sum_rows.add_windows` writes them
    (plain block and clip counts (f, h + n_ch), mean squares (f, n_ch)) and ``h``, the
    length of a plain block."""
    rows_w = window_rows(rows, j0, j1, n, n_ch, no)
    h = (rows_w.shape[1] - n_ch) // 2
    total = np.empty((j1 - j0 + 1, h + n_ch))
    mean_square = np.empty((j1 - j0 + 1, n_ch))
    _jit(add_windows)(rows_w, n, h, n_ch, total, mean_square)
    return total, mean_square, h


def group_amplitudes(
    rows: dict[int, np.ndarray], js: np.ndarray, n: int, no: int, usable: np.ndarray,
    cols: np.ndarray, x: np.ndarray, ms: np.ndarray, ok: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int]:  # fmt: skip
    """A group's window sums, amplitudes and flags of frames ``js`` in one compiled call
    (:func:`dsp.fused_frames.group_windows`, the numpy path's bits; arguments as there;
    the group must have no holes): the frames with a non-finite amplitude and with clipped
    samples (f,) bool, and a code: 1 if any frame has the first, plus 2 the second."""
    from dsp import fused_frames  # imports numba: see piece_sums

    rows_w = window_rows(rows, int(js[0]), int(js[-1]), n, cols.size, no)
    h = (rows_w.shape[1] - cols.size) // 2
    flags = np.empty(js.size, bool), np.empty(js.size, bool)  # NaN, clipped
    code = fused_frames.group_windows(rows_w, n, h, no, usable, cols, x, ms, ok, *flags)
    return flags[0], flags[1], code


def correct_ramps(*args: Any) -> None:
    """:func:`dsp.fused_frames.correct_ramps`: the leakage correction's ramps and their
    coupling in one compiled call."""
    from dsp import fused_frames  # imports numba: see piece_sums

    fused_frames.correct_ramps(*args)


def window_times(*args: Any) -> bool:
    """:func:`dsp.window_times.window_times` compiled (as :func:`append_knots`)."""
    return cast(bool, _jit(times_loops, numpy_division=True)(*args))


def frame_outputs(*args: Any) -> None:
    """:func:`dsp.frame_figures.frame_outputs` compiled (as :func:`cubic_values`)."""
    _jit(outputs_loops)(*args)


def cubic_times(*args: Any) -> None:
    """:func:`_cubic_times` compiled (on the first call, as :func:`piece_sums`)."""
    _jit(_cubic_times)(*args)


def _jit(fn: _Fn, numpy_division: bool = False) -> _Fn:
    """``fn`` compiled by numba, once per process (``numpy_division``: numba's numpy
    error model, a float division by zero gives inf or NaN instead of raising). numba's
    disk cache does not key on the error model: a function is always compiled with the
    same one, and a change of it goes with an edit of the function's file."""
    compiled = _compiled.get(fn)
    if compiled is None:
        from numba import njit  # heavy (0.3 s): only where a kernel is used

        jit = njit(cache=True, nogil=True, error_model="numpy") if numpy_division else None
        compiled = _compiled[fn] = (jit or njit(cache=True, nogil=True))(fn)
    return cast(_Fn, compiled)


def _cubic_values(
    t: np.ndarray,
    counts: np.ndarray,
    t_lo: np.ndarray,
    phi_lo: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    c3: np.ndarray,
    phi: np.ndarray,
    omega: np.ndarray,
) -> None:
    """:func:`dsp.angle.lookup`'s angle and speed, piece by piece in one pass.

    ``t`` (n,) s, ``counts`` (p,) how many of them (in turn) each piece holds, the
    pieces' start time, angle and coefficients (p,); writes ``phi`` (rad) and ``omega``
    (rad/s) (n,). The same operations in the same order as the numpy arrays there
    (no fused multiply-add: numba does not contract without fastmath), so the same bits.
    """
    i = 0
    for p in range(counts.size):
        tl, pl, a1, a2, a3 = t_lo[p], phi_lo[p], c1[p], c2[p], c3[p]
        a3x3 = 3.0 * a3
        a2x2 = 2.0 * a2
        for _ in range(counts[p]):
            tau = t[i] - tl
            phi[i] = ((tau * a3 + a2) * tau + a1) * tau + pl
            omega[i] = (tau * a3x3 + a2x2) * tau + a1
            i += 1


def compiled_rows(
    sets: Sequence[SumSet], cut: Cut, first_index: int, frames_per_rev: int
) -> list[np.ndarray]:
    """Every set's rows (seg, :func:`dsp.sum_rows.row_size`), packed by :func:`piece_sums`."""
    from dsp import fused_sums  # imports numba: see piece_sums (once a call, not a piece)

    sums = fused_sums.piece_sums
    seg = cut.seg
    phi, q, cos_half, sin_half = cut.phi, cut.q, cut.cos_half, cut.sin_half
    assert cut.falls is not None  # (the compiled cut's)
    fall, wd = cut.falls
    turn_re, turn_im = _turns(2 * frames_per_rev)
    out = []
    for st in sets:
        # every row written whole by the kernel (dsp.fused_rows.pack_row): no zeros needed
        w = np.empty((seg.mu.size, row_size(st.x[0].shape[0], st.k2.size)))
        level = math.nan if st.clip_level is None else st.clip_level
        i = 0
        # the whole call's arrays and where the piece is in them (sliced in the kernel)
        for xp, p0, count in zip(st.x, seg.cuts[:-1], seg.per_piece, strict=True):
            sums(
                xp, phi, q, cos_half, sin_half, fall, wd, seg.starts, seg.ends, seg.zone_end,
                st.k2, st.tracked, (-(first_index + p0)) % POWER_STRIDE, POWER_STRIDE, level,
                seg.mu, turn_re, turn_im, w, p0, i, i + count,
            )  # fmt: skip
            i += count
        out.append(w)
    return out


@functools.cache
def _turns(period: int) -> tuple[np.ndarray, np.ndarray]:
    """The rotations ``exp(-i h c_m)`` as :mod:`dsp.sums` computes them, one per integer
    turn of ``period``: real and imaginary parts (period,), never modified."""
    turn = np.exp(-2j * np.pi * np.arange(period) / period)
    return turn.real.copy(), turn.imag.copy()


def _cubic_times(
    phi: np.ndarray,
    t_lo: np.ndarray,
    t_hi: np.ndarray,
    phi_lo: np.ndarray,
    phi_hi: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    c3: np.ndarray,
    t: np.ndarray,
    omega: np.ndarray,
) -> None:
    """:func:`dsp.angle.time_at` angle by angle: its Newton steps on the piece's cubic, the
    same operations in the same order, so the same bits; NaN outside every piece.
    ``phi`` (n,) rad (any order), the table's columns (p,); writes ``t`` (s), ``omega`` (rad/s).
    """
    for i in range(phi.size):
        j = np.searchsorted(phi_lo, phi[i], side="right") - 1
        if j < 0 or not phi[i] <= phi_hi[j]:
            t[i] = np.nan
            omega[i] = np.nan
            continue
        a1, a2, a3 = c1[j], c2[j], c3[j]
        a2x2 = 2.0 * a2
        target = phi[i] - phi_lo[j]
        tau = target / (phi_hi[j] - phi_lo[j]) * (t_hi[j] - t_lo[j])
        for _ in range(4):
            f = tau * (a1 + tau * (a2 + tau * a3)) - target
            fp = a1 + tau * (a2x2 + 3.0 * tau * a3)
            tau -= f / fp
        omega[i] = a1 + tau * (a2x2 + 3.0 * tau * a3)
        t[i] = t_lo[j] + tau
