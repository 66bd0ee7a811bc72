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

Issue 24, third pass (the run's 60 s log, the kernels alone over the calls of a replay,
CPU best of 15, load 3): :func:`grid_values` 3.7 -> 2.7 ms a minute (each piece's last
sample found from where the grid puts it, not by a scan of its samples; the flags and
runs of one run written in one fill); :func:`append_knots` 2.3 -> 1.5-1.7 ms (the old
columns copied as slices, each run's divided differences on slices indexed from 0 and
compiled with numpy's division, so LLVM vectorises them). The same bits (each kernel's
outputs compared on every call of that log; the tests compare them with the numpy path).
"""

from __future__ import annotations

import math

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
    i_first = i
    # piece by piece: a sample belongs to the last piece that starts at or before it
    while i < n:
        j = n
        if p + 1 < end:
            # the first sample at or after the next piece's start: from where the grid puts
            # it, settled with the times themselves (a piece holds some ten samples at
            # 25.6 kHz: a step or two, not a scan of all of them)
            t_next = t_lo[p + 1]
            j = min(max(math.ceil((t_next - t0_s) * rate_hz) - first, i), n)
            while j > i and not t[j - 1] < t_next:
                j -= 1
            while j < n and t[j] < t_next:
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
        if not one_run:
            t_end, run_p = t_hi[p], runs[p]
            for k in range(i, j):
                ok[k] = t[k] < t_end
                run[k] = run_p
        i = j
        p += 1
    if one_run:  # every sample from the first piece on: one fill each
        ok[i_first:] = True
        run[i_first:] = run0


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
    o_tlo[:old], o_thi[:old], o_plo[:old], o_phi[:old] = t_lo, t_hi, phi_lo, phi_hi
    o_c1[:old], o_c2[:old], o_c3[:old], o_run[:old] = c1, c2, c3, run
    at = old
    a = 0
    for i in range(1, k + 1):
        if i == k or kr[i] != kr[i - 1]:
            # the intervals from knot j to j + 1 (j = a + 1 .. i - 3), each cubic through
            # knots j - 1 .. j + 2, as slices indexed from 0 (numba checks no index for
            # wrap-around and, without Python's zero-division checks, LLVM vectorises the
            # divisions: dsp.kernels.append_knots)
            m = i - a - 3
            if m > 0:
                tm, t0, t1, t2 = (
                    kt[a : a + m],
                    kt[a + 1 : a + 1 + m],
                    kt[a + 2 : a + 2 + m],
                    kt[a + 3 : a + 3 + m],
                )
                pm, p0, p1, p2 = (
                    kp[a : a + m],
                    kp[a + 1 : a + 1 + m],
                    kp[a + 2 : a + 2 + m],
                    kp[a + 3 : a + 3 + m],
                )
                w1, w2, w3 = o_c1[at : at + m], o_c2[at : at + m], o_c3[at : at + m]
                for q in range(m):
                    t_j, p_j = t0[q], p0[q]
                    z1 = t1[q] - t_j
                    z2 = tm[q] - t_j
                    z3 = t2[q] - t_j
                    f01 = (p1[q] - p_j) / z1
                    f02 = (pm[q] - p_j) / z2
                    f03 = (p2[q] - p_j) / z3
                    f012 = (f02 - f01) / (z2 - z1)
                    f013 = (f03 - f01) / (z3 - z1)
                    f0123 = (f013 - f012) / (z3 - z2)
                    w3[q] = f0123
                    w2[q] = f012 - f0123 * (z1 + z2)
                    w1[q] = f01 - f012 * z1 + f0123 * z1 * z2
                o_tlo[at : at + m], o_thi[at : at + m] = t0, t1
                o_plo[at : at + m], o_phi[at : at + m] = p0, p1
                o_run[at : at + m] = kr[a + 1 : a + 1 + m]
                at += m
            a = i
    return o_tlo, o_thi, o_plo, o_phi, o_c1, o_c2, o_c3, o_run, kt[tail:], kp[tail:], kr[tail:]
