"""The angle table's per-step loops for numba: the lookup of a block's consecutive samples
in one pass, and the table's cubic coefficients knot by knot.

:func:`dsp.segments` looks up every sample of a step: their times ``t0 + k / rate``, then
:func:`dsp.angle.lookup`, which places the table's pieces among the samples with a binary
search per piece and evaluates each piece's cubic over its samples. At 25.6 kHz a 0.5 s
block holds 12 800 samples over some 1 400 pieces: the times and the searches took about
50 us of a step's 1 ms (issue 24). :func:`grid_values` walks samples and pieces together
(both are sorted) and makes the times, angles, speeds, flags and runs in the same pass.
It evaluates each piece's cubic over its samples as a slice indexed from 0, which numba
vectorises (issue 24, second pass: 36 -> 28 us of CPU a 0.5 s block at 25.6 kHz, the
same bits).

The same numbers as the numpy path, bit for bit: each time is ``t0 + (k / rate)`` (the
index converted exactly, one division, one addition, as numpy's arrays), a sample belongs
to the last piece that starts at or before it (where the binary search puts it), and
the cubic is evaluated with :func:`dsp.kernels._cubic_values`'s operations, in its order
(numba contracts no multiply-add without fastmath). Plain Python: the tests can run it
uncompiled; the compiled path (:data:`dsp.kernels.USE`) runs it through numba.

:func:`append_knots` is :func:`dsp.angle.add_knots` in one pass: the knots' run stretches,
:func:`dsp.angle.cubic_pieces`'s divided differences knot by knot (the same operations in
the same order, so the same bits) and the new columns (issue 24: some 25 array operations
a step in numpy, 26 -> 14.5 us of CPU at load 6; :func:`dsp.kernels.append_knots` compiles it).
"""

from __future__ import annotations

import numpy as np


def grid_values(
    t0_s: float,
    rate_hz: float,
    first: int,
    t_lo: np.ndarray,
    t_hi: np.ndarray,
    phi_lo: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    c3: np.ndarray,
    runs: np.ndarray,
    t: np.ndarray,
    ok: np.ndarray,
    phi: np.ndarray,
    omega: np.ndarray,
    run: np.ndarray,
) -> None:
    """:func:`dsp.angle.lookup` of the times of grid indices ``first .. first + n - 1``.

    ``t0_s`` (s) and ``rate_hz`` the sample clock, the table's columns (p,) (time order);
    writes (n,) the times ``t`` (s), ``ok`` (the sample lies in a piece), ``phi`` (rad),
    ``omega`` (rad/s) and ``run`` (0, 0 and 0 where not ``ok`` before the first piece).
    """
    n = t.size
    for i in range(n):
        t[i] = t0_s + (first + i) / rate_hz
    if t_lo.size == 0 or n == 0 or t[n - 1] < t_lo[0]:
        for i in range(n):
            ok[i] = False
            phi[i] = 0.0
            omega[i] = 0.0
            run[i] = 0
        return
    # the pieces lookup's searches select: from the last one starting at or before the
    # first sample (or the first piece) to the last one starting at or before the last
    p = max(np.searchsorted(t_lo, t[0], side="right") - 1, 0)
    end = np.searchsorted(t_lo, t[n - 1], side="right")
    # the pieces of one run follow each other: every sample from the first piece on is inside
    one_run = runs[p] == runs[end - 1] and t[n - 1] < t_hi[end - 1]
    run0 = runs[p]
    i = 0
    while i < n and t[i] < t_lo[p]:  # before the first piece
        ok[i] = False
        phi[i] = 0.0
        omega[i] = 0.0
        run[i] = 0
        i += 1
    # piece by piece: a sample belongs to the last piece that starts at or before it
    while i < n:
        j = n
        if p + 1 < end:
            j = i
            while j < n and t[j] < t_lo[p + 1]:
                j += 1
        # the piece's samples as slices indexed from 0: numba then knows no index is
        # negative and vectorises the loop (from the piece's first sample it checked
        # each index for wrap-around and ran scalar)
        tl, pl, a1, a2, a3 = t_lo[p], phi_lo[p], c1[p], c2[p], c3[p]
        a3x3 = 3.0 * a3
        a2x2 = 2.0 * a2
        ts, ps, ws = t[i:j], phi[i:j], omega[i:j]
        for k in range(ts.size):
            tau = ts[k] - tl
            ps[k] = ((tau * a3 + a2) * tau + a1) * tau + pl
            ws[k] = (tau * a3x3 + a2x2) * tau + a1
        for k in range(i, j):
            ok[k] = True if one_run else t[k] < t_hi[p]
            run[k] = run0 if one_run else runs[p]
        i = j
        p += 1


def append_knots(
    t_lo: np.ndarray,
    t_hi: np.ndarray,
    phi_lo: np.ndarray,
    phi_hi: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    c3: np.ndarray,
    run: np.ndarray,
    tail_t: np.ndarray,
    tail_phi: np.ndarray,
    tail_run: np.ndarray,
    t: np.ndarray,
    phi: np.ndarray,
    runs: np.ndarray,
) -> tuple[np.ndarray, ...]:
    """:func:`dsp.angle.add_knots` in one pass: the table's columns ``t_lo .. run`` and
    tail ``tail_t, tail_phi, tail_run``, the new knots ``t`` (s), ``phi`` (rad), ``runs``;
    returns the new columns (the same arrays when no interval is formed) and tail.

    The knots (tail, then new) split where the run changes; a stretch of ``k >= 4`` knots
    forms intervals 1 .. k-3, each with :func:`dsp.angle.cubic_pieces`'s divided
    differences on its four knots, the same operations in the same order (no
    contraction), so the same bits; the tail is the last stretch's last three knots.
    """
    nt = tail_t.size
    k = nt + t.size
    kt, kp, kr = np.empty(k), np.empty(k), np.empty(k, np.int64)
    for i in range(nt):
        kt[i], kp[i], kr[i] = tail_t[i], tail_phi[i], tail_run[i]
    for i in range(t.size):
        kt[nt + i], kp[nt + i], kr[nt + i] = t[i], phi[i], runs[i]
    new = 0  # intervals formed
    a = last = 0
    for i in range(1, k + 1):
        if i == k or kr[i] != kr[i - 1]:
            new += max(i - a - 3, 0)
            last = a
            a = i
    tail = max(last, k - 3)
    if new == 0:
        return t_lo, t_hi, phi_lo, phi_hi, c1, c2, c3, run, kt[tail:], kp[tail:], kr[tail:]
    old = t_lo.size
    cols = [np.empty(old + new) for _ in range(7)]
    o_tlo, o_thi, o_plo, o_phi, o_c1, o_c2, o_c3 = cols
    o_run = np.empty(old + new, np.int64)
    for i in range(old):
        o_tlo[i], o_thi[i], o_plo[i], o_phi[i] = t_lo[i], t_hi[i], phi_lo[i], phi_hi[i]
        o_c1[i], o_c2[i], o_c3[i], o_run[i] = c1[i], c2[i], c3[i], run[i]
    at = old
    a = 0
    for i in range(1, k + 1):
        if i == k or kr[i] != kr[i - 1]:
            # the interval from knot j to j + 1, its cubic through knots j - 1 .. j + 2
            for j in range(a + 1, i - 2):
                t_j, p_j = kt[j], kp[j]
                z1 = kt[j + 1] - t_j
                z2 = kt[j - 1] - t_j
                z3 = kt[j + 2] - t_j
                f01 = (kp[j + 1] - p_j) / z1
                f02 = (kp[j - 1] - p_j) / z2
                f03 = (kp[j + 2] - p_j) / z3
                f012 = (f02 - f01) / (z2 - z1)
                f013 = (f03 - f01) / (z3 - z1)
                f0123 = (f013 - f012) / (z3 - z2)
                o_c3[at] = f0123
                o_c2[at] = f012 - f0123 * (z1 + z2)
                o_c1[at] = f01 - f012 * z1 + f0123 * z1 * z2
                o_tlo[at], o_thi[at], o_plo[at], o_phi[at] = t_j, kt[j + 1], p_j, kp[j + 1]
                o_run[at] = kr[j]
                at += 1
            a = i
    return o_tlo, o_thi, o_plo, o_phi, o_c1, o_c2, o_c3, o_run, kt[tail:], kp[tail:], kr[tail:]
