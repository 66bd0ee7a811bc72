"""Compiled per-sample work of the order tracker: carriers and segment sums in one pass.

:func:`dsp.sums.add_sample_sets` needs, for each segment, ``sum x e`` over its samples
and ``sum x e (1 - rise)`` over its taper zone, ``e`` the carriers ``q exp(-i k delta / 2)``
of the orders summed, and the weights, mean squares and clip flags beside them. In numpy
that is a carrier array for every order up to the highest (written once, read by a BLAS
product per segment) and a dozen passes over the samples. :func:`piece_sums` makes each
carrier in registers from the sample's base ``exp(-i delta / 2)`` by the same running
product, keeps only the orders of the set, and adds them, the taper weights, the mean
square and the clip flags to the segment's sums as it goes: one pass, no temporaries.

Measured (issue 24; 2-core machine shared with other work, best of several runs, 10
channels at 25.6 kHz, orders 1, 1.5, 2 and the leakage correction's: 8 half-orders): the
kernel alone runs at about 1200x real time on one core; the sums in numpy take 53 ms per
30 s of data, compiled 42 ms, and the whole tracker goes from about 290x to 320x real
time: the rest of the tracker (frame assembly, leakage correction, angle lookup, the
per-block Python) is now most of its time. numba (well kept, NumPy's release cadence)
over hand-written C: no build step, and ``cache=True`` keeps the machine code beside
this module (or in numba's user cache when the package is read-only), so only the
first use after an install compiles (about 3 s of CPU). But importing numba and loading
the cached code cost about 0.5 s of CPU per process, while the kernel saves about 0.4 ms
per second of 10-channel data: it pays for itself after some 20 minutes of data. So the
tracker uses it only when asked (``PTINERTIA_NUMBA=1``: hour-long runs, campaigns and
studies, whose worker processes pay the import once), and numba is imported on first
use; a short ``ptinertia run`` never loads it. ``nogil=True``: the kernel releases the
GIL, so a tracker on its own thread leaves the others running.

Measured again (issue 24, later session; load average 3 to 19 on the 2 cores, so CPU
figures, best of 5 to 30; ``benchmarks/bench_pipeline.py``): the kernel's calls for a 10 s
sweep of that load (0.5 s blocks) take 11-12 ms, the numpy sums 13-15 ms; the whole
tracker runs 224x -> 281x on that load with the kernel, 146x -> 184x on the live
pipeline's 9 accelerometers + pressure spectrum (load 10), 291x -> 319x in 0.5 s blocks and
350x -> 368x in 1 s blocks (load 15). ``ptinertia run --duration 5`` takes 1.01 s of CPU
with the numpy sums, 1.51 s with the kernel from a filled numba cache and 3.6 s with an
empty one (load 10; 0.92 s and 1.37 s at load 3). The kernel saves 0.05-0.08 s per minute
of 10 channels at 25.6 kHz against 0.5 s for numba's import: it pays after some 6-10
minutes of such data (the figures move by 10 % between runs on this shared machine). So numba stays optional and off by default. Tried and
left out: the sums as vectorised dot products over the samples (numba ``fastmath``
reassociation; 10-20 % off the kernel, but a row's weight sum then differed at 1e-16
between one call and one call per piece, and a sum that depends on the block cut breaks
replay = live), four fixed partial sums per dot product (2.5x slower), a BLAS product
per segment from inside the kernel, the carrier-times-taper product taken once per
sample instead of per channel (no gain each). The samples come channel-fastest (the
synthetic bench) or sample-fastest (the simulator): neither layout changes the figures.
What the tracker spends beyond the sums is Python per block and per frame (frame
assembly, leakage correction, angle lookup), which a kernel for the sums cannot remove.

Third pass (issue 24): beyond the sums, the compiled path runs through numba the angle
lookup of the samples (:func:`cubic_values`) and the times of the frames' window ends
(:func:`cubic_times`), both the numpy path's operations in its order (numba contracts
no multiply-add without ``fastmath``: the same bits, tested), and the leakage
correction's ramps (:mod:`dsp.ramp_slopes`, within 1e-12). Tried and left out, none
faster: the kernel's sums channel by channel with blocks of 4 to 16 rows x 1 to 4
channels as accumulators in registers, its carriers order by order across the samples,
fused multiply-add (``fastmath={"contract"}``); the lookup as one merge of samples and
knots (a branch per sample: 37 us a block against 28 us for the knots' ``searchsorted``
and a vectorised loop per piece). Measured side by side with main (issue-24 load: 10
channels at 25.6 kHz, orders 1, 1.5, 2, 30 s sweep in 0.5 s blocks; CPU, best of 3 runs
of best of 3, load average 11 on the 2 cores): the whole tracker 306x -> 380x real time
compiled (274x -> 296x numpy; with the held-back samples of :mod:`dsp.segments` and the
frame objects of :mod:`dsp.assemble`, which serve both paths); ramp_correction 8.7 ->
2.9 ms and the lookup 7.1 -> 4.4 ms per 30 s. The kernel is now some 40 % of the
compiled path's time, the frames' assembly (window sums, correction, frame objects) a
quarter, the tacho's decoding and angle table a tenth.

What stays identical and what does not: the base ``exp(-i delta / 2)`` is still made by
numpy in single precision (its SIMD ``cos``/``sin`` round differently from libm's), the
taper weights repeat :func:`dsp.frames.rise_table`'s arithmetic, so the carriers are
those of the numpy path to the last bit of the complex product; the sums are taken
sample by sample in time order, where BLAS and ``reduceat`` group them their own way.
The rows agree with the numpy reference (:func:`dsp.sums.add_sample_sets` with
``compiled=False``) within 1e-12 relative to the segment's largest sum (measured: under
1e-15; ``tests/dsp/test_kernels.py``).
"""

from __future__ import annotations

import importlib.util
import math
import os
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from dsp.frames import RISE_GRID, RISE_SLOPE, RISE_TABLE
from dsp.ramp_slopes import ramp_slopes as slopes_loops
from dsp.sum_rows import row_size
from dsp.sum_sets import POWER_STRIDE, Segments, SumSet, base_parts

# numba is optional and imported on first use only: its import and the cached machine
# code cost about 0.5 s of CPU per process, more than the kernel saves on a short run
AVAILABLE = importlib.util.find_spec("numba") is not None
# PTINERTIA_NUMBA=1: the tracker uses the kernel (long runs, campaigns and studies); the
# benchmarks and tests switch it per call
USE = AVAILABLE and os.environ.get("PTINERTIA_NUMBA", "0") == "1"
_compiled: dict[Callable[..., None], Callable[..., None]] = {}


def piece_sums(*args: Any) -> None:
    """:func:`dsp.fused_sums.piece_sums`: the segment sums of one piece in one vectorised pass."""
    # imported here, not at the top: the module imports numba (0.3 s), which the default
    # path never loads
    from dsp import fused_sums

    fused_sums.piece_sums(*args)


def segment_cuts(
    phi: np.ndarray, cuts: np.ndarray, spacing: float, half: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[int], np.ndarray]:
    """:func:`dsp.fused_sums.segment_cuts`: the segments of each piece and the samples'
    angles from their segment's frame angle, as :func:`dsp.sums.add_sample_sets` cuts them."""
    from dsp import fused_sums  # imports numba: see piece_sums

    mu, starts, ends, zone_end, per_piece, delta = fused_sums.segment_cuts(phi, cuts, spacing, half)
    return mu, starts, ends, zone_end, per_piece.tolist(), delta


def cubic_values(*args: Any) -> None:
    """:func:`_cubic_values` compiled (on the first call, as :func:`piece_sums`)."""
    _jit(_cubic_values)(*args)


def ramp_slopes(*args: Any) -> None:
    """:func:`dsp.ramp_slopes.ramp_slopes` compiled (on the first call, as :func:`piece_sums`)."""
    _jit(slopes_loops)(*args)


def cubic_times(*args: Any) -> None:
    """:func:`_cubic_times` compiled (on the first call, as :func:`piece_sums`)."""
    _jit(_cubic_times)(*args)


def _jit(fn: Callable[..., None]) -> Callable[..., None]:
    """``fn`` compiled by numba, once per process."""
    compiled = _compiled.get(fn)
    if compiled is None:
        from numba import njit  # heavy (0.3 s): only where a kernel is used

        compiled = _compiled[fn] = njit(cache=True, nogil=True)(fn)
    return compiled


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
    sets: Sequence[SumSet],
    seg: Segments,
    phi: np.ndarray,
    q: np.ndarray,
    delta: np.ndarray,
    first_index: int,
    frames_per_rev: int,
) -> list[np.ndarray]:
    """Every set's rows (seg, :func:`dsp.sum_rows.row_size`), packed by :func:`piece_sums`."""
    base_re, base_im = base_parts(delta)
    c_lo = seg.c - seg.half
    period = 2 * frames_per_rev
    # the rotations exp(-i h c_m) as dsp.sums computes them, one per integer turn
    turn = np.exp(-2j * np.pi * np.arange(period) / period)
    turn_re, turn_im = turn.real.copy(), turn.imag.copy()
    out = []
    for st in sets:
        w = np.zeros((seg.mu.size, row_size(st.x[0].shape[0], st.k2.size)))
        level = math.nan if st.clip_level is None else st.clip_level
        i = 0
        pieces = zip(st.x, seg.cuts[:-1], seg.cuts[1:], seg.per_piece, strict=True)
        for xp, p0, p1, count in pieces:
            s = slice(i, i + count)
            piece_sums(
                xp, phi[p0:p1], q[p0:p1], base_re[p0:p1], base_im[p0:p1], c_lo[s],
                seg.starts[s] - p0, seg.ends[s] - p0, seg.zone_end[s] - p0, 2.0 * seg.half,
                st.k2, st.tracked, (-(first_index + p0)) % POWER_STRIDE, POWER_STRIDE, level,
                RISE_GRID, RISE_TABLE, RISE_SLOPE, seg.mu[s], turn_re, turn_im, w[s],
            )  # fmt: skip
            i += count
        out.append(w)
    return out


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
