"""The angle lookup of a block's consecutive samples in one pass, for numba.

:func:`dsp.segments` looks up every sample of a step: their times ``t0 + k / rate``, then
:func:`dsp.angle.lookup`, which places the table's pieces among the samples with a binary
search per piece and evaluates each piece's cubic over its samples. At 25.6 kHz a 0.5 s
block holds 12 800 samples over some 1 400 pieces: the times and the searches took about
50 us of a step's 1 ms (issue 24). :func:`grid_values` walks samples and pieces together
(both are sorted) and makes the times, angles, speeds, flags and runs in the same pass.

The same numbers as the numpy path, bit for bit: each time is ``t0 + (k / rate)`` (the
index converted exactly, one division, one addition, as numpy's arrays), a sample belongs
to the last piece that starts at or before it (where the binary search puts it), and
the cubic is evaluated with :func:`dsp.kernels._cubic_values`'s operations, in its order
(numba contracts no multiply-add without fastmath). Plain Python: the tests can run it
uncompiled; the compiled path (:data:`dsp.kernels.USE`) runs it through numba.
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
    for i in range(n):
        ti = t[i]
        while p + 1 < end and t_lo[p + 1] <= ti:
            p += 1
        if ti < t_lo[p]:  # before the first piece
            ok[i] = False
            phi[i] = 0.0
            omega[i] = 0.0
            run[i] = 0
            continue
        tau = ti - t_lo[p]
        a1, a2, a3 = c1[p], c2[p], c3[p]
        phi[i] = ((tau * a3 + a2) * tau + a1) * tau + phi_lo[p]
        omega[i] = (tau * (3.0 * a3) + 2.0 * a2) * tau + a1
        if one_run:
            ok[i] = True
            run[i] = run0
        else:
            ok[i] = ti < t_hi[p]
            run[i] = runs[p]
