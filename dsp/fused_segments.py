"""Where the compiled path's segments begin and end, and the taper over their zones.

Compiled kernels of the compiled path (numba). Both repeat the numpy path's operations in
its order, so they give its numbers bit for bit: :func:`segment_cuts` those of
:func:`dsp.sums._segments` and the angles from the frame angle, :func:`falling_taper`
those of :func:`dsp.frames.rise_table`. Every kernel here calls only this file's, so
numba's cache of this file is its own (no helper hash).

:func:`cut_pass` makes the whole compiled cut of a step's samples in one call (issue 24,
seventh pass): ``q``, the segments, the frame angles and the zones' taper, which took two
calls and five numpy operations (each a pass over the samples or the segments, a
temporary, some microseconds of call overhead) a step; the same bits. Measured on the
calls of the run's 60 s log (both ways in one process, CPU best of 15, load 6.6): 6.34 ->
6.0 ms a minute; callgrind, the busy steps of :func:`dsp.segments.process_groups` with
this pass's other changes: 916.6 -> 878.0 M instructions.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def cut_pass(phi, omega, inv_rate, cuts, spacing, half, rise_packed):
    """What :func:`dsp.sums.cut_samples` makes in numpy, in one call: ``q = omega * inv_rate``
    (rad; ``inv_rate = 1 / rate_hz`` (s), numpy's one multiplication), :func:`segment_cuts`,
    the frame angles ``c = mu * spacing`` (rad) and :func:`zone_falls` with the zones'
    starts ``c - half`` (the operations numpy did between them, in its order: the same
    bits). Returns ``mu, starts, ends, zone_end, per_piece, delta, half32`` as
    :func:`segment_cuts`, then ``c`` (seg,), ``q`` (n,), ``fall`` (n,), ``wd`` (seg,).
    Issue 24: one call, not two and five numpy operations between them
    (:func:`dsp.kernels.segment_cuts`)."""
    q = np.empty(phi.size)
    for i in range(phi.size):
        q[i] = omega[i] * inv_rate
    mu, starts, ends, zone_end, per_piece, delta, half32 = segment_cuts(phi, cuts, spacing, half)
    c = np.empty(mu.size)
    c_lo = np.empty(mu.size)
    for i in range(mu.size):
        c[i] = mu[i] * spacing
        c_lo[i] = c[i] - half
    fall = np.empty(phi.size)
    wd = np.empty(mu.size)
    zone_falls(phi, q, starts, zone_end, c_lo, 2.0 * half, rise_packed, fall, wd)
    return mu, starts, ends, zone_end, per_piece, delta, half32, c, q, fall, wd


@njit(cache=True, nogil=True)
def segment_cuts(phi, cuts, spacing, half):
    """:func:`dsp.sums._segments` of every piece ``cuts[p] .. cuts[p+1]-1`` of ``phi``
    (rad), concatenated, and ``delta = phi - c_m`` (rad) of each sample from its segment's
    frame angle: the same operations (``searchsorted``, ``floor``), so the same numbers.
    Returns ``mu``, ``starts``, ``ends``, ``zone_end`` (seg,), the segments per piece,
    ``delta`` (n,) and ``half = float32(delta / 2)`` (n,), the carriers' angle
    (:func:`dsp.sum_sets.base_parts`: the same multiplication and rounding)."""
    n_pieces = cuts.size - 1
    per_piece = np.empty(n_pieces, dtype=np.int64)
    for p in range(n_pieces):
        m0 = math.floor((phi[cuts[p]] + half) / spacing)
        per_piece[p] = math.floor((phi[cuts[p + 1] - 1] + half) / spacing) - m0 + 1
    total = per_piece.sum()
    mu = np.empty(total, dtype=np.int64)
    starts = np.empty(total, dtype=np.int64)
    ends = np.empty(total, dtype=np.int64)
    zone_end = np.empty(total, dtype=np.int64)
    delta = np.empty(phi.size)
    half32 = np.empty(phi.size, np.float32)
    i = 0
    for p in range(n_pieces):
        p0, p1 = cuts[p], cuts[p + 1]
        piece = phi[p0:p1]
        m0 = math.floor((piece[0] + half) / spacing)
        for k in range(per_piece[p]):
            c = (m0 + k) * spacing
            mu[i + k] = m0 + k
            starts[i + k] = p0 + (0 if k == 0 else np.searchsorted(piece, c - half))
            zone_end[i + k] = p0 + np.searchsorted(piece, c + half)
        for k in range(per_piece[p]):
            ends[i + k] = starts[i + k + 1] if k + 1 < per_piece[p] else p1
            zone_end[i + k] = min(max(zone_end[i + k], starts[i + k]), ends[i + k])
            a, b = starts[i + k], ends[i + k]
            _angles(phi[a:b], mu[i + k] * spacing, delta[a:b], half32[a:b])
        i += per_piece[p]
    return mu, starts, ends, zone_end, per_piece, delta, half32


@njit(cache=True, nogil=True, inline="always")
def _angles(phi, c, delta, half32):
    """``delta = phi - c`` and ``half32 = float32(delta / 2)`` of one segment's samples.

    On slices, indexed from 0: numba then knows no index is negative, LLVM vectorises the
    loop (issue 24: :func:`segment_cuts` on a 0.5 s block of 25.6 kHz, 15.3 -> 4.6 us of
    CPU); indexed from the segment's start it checked each index for wrap-around and ran
    scalar. The same operations, so the same bits."""
    for s in range(phi.size):
        d = phi[s] - c
        delta[s] = d
        half32[s] = np.float32(0.5 * d)


@njit(cache=True, nogil=True)
def falling_taper(phi, q, s0, nz, c_lo, taper_rad, rise_packed, fall):
    """``1 - rise`` over the zone's samples into ``fall``; returns ``sum q (1 - rise)``
    (:func:`dsp.frames.rise_table`'s arithmetic, the same bits; ``rise_packed`` its grid,
    slope and value side by side, :data:`dsp.frames.RISE_PACKED`)."""
    n_grid = rise_packed.size // 3 - 1
    total = 0.0
    for s in range(nz):
        u = (phi[s0 + s] - c_lo) / taper_rad
        if u >= 1.0:
            rise = rise_packed[3 * n_grid + 2]
        elif u < 0.0:
            rise = rise_packed[2]
        else:
            g = 3 * min(math.floor(u * n_grid), n_grid - 1)
            rise = rise_packed[g + 1] * (u - rise_packed[g]) + rise_packed[g + 2]
        fall[s] = 1.0 - rise
        total += q[s0 + s] * fall[s]
    return total


@njit(cache=True, nogil=True)
def zone_falls(phi, q, starts, zone_end, c_lo, taper_rad, rise_packed, fall, wd):
    """:func:`falling_taper` of every segment: each zone's ``1 - rise`` into ``fall`` (n,)
    at its samples' places (the flat stretches' entries left as they are) and each
    segment's ``sum q (1 - rise)`` into ``wd`` (seg,), once for every set of sums on the
    cut. Issue 24 (the run's 60 s log, CPU per function, load 3): the spectrum channel's
    calls made them a second time; the sums' calls 25.5 -> 23.3-24.0 ms a minute, the cut
    4.2-4.4 -> 5.3 ms, the same bits."""
    for i in range(starts.size):
        s0 = starts[i]
        nz = zone_end[i] - s0
        wd[i] = falling_taper(phi, q, s0, nz, c_lo[i], taper_rad, rise_packed, fall[s0:])
