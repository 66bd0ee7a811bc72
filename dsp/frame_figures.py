"""A frame's speed, speed change and leakage figure, frame by frame, for the compiled path.

:func:`dsp.assemble._finish` computes them with some fifteen array operations per step
(its numpy code is the reference); :func:`frame_figures` is the same arithmetic as loops,
which the compiled path (:func:`dsp.kernels.frame_figures`) runs through numba in one
call. The same operations in the same order, so the same bits: the magnitudes are
numpy's own (its SIMD ``abs`` of a complex is not libm's ``hypot``: it differs in the last
bit, measured, and whether it fuses a multiply-add depends on the machine), the sums over
the internal orders add them in order as numpy's reduction over that (non-contiguous)
axis does, NaN propagates through
the largest output order as ``np.max`` lets it, and the divisions by zero numpy lets
through (inf, NaN) are written out (numba's ``/`` would raise). The leakage figure takes
the square root of a difference of nearly equal powers, so only equal bits keep it equal.
Plain Python: the loops run uncompiled too, which is how the tests step through them.
"""

from __future__ import annotations

import math

import numpy as np


def frame_figures(
    times: np.ndarray,
    omegas: np.ndarray,
    absx: np.ndarray,
    ms: np.ndarray,
    corrected: np.ndarray,
    out: np.ndarray,
    rpm: np.ndarray,
    rpm_change: np.ndarray,
    leak: np.ndarray,
) -> None:
    """``rpm``, ``rpm_change`` (f,) and ``leak`` (f, n_ch) of :func:`dsp.assemble._finish`.

    ``times``, ``omegas`` (f, 3) at the window's start, centre and end (s, rad/s),
    ``absx`` (f, n_int, n_ch) the magnitudes of the corrected amplitudes (``np.abs``),
    ``ms`` (f, n_ch) the mean squares, ``corrected`` (f, n_ch), ``out`` the output orders'
    rows. rpm is 720 deg over the window's duration, ``rpm_change`` the speed change
    across it (``(omega_end - omega_start) * duration / 4 pi``), as there.
    """
    f, n_int, n_ch = absx.shape
    for i in range(f):
        duration = times[i, 2] - times[i, 0]
        if duration != 0.0:
            rpm[i] = 120.0 / duration
        else:  # numpy's 120 / 0: inf of the zero's sign (numba's "/" would raise)
            rpm[i] = np.inf if math.copysign(1.0, duration) > 0.0 else -np.inf
        change = (omegas[i, 2] - omegas[i, 0]) * duration / (4.0 * math.pi)
        rpm_change[i] = change
        scale = abs(change) / math.pi
        for c in range(n_ch):
            explained = 0.0
            total = 0.0
            for k in range(n_int):
                a = absx[i, k, c]
                explained += a * a  # numpy's square
                total += a
            explained = 0.5 * explained
            d = ms[i, c] - explained
            rest = math.sqrt(2.0 * (d if d >= 0.0 or d != d else 0.0))
            known = 0.0 if corrected[i, c] else total
            strongest = -np.inf
            for o in range(out.size):
                v = absx[i, out[o], c]
                if v != v or strongest != strongest:
                    strongest = np.nan
                elif v > strongest:
                    strongest = v
            num = scale * (known + rest)
            if strongest != 0.0:
                leak[i, c] = num / strongest
            else:  # numpy's x / 0 (strongest >= 0): NaN for 0 / 0, else inf
                leak[i, c] = np.nan if num != num or num == 0.0 else np.inf
