"""The compiled segment sums in one pass, with eight float64 lanes per instruction.

Imported only where the compiled path runs (:func:`dsp.kernels.compiled_rows`): it
imports numba and llvmlite. :func:`piece_sums` does for one piece what the numpy
reference (:func:`dsp.sum_sets.numpy_sums`, then :func:`dsp.sums._packed`) does:
carriers, taper weights, the sums ``a``, ``d``, ``wa``, ``wd``, the mean square and the
clip flags of each segment, rotated to the frame angle and packed into the segment's
:data:`dsp.sum_rows.Row`.

numba vectorises none of the loops that matter here by itself: the sums are reductions it
may not reorder without ``fastmath`` (and with it the order would follow the arrays'
alignment, so the bits would depend on where the allocator put them), and numba's
negative-index checks keep LLVM's SLP vectoriser from joining the rows' scalar
accumulators (measured: a 16-row inner loop per sample and channel, AVX-512 barely
used). So the kernel says what it means with LLVM's own vector type, ``<8 x double>``
(:mod:`dsp.vec8`: one AVX-512 register, two AVX2 ones on a machine without it). Where
the lanes go:

* carriers: lanes are eight consecutive samples; the running product
  ``p_k = p_(k-1) exp(-i delta / 2)`` is the numpy path's, operation for operation (no
  contraction), so the carriers are its bits; each block of 8 samples x 8 rows is then
  transposed (:func:`dsp.vec8.vtranspose8`) to a sample per row, rows in lanes;
* sums of the tracked channels: lanes are rows (the orders' real and imaginary parts,
  16 per chunk); four channels share each load of the carriers, so eight vector
  accumulators stay in registers, and each accumulator adds its terms in time order,
  one sample after the other, so a piece's sums depend neither on memory layout nor on
  the other pieces of a call (replay = live). Each term is ``fma(x, e, acc)``: one
  rounding per term instead of two; against the numpy path (BLAS, which groups and
  fuses its own way) the rows stay within 1e-15 of a segment's largest sum (tests:
  within 1e-12). Channels beyond a multiple of four are summed by a last block of four
  that starts earlier (the same terms in the same order: the same bits); fewer than four
  channels, 48 columns a pass;
* the spectrum channel (one channel, 17 orders): lanes over samples throughout
  (:mod:`dsp.spectrum_lanes`);
* the clip flags ride on the sums' pass (the largest ``|x|`` of each channel), the mean
  square sums four channels' chains at once; the segments and taper weights come from
  :mod:`dsp.fused_segments`.

Measured (issue 24, 30 s of 10 channels at 25.6 kHz in 0.5 s blocks, orders 1, 1.5, 2
and the correction's: 8 half orders, 119 calls; CPU, best of 7, load 3-9 on 2 cores): the
kernel's calls 36-38 ms before (scalar sums), 23 ms with vector sums one channel at a
time, 19 ms with four channels and fused multiply-add, 14.6 ms with the clip flags on the
sums' pass, 12-13 ms with the rows packed here (which also spares the numpy packing of
every block). Samples read through slices indexed from 0 (issue 24: no wrap-around checks,
the same bits, ~1 ms a minute); the pieces sliced here (2 -> 1 ms). ``nogil`` throughout.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numba import types as nt

from dsp.fused_rows import pack_row, power_sums, put_rows
from dsp.spectrum_lanes import lane_sums
from dsp.vec8 import vadd, vfma, vload, vmul, vprefetch, vsplat, vstore, vsub, vtranspose8, vzero


@njit(cache=True, nogil=True)
def _carriers(pb_re, pb_im, pq, s, k2, blk):
    """Carriers of samples ``s .. s+7``: ``blk[8 r : 8 r + 8]`` row r (Re of order j in row
    j, Im in row no + j), by the running product of :func:`dsp.sum_sets.carriers`."""
    no = k2.size
    br = vload(pb_re, s)
    bi = vload(pb_im, s)
    qv = vload(pq, s)
    j = 0
    if k2[0] == 0:
        vstore(blk, 0, qv)
        vstore(blk, 8 * no, vzero())
        j = 1
    pr = vmul(br, qv)
    pi = vmul(bi, qv)
    for k in range(1, k2[no - 1] + 1):
        if k > 1:
            t = vsub(vmul(pr, br), vmul(pi, bi))
            pi = vadd(vmul(pr, bi), vmul(pi, br))
            pr = t
        if j < no and k == k2[j]:
            vstore(blk, 8 * j, pr)
            vstore(blk, 8 * (no + j), pi)
            j += 1


@njit(cache=True, nogil=True)
def _sums4(x, c, s0, n, e, rp, r0, sums, top, clipping):
    """``sum_s x[c + k, s0 + s] e[s, r0 : r0 + 16]`` for k = 0..3 into ``sums`` (64,),
    each in time order; with ``clipping`` the largest ``|x|`` of each channel into ``top``."""
    xs = x[:, s0 : s0 + n]  # indexed from 0: no wrap-around checks
    a0, a1, a2, a3 = vzero(), vzero(), vzero(), vzero()
    a4, a5, a6, a7 = vzero(), vzero(), vzero(), vzero()
    m0 = m1 = m2 = m3 = -np.inf  # a NaN sample never wins (as |x| >= level is False)
    for s in range(n):
        b = s * rp + r0
        e0 = vload(e, b)
        e1 = vload(e, b + 8)
        y0, y1, y2, y3 = xs[c, s], xs[c + 1, s], xs[c + 2, s], xs[c + 3, s]
        if clipping:
            m0 = abs(y0) if abs(y0) > m0 else m0
            m1 = abs(y1) if abs(y1) > m1 else m1
            m2 = abs(y2) if abs(y2) > m2 else m2
            m3 = abs(y3) if abs(y3) > m3 else m3
        v = vsplat(y0)
        a0, a1 = vfma(v, e0, a0), vfma(v, e1, a1)
        v = vsplat(y1)
        a2, a3 = vfma(v, e0, a2), vfma(v, e1, a3)
        v = vsplat(y2)
        a4, a5 = vfma(v, e0, a4), vfma(v, e1, a5)
        v = vsplat(y3)
        a6, a7 = vfma(v, e0, a6), vfma(v, e1, a7)
    vstore(sums, 0, a0)
    vstore(sums, 8, a1)
    vstore(sums, 16, a2)
    vstore(sums, 24, a3)
    vstore(sums, 32, a4)
    vstore(sums, 40, a5)
    vstore(sums, 48, a6)
    vstore(sums, 56, a7)
    top[0], top[1], top[2], top[3] = m0, m1, m2, m3


@njit(cache=True, nogil=True)
def _sums5(x, c, s0, n, e, rp, r0, sums, top, clipping):
    """:func:`_sums4` for channels ``c .. c + 4`` into ``sums`` (80,) and ``top`` (5,): the
    last block when the channels leave one over a multiple of four (nine: four and five,
    not four, four and four again from the fifth)."""
    xs = x[:, s0 : s0 + n]  # indexed from 0: no wrap-around checks
    a0, a1, a2, a3 = vzero(), vzero(), vzero(), vzero()
    a4, a5, a6, a7 = vzero(), vzero(), vzero(), vzero()
    a8, a9 = vzero(), vzero()
    m0 = m1 = m2 = m3 = m4 = -np.inf
    for s in range(n):
        b = s * rp + r0
        e0 = vload(e, b)
        e1 = vload(e, b + 8)
        y0, y1, y2, y3 = xs[c, s], xs[c + 1, s], xs[c + 2, s], xs[c + 3, s]
        y4 = xs[c + 4, s]
        if clipping:
            m0 = abs(y0) if abs(y0) > m0 else m0
            m1 = abs(y1) if abs(y1) > m1 else m1
            m2 = abs(y2) if abs(y2) > m2 else m2
            m3 = abs(y3) if abs(y3) > m3 else m3
            m4 = abs(y4) if abs(y4) > m4 else m4
        v = vsplat(y0)
        a0, a1 = vfma(v, e0, a0), vfma(v, e1, a1)
        v = vsplat(y1)
        a2, a3 = vfma(v, e0, a2), vfma(v, e1, a3)
        v = vsplat(y2)
        a4, a5 = vfma(v, e0, a4), vfma(v, e1, a5)
        v = vsplat(y3)
        a6, a7 = vfma(v, e0, a6), vfma(v, e1, a7)
        v = vsplat(y4)
        a8, a9 = vfma(v, e0, a8), vfma(v, e1, a9)
    vstore(sums, 0, a0)
    vstore(sums, 8, a1)
    vstore(sums, 16, a2)
    vstore(sums, 24, a3)
    vstore(sums, 32, a4)
    vstore(sums, 40, a5)
    vstore(sums, 48, a6)
    vstore(sums, 56, a7)
    vstore(sums, 64, a8)
    vstore(sums, 72, a9)
    top[0], top[1], top[2], top[3], top[4] = m0, m1, m2, m3, m4


@njit(cache=True, nogil=True)
def _sums1(x, c, s0, n, e, rp, r0, sums, top, clipping):
    """:func:`_sums4` for one channel and 48 columns (six vectors: the sums of one
    channel on their own would wait on each other)."""
    xs = x[:, s0 : s0 + n]  # indexed from 0: no wrap-around checks
    a0, a1, a2, a3, a4, a5 = vzero(), vzero(), vzero(), vzero(), vzero(), vzero()
    m0 = -np.inf
    for s in range(n):
        b = s * rp + r0
        y = xs[c, s]
        if clipping:
            m0 = abs(y) if abs(y) > m0 else m0
        v = vsplat(y)
        a0, a1 = vfma(v, vload(e, b), a0), vfma(v, vload(e, b + 8), a1)
        a2, a3 = vfma(v, vload(e, b + 16), a2), vfma(v, vload(e, b + 24), a3)
        a4, a5 = vfma(v, vload(e, b + 32), a4), vfma(v, vload(e, b + 40), a5)
    vstore(sums, 0, a0)
    vstore(sums, 8, a1)
    vstore(sums, 16, a2)
    vstore(sums, 24, a3)
    vstore(sums, 32, a4)
    vstore(sums, 40, a5)
    top[0] = m0


# numba's cache keys a kernel's machine code on the sha256 of its own file only: the
# helpers this file inlines (vec8's intrinsics, spectrum_lanes, fused_rows) change
# the code without changing this file. Their hash, written here, makes any edit of
# theirs change this file too (tests/dsp/test_kernels.py recomputes it and fails with
# the new value), so a stale cache is never loaded.
HELPERS = ("fused_rows.py", "spectrum_lanes.py", "vec8.py")
HELPERS_SHA256 = "e13b0cf8efbbd409f8e0ff98916dc2d2d33337faaa896e82f20b8a1280fa1a84"

# one signature, compiled (or loaded from numba's cache) when this module is imported, so
# after the helpers above: the samples as any 2-d layout (blocks come channel-fastest,
# sample-fastest or sliced), so that a run compiles one version, not one per layout (some
# 3 s of CPU each on an empty cache), read-only too (a block over a bytes buffer, as
# np.frombuffer makes it: the numpy path takes it, so this one must)
_F1, _I1 = nt.float64[::1], nt.int64[::1]
_SAMPLES = nt.Array(nt.float64, 2, "A", readonly=True)
_H1 = nt.float32[::1]
_SIGNATURE = nt.void(
    _SAMPLES, _F1, _F1, _H1, _H1, _F1, _F1, _I1, _I1, _I1, _I1, nt.boolean,
    nt.int64, nt.int64, nt.float64, _I1, _F1, _F1, nt.float64[:, ::1],
    nt.int64, nt.int64, nt.int64,
)  # fmt: skip


@njit(_SIGNATURE, cache=True, nogil=True)
def piece_sums(
    x, phi, q, cos_half, sin_half, fall_all, wd_seg, starts, ends, zone_end, k2, tracked,
    power_from, power_stride, clip_level, mu, turn_re, turn_im, w, p0, i0, i1,
):  # fmt: skip
    """Add the sums of the segments of one piece (one set of channels) to ``out``.

    ``x`` (n_ch, n) the piece's samples, ``p0 .. p0 + n - 1`` of the call's ``phi`` (rad),
    ``q = omega dt`` (rad), ``cos_half``, ``sin_half`` (float32) the carriers' base ``exp(-i delta / 2)`` as
    :func:`dsp.sum_sets.base_parts` makes it (``cos - i sin``, widened here); per segment
    (the call's; the piece's are ``i0 .. i1 - 1``): ``starts``, ``ends``, ``zone_end``
    (samples) and ``wd_seg`` the zone's ``sum q (1 - rise)``; ``fall_all`` (the call's
    samples) each zone's falling taper ``1 - rise`` (:func:`dsp.fused_segments.zone_falls`,
    made once for every set on the cut), ``k2`` (no,) ascending (0 the mean). ``tracked``: the zone weight multiplies the
    carrier, and the mean square (samples ``power_from + power_stride * i``) and the
    clip flags (``|x| >= clip_level``; NaN for none) are summed; else it multiplies the
    sample (the spectrum channel's layout, as :func:`dsp.sum_sets.numpy_sums` does).
    ``mu`` (seg,) the segments' numbers, ``turn_re``, ``turn_im``
    (period,) ``exp(-2 pi i m / period)``, ``period = 2 frames_per_rev``: the rotation to
    the frame angle, ``exp(-i h c_m)`` for ``h = k2 / 2``, reduced exactly with integers.
    Writes each segment's :data:`dsp.sum_rows.Row` into ``w`` (seg, row_size): the sums
    rotated, their weights, mean square, count and clip flags, as
    :func:`dsp.sums.add_sample_sets` packs the numpy path's.
    """
    phi, q = phi[p0 : p0 + x.shape[1]], q[p0 : p0 + x.shape[1]]  # the piece's, from 0
    cos_half, sin_half = cos_half[p0 : p0 + x.shape[1]], sin_half[p0 : p0 + x.shape[1]]
    no = k2.size
    n_ch = x.shape[0]
    longest = 0
    for i in range(i0, i1):
        longest = max(longest, ends[i] - starts[i])
    longest8 = (longest + 7) // 8 * 8
    # the carriers of a segment, a sample per row of e: Re of order j in column j, Im in
    # column no + j (the layout of the sums), padded with zeros to a multiple of 16
    # columns; three rows more, which the one-channel sums read past the last sample (48
    # columns at a time) and ignore; ez: the same times the zone's falling taper
    n_rows = 2 * no
    n_cols8 = (n_rows + 7) // 8 * 8  # the columns the carriers fill, 8 at a time
    rp = (n_rows + 15) // 16 * 16
    size = (longest8 + 3) * rp if tracked else 0
    if n_cols8 == rp and n_ch >= 4:
        # the carriers fill every column and the blocks of four or five channels read
        # only the rows the carriers (and their zone copies) were written to: no zeros
        # needed (issue 24: two memsets of some 64 KB a call at 3000 rpm spared)
        e = np.empty(size)
        ez = np.empty(size)
    else:  # padding columns, or 1-3 channels: the extra lanes' sums are dropped (put_rows),
        # zeros keep NaN and denormal arithmetic out of them
        e = np.zeros(size)
        ez = np.zeros(size)
    blk = np.zeros(8 * rp)  # one block of 8 samples, a row per column of e
    pb_re = np.zeros(longest8)
    pb_im = np.zeros(longest8)
    pq = np.zeros(longest8)
    sums = np.empty(80)
    top = np.empty(5)
    acc_a = np.empty((n_ch, n_rows))
    acc_d = np.empty((n_ch, n_rows))
    clip = np.zeros(n_ch)
    s2 = np.zeros(n_ch)
    period = turn_re.size
    px = np.zeros(2 * longest8)  # a channel's samples, then their zone's, padded with zeros
    lanes = np.zeros(16 * n_rows)
    # four channels at a time while there are four: a last block of fewer starts earlier
    # and sums some channels again, the same terms in the same order (the same bits);
    # one channel over a multiple of four ends with a block of five instead (nine
    # channels: 18 vector multiply-adds a sample, not 24)
    five = tracked and n_ch >= 5 and n_ch % 4 == 1
    quads = (n_ch // 4 - 1 if five else (n_ch + 3) // 4) if tracked and n_ch >= 4 else 0
    for i in range(i0, i1):
        s0 = starts[i] - p0
        n = ends[i] - starts[i]
        nz = zone_end[i] - starts[i]
        total = 0.0
        ch_s, sh_s, q_s = cos_half[s0 : s0 + n], sin_half[s0 : s0 + n], q[s0 : s0 + n]
        for s in range(n):
            pb_re[s] = np.float64(ch_s[s])  # exp(-i delta / 2), widened exactly
            pb_im[s] = -np.float64(sh_s[s])
            pq[s] = q_s[s]
        if not tracked:  # (the tracked channels' wa: below)
            for s in range(n):
                total += q_s[s]
        for s in range(n, (n + 7) // 8 * 8):
            pb_re[s] = pb_im[s] = pq[s] = 0.0
        wa = total
        wd = wd_seg[i]  # and the zone's falling taper (dsp.fused_segments.zone_falls)
        fall = fall_all[starts[i] : zone_end[i]]
        if not tracked:
            # the spectrum channel: one channel, many orders; lanes are samples throughout.
            # The next segment's samples on their way while this one's are summed (issue
            # 24: the spectrum channel's calls 9.4 -> 8.6 ms a minute of the run's log)
            if i + 1 < i1:
                for s in range(starts[i + 1] - p0, ends[i + 1] - p0, 8):
                    for ch in range(n_ch):
                        vprefetch(x, ch, s)
            for ch in range(n_ch):
                lane_sums(x, ch, s0, n, nz, pb_re, pb_im, pq, fall, k2, px, lanes, acc_a, acc_d)
            pack_row(w[i], mu[i], k2, turn_re, turn_im, period, acc_a, acc_d, wa, wd, s2, 0, clip)
            continue
        for s in range(0, n, 8):
            for ch in range(n_ch):  # the sums' samples on their way while the carriers are made
                vprefetch(x, ch, s0 + s)
            _carriers(pb_re, pb_im, pq, s, k2, blk)
            for g in range(0, n_cols8, 8):
                vtranspose8(blk, 8 * g, e, s * rp + g, rp)
            # wa = sum q in sample order, a chain of additions that waits on itself: here
            # it hides behind the carriers' work (issue 24: 19.8 -> 19.3 ms a minute)
            for t in range(s, min(s + 8, n)):
                total += pq[t]
        wa = total
        for s in range(nz):  # (tracked: the spectrum channel's went on above)
            f = vsplat(fall[s])
            for g in range(0, n_cols8, 8):
                vstore(ez, s * rp + g, vmul(vload(e, s * rp + g), f))
        for quad in range(quads):
            ch = min(4 * quad, n_ch - 4)
            for r0 in range(0, rp, 16):
                # the clip flags ride on the first chunk's pass
                _sums4(x, ch, s0, n, e, rp, r0, sums, top, r0 == 0)
                put_rows(acc_a, ch, 4, r0, 16, sums)
                if r0 == 0:
                    for c in range(4):
                        clip[ch + c] = 1.0 if top[c] >= clip_level else 0.0
                _sums4(x, ch, s0, nz, ez, rp, r0, sums, top, False)
                put_rows(acc_d, ch, 4, r0, 16, sums)
        if five:
            ch = n_ch - 5
            for r0 in range(0, rp, 16):
                _sums5(x, ch, s0, n, e, rp, r0, sums, top, r0 == 0)
                put_rows(acc_a, ch, 5, r0, 16, sums)
                if r0 == 0:
                    for c in range(5):
                        clip[ch + c] = 1.0 if top[c] >= clip_level else 0.0
                _sums5(x, ch, s0, nz, ez, rp, r0, sums, top, False)
                put_rows(acc_d, ch, 5, r0, 16, sums)
        for ch in range(n_ch if quads or five else 0, n_ch):
            for r0 in range(0, rp, 48):
                first = r0 == 0
                _sums1(x, ch, s0, n, e, rp, r0, sums, top, first)
                put_rows(acc_a, ch, 1, r0, 48, sums)
                if first:
                    clip[ch] = 1.0 if top[0] >= clip_level else 0.0
                _sums1(x, ch, s0, nz, ez, rp, r0, sums, top, False)
                put_rows(acc_d, ch, 1, r0, 48, sums)
        n2 = 0
        if tracked:
            power_sums(x, s0, n, power_from, power_stride, s2)
            n2 = len(range(s0 + (power_from - s0) % power_stride, s0 + n, power_stride))
        pack_row(w[i], mu[i], k2, turn_re, turn_im, period, acc_a, acc_d, wa, wd, s2, n2, clip)
