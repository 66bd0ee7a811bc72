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

:func:`cubic_pieces` does :func:`dsp.angle.cubic_pieces`'s divided differences knot by knot
(some 25 array operations a step in numpy), the same operations in the same order, so the
same bits (:func:`dsp.kernels.cubic_pieces` compiles it).
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


def cubic_pieces(
    t: np.ndarray, phi: np.ndarray, c1: np.ndarray, c2: np.ndarray, c3: np.ndarray
) -> None:
    """:func:`dsp.angle.cubic_pieces` knot by knot: its divided differences, the same
    operations in the same order (no contraction), so the same bits. ``t``, ``phi`` (k,);
    writes ``c1``, ``c2``, ``c3`` (k - 3,)."""
    for j in range(c1.size):
        t_j, p_j = t[j + 1], phi[j + 1]
        z1 = t[j + 2] - t_j
        z2 = t[j] - t_j
        z3 = t[j + 3] - t_j
        f01 = (phi[j + 2] - p_j) / z1
        f02 = (phi[j] - p_j) / z2
        f03 = (phi[j + 3] - p_j) / z3
        f012 = (f02 - f01) / (z2 - z1)
        f013 = (f03 - f01) / (z3 - z1)
        f0123 = (f013 - f012) / (z3 - z2)
        c3[j] = f0123
        c2[j] = f012 - f0123 * (z1 + z2)
        c1[j] = f01 - f012 * z1 + f0123 * z1 * z2
