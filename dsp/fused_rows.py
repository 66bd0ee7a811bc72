"""A segment's sums in the compiled path once made: into the accumulators, the mean
square, packed into the segment's row.

Compiled helpers of :mod:`dsp.fused_sums` (imported only with it: numba), which calls
them once per segment or chunk of rows; moved here to keep that module within its
length. Each repeats the numpy path's operations in its order (:func:`dsp.sums._packed`
and :func:`dsp.sum_sets.numpy_sums`), so the same numbers bit for bit. numba's cache does
not watch this file for :mod:`dsp.fused_sums`: after changing it, set
``dsp.fused_sums.HELPERS_SHA256`` anew (its test prints the value).
"""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True)
def put_rows(acc, ch, nb, r0, width, sums):
    """The sums of ``nb`` channels, ``width`` columns each from column ``r0``, into their
    rows of ``acc`` (n_ch, 2 no); columns past ``2 no`` are padding."""
    for c in range(nb):
        for r in range(r0, min(r0 + width, acc.shape[1])):
            acc[ch + c, r] = sums[width * c + r - r0]


@njit(cache=True, nogil=True)
def pack_row(row, m, k2, turn_re, turn_im, period, acc_a, acc_d, wa, wd, s2, n2, clip):
    """Segment ``m``'s sums into its :data:`dsp.sum_rows.Row`: ``a`` and ``d`` as complex
    (Re, Im pairs), rotated by ``exp(-i h c_m)``, each product as numpy's complex one;
    every place of the row written."""
    n_ch, no = acc_a.shape[0], k2.size
    k = 2 * n_ch * no
    h = k + n_ch + 2
    for j in range(no):
        turn = (m * k2[j]) % period
        tr, ti = turn_re[turn], turn_im[turn]
        for ch in range(n_ch):
            at = 2 * (ch * no + j)
            ar, ai = acc_a[ch, j], acc_a[ch, no + j]
            row[at] = ar * tr - ai * ti
            row[at + 1] = ar * ti + ai * tr
            dr, di = acc_d[ch, j], acc_d[ch, no + j]
            row[h + at] = dr * tr - di * ti
            row[h + at + 1] = dr * ti + di * tr
    row[k] = wa
    row[h + k] = wd
    row[k + 1 + n_ch] = n2
    for ch in range(n_ch):
        row[k + 1 + ch] = s2[ch]
        row[2 * h + ch] = clip[ch]
    # the zone block's mean-square and count places are not used: zeros, as numpy's
    # packing leaves them, so the whole row is written (the rows come uninitialised)
    for j in range(h + k + 1, 2 * h):
        row[j] = 0.0


@njit(cache=True, nogil=True)
def power_sums(x, s0, n, power_from, power_stride, s2):
    """``sum x^2`` over the segment's samples of the mean square, into ``s2`` (n_ch,):
    each channel's sum in time order, four channels' chains side by side."""
    p0 = s0 + (power_from - s0) % power_stride
    n_ch = x.shape[0]
    ch = 0
    while ch + 4 <= n_ch:
        t0 = t1 = t2 = t3 = 0.0
        for s in range(p0, s0 + n, power_stride):
            t0 += x[ch, s] * x[ch, s]
            t1 += x[ch + 1, s] * x[ch + 1, s]
            t2 += x[ch + 2, s] * x[ch + 2, s]
            t3 += x[ch + 3, s] * x[ch + 3, s]
        s2[ch], s2[ch + 1], s2[ch + 2], s2[ch + 3] = t0, t1, t2, t3
        ch += 4
    for c in range(ch, n_ch):
        t0 = 0.0
        for s in range(p0, s0 + n, power_stride):
            t0 += x[c, s] * x[c, s]
        s2[c] = t0
