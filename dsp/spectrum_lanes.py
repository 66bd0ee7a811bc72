"""The sums of one channel over many orders, with lanes over samples (the spectrum channel).

Compiled helper of :mod:`dsp.fused_sums` (imported only with it: numba). The spectrum
channel is one channel with every half order up to ``spectrum_max_order + 2`` (17 orders,
34 rows of sums): transposing its carriers to rows-in-lanes, as the tracked channels'
sums want them, would cost more than the sums. Here lanes are samples throughout: each
carrier is used as it is made, and each row keeps eight partial sums (sample ``s`` in
lane ``s mod 8``, counted from the segment's first sample in the piece), added in a fixed
order at the end. The same piece gives the same bits whatever else the call holds
(replay = live); against the numpy path's BLAS products the rows agree within 1e-12 of
the segment's largest sum (``tests/dsp/test_kernels.py``). Measured (the run's dsp stage,
9 accelerometers + the pressure's spectrum, 60 s, CPU, load 3): the spectrum channel's
kernel time 17.7 ms -> 11.1 ms per minute against the transposed layout. Two blocks of eight
samples a pass (issue 24: two independent running products, each row's partial sums
loaded and stored once for both; the terms added in the same order, so the same bits,
checked on every call of the run's log): the spectrum channel's calls 14.4-15.1 ->
12.5-13.1 ms per minute of that log (CPU, best of 7, load 3.5). numba's cache
does not watch this file for :mod:`dsp.fused_sums`: after changing it, set
``dsp.fused_sums.HELPERS_SHA256`` anew (its test prints the value).
"""

from __future__ import annotations

from numba import njit

from dsp.vec8 import vadd, vfma, vload, vmul, vstore, vsub, vzero

# numba's cache watches this file only, and its functions are cached on their own: the
# sha256 of the intrinsics they inline (tests/dsp/test_kernels.py prints a new value)
HELPERS = ("vec8.py",)
HELPERS_SHA256 = "d5b248d7803074a1bceacba3229e2f17bae7537116e76ac70f400793a0fa8ca4"


@njit(cache=True, nogil=True)
def lane_sums(x, c, s0, n, nz, pb_re, pb_im, pq, fall, k2, px, lanes, acc_a, acc_d):
    """Channel ``c``'s sums of one segment with lanes over samples: eight partial sums per
    row (sample ``s`` in lane ``s mod 8``, counted from the segment's first sample in the
    piece, so the same piece gives the same bits), added lane by lane at the end. For a
    set of one channel and many orders (the spectrum channel's 17 carry 34 rows): no
    transposes, and each carrier is used as it is made. The zone's samples are weighted
    by the falling taper (``x * fall``, as :func:`dsp.sum_sets.numpy_sums`)."""
    no = k2.size
    n_rows = 2 * no
    n8 = (n + 7) // 8 * 8
    nz8 = (nz + 7) // 8 * 8
    zx = n8  # where the zone's weighted samples begin in px
    # slices indexed from 0: no wrap-around checks, so numba vectorises the copies
    xs, pxz = x[c, s0 : s0 + n], px[zx : zx + nz8]
    for s in range(n):
        px[s] = xs[s]
    for s in range(n, n8):
        px[s] = 0.0
    for s in range(nz):
        pxz[s] = px[s] * fall[s]
    for s in range(nz, nz8):
        pxz[s] = 0.0
    lanes[:] = 0.0
    zd = 8 * n_rows  # where the zone's sums begin in lanes
    s = 0
    while s + 8 < n:
        # two blocks of eight samples at once: their running products are independent
        # chains, and each row's partial sums are loaded and stored once for both
        # (block s's term added before block s + 8's, as one block at a time: the same bits)
        t = s + 8
        xa = vload(px, s)
        xb = vload(px, t)
        za = s < nz
        zb = t < nz  # implies za
        fa = vload(px, zx + s) if za else vzero()
        fb = vload(px, zx + t) if zb else vzero()
        bra = vload(pb_re, s)
        bia = vload(pb_im, s)
        qa = vload(pq, s)
        brb = vload(pb_re, t)
        bib = vload(pb_im, t)
        qb = vload(pq, t)
        j = 0
        if k2[0] == 0:
            _lane_add2(lanes, 0, 8 * no, xa, qa, vzero(), xb, qb, vzero())
            if zb:
                _lane_add2(lanes, zd, zd + 8 * no, fa, qa, vzero(), fb, qb, vzero())
            elif za:
                _lane_add(lanes, zd, zd + 8 * no, fa, qa, vzero())
            j = 1
        pra = vmul(bra, qa)
        pia = vmul(bia, qa)
        prb = vmul(brb, qb)
        pib = vmul(bib, qb)
        for k in range(1, k2[no - 1] + 1):
            if k > 1:
                ta = vsub(vmul(pra, bra), vmul(pia, bia))
                pia = vadd(vmul(pra, bia), vmul(pia, bra))
                pra = ta
                tb = vsub(vmul(prb, brb), vmul(pib, bib))
                pib = vadd(vmul(prb, bib), vmul(pib, brb))
                prb = tb
            if j < no and k == k2[j]:
                _lane_add2(lanes, 8 * j, 8 * (no + j), xa, pra, pia, xb, prb, pib)
                if zb:
                    _lane_add2(lanes, zd + 8 * j, zd + 8 * (no + j), fa, pra, pia, fb, prb, pib)
                elif za:
                    _lane_add(lanes, zd + 8 * j, zd + 8 * (no + j), fa, pra, pia)
                j += 1
        s += 16
    while s < n:  # an odd block left over
        xv = vload(px, s)
        zone = s < nz
        xf = vload(px, zx + s) if zone else vzero()
        br = vload(pb_re, s)
        bi = vload(pb_im, s)
        qv = vload(pq, s)
        j = 0
        if k2[0] == 0:
            _lane_add(lanes, 0, 8 * no, xv, qv, vzero())
            if zone:
                _lane_add(lanes, zd, zd + 8 * no, xf, qv, vzero())
            j = 1
        pr = vmul(br, qv)
        pi = vmul(bi, qv)
        for k in range(1, k2[no - 1] + 1):
            if k > 1:
                tr = vsub(vmul(pr, br), vmul(pi, bi))
                pi = vadd(vmul(pr, bi), vmul(pi, br))
                pr = tr
            if j < no and k == k2[j]:
                _lane_add(lanes, 8 * j, 8 * (no + j), xv, pr, pi)
                if zone:
                    _lane_add(lanes, zd + 8 * j, zd + 8 * (no + j), xf, pr, pi)
                j += 1
        s += 8
    for r in range(n_rows):
        acc_a[c, r] = _lane_total(lanes, 8 * r)
        acc_d[c, r] = _lane_total(lanes, zd + 8 * r)


@njit(cache=True, nogil=True, inline="always")
def _lane_add(lanes, at_re, at_im, xv, pr, pi):
    """Add ``xv pr`` and ``xv pi`` to the eight partial sums at ``at_re`` and ``at_im``."""
    vstore(lanes, at_re, vfma(xv, pr, vload(lanes, at_re)))
    vstore(lanes, at_im, vfma(xv, pi, vload(lanes, at_im)))


@njit(cache=True, nogil=True, inline="always")
def _lane_add2(lanes, at_re, at_im, xa, pra, pia, xb, prb, pib):
    """:func:`_lane_add` of ``xa (pra, pia)`` then of ``xb (prb, pib)``, with one load and
    one store of each row's partial sums."""
    vstore(lanes, at_re, vfma(xb, prb, vfma(xa, pra, vload(lanes, at_re))))
    vstore(lanes, at_im, vfma(xb, pib, vfma(xa, pia, vload(lanes, at_im))))


@njit(cache=True, nogil=True)
def _lane_total(lanes, at):
    """The eight partial sums at ``at`` added in a fixed order (pairs, then pairs of pairs)."""
    a = (lanes[at] + lanes[at + 1]) + (lanes[at + 2] + lanes[at + 3])
    return a + ((lanes[at + 4] + lanes[at + 5]) + (lanes[at + 6] + lanes[at + 7]))
