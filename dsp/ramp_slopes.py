"""The ramps of the leakage correction frame by frame and channel by channel, for numba.

:func:`dsp.leakage.ramp_correction` finds, for each frame and channel, the newest usable
frames one, two or three cycles back and takes the ramp ``b`` of the parabola through
them; in numpy that is some thirty operations on arrays of a few hundred elements, a
tenth of a millisecond per step whatever the number of frames. :func:`ramp_slopes` is
the same rule as loops, which the compiled path (:data:`dsp.kernels.USE`) runs through
numba in a few microseconds; the coupling products that follow stay numpy's.

Equal to the numpy reference in which frames are corrected (exactly) and in ``b``
within 1e-12 relative (the divisions by the distances in windows round as numba's
complex arithmetic does, not as numpy's complex-by-real loop; measured: within 2e-16,
``tests/dsp/test_kernels.py``). Those divisions are written out as numba's complex
division computes them, which skips them where the distance is one window and halves
exactly where it is two (the rule): the same bits, 14.4 -> 7.2 us of CPU a step of 25
frames for the tracked channels, 4.2 -> 2.5 us for the spectrum channel (issue 24).
Plain Python: the loops run uncompiled too (slowly, now with the compiled bits: numpy's
scalars divided their own way), which is how the tests can step through them.
"""

from __future__ import annotations

import numpy as np


def ramp_slopes(
    all_j: np.ndarray,
    all_c: np.ndarray,
    all_x: np.ndarray,
    js: np.ndarray,
    chains: np.ndarray,
    tacho_bad: np.ndarray,
    period: int,
    n_back: int,
    b: np.ndarray,
    good: np.ndarray,
) -> None:
    """Ramp per 720 deg window ``b`` (f, n_int, n_ch) complex and ``good`` (f, n_ch) bool.

    ``all_j`` (h + f,) the frame indices of history and new frames (increasing; the new
    frames ``js`` (f,) last), ``all_c`` their parity chains, ``all_x`` (h + f, n_int,
    n_ch) their raw amplitudes (the new frames' last), ``chains`` and ``tacho_bad`` (f,)
    the new frames'. The frames ``k period`` back (``k = 1 .. n_back``) of the same chain
    and finite in the channel are usable; the newest gives the chord, the next older
    one the bend; ``b`` is 0 where ``good`` is False. ``b`` and ``good`` are written.
    """
    n_all = all_j.size
    f = js.size
    n_int = all_x.shape[1]
    n_ch = all_x.shape[2]
    first = all_j[0]
    gapless = all_j[n_all - 1] - first == n_all - 1
    finite = np.empty((n_all, n_ch), np.bool_)
    for p in range(n_all):
        for c in range(n_ch):
            ok = True
            for h in range(n_int):
                v = all_x[p, h, c]
                ok = ok and np.isfinite(v.real) and np.isfinite(v.imag)
            finite[p, c] = ok
    back = np.empty(n_back, np.int64)
    for i in range(f):
        j = js[i]
        for k in range(n_back):
            want = j - (k + 1) * period
            if gapless:
                pos = want - first
                back[k] = pos if 0 <= pos < n_all else -1
            else:
                pos = min(np.searchsorted(all_j, want), n_all - 1)
                back[k] = pos if all_j[pos] == want else -1
        base = (n_all - f) + i  # the frame itself
        for c in range(n_ch):
            ref = -1
            ref2 = -1
            for k in range(n_back):
                pos = back[k]
                if pos >= 0 and all_c[pos] == chains[i] and finite[pos, c]:
                    if ref < 0:
                        ref = pos
                    elif ref2 < 0:
                        ref2 = pos
            ok = ref >= 0 and finite[base, c] and not tacho_bad[i]
            good[i, c] = ok
            if not ok:
                for h in range(n_int):
                    b[i, h, c] = 0.0
                continue
            # how far back, in windows: the frames sit at u = 0, -d1, -d2
            d1 = (j - all_j[ref]) / period
            d2 = (j - all_j[ref2]) / period if ref2 >= 0 else 0.0
            d21 = d2 - d1
            for h in range(n_int):
                x0 = all_x[base, h, c]
                x1 = all_x[ref, h, c]
                # the chord's slope (x0 - x1) / d1: the ramp half a chord back. Each
                # complex-by-real quotient z / d written out as numba's (and CPython's)
                # complex division by d + 0j computes it for d > 0 (ratio 0, denominator
                # d): (Re z + Im z 0) / d, (Im z - Re z 0) / d; no division where d is 1,
                # an exact halving where it is 2 (the rule: frames one and two cycles
                # back), the same bits (issue 24: the divisions were half of this loop)
                zr, zi = x0.real - x1.real, x0.imag - x1.imag
                qr, qi = zr + zi * 0.0, zi - zr * 0.0
                if d1 == 2.0:
                    qr, qi = qr * 0.5, qi * 0.5
                elif d1 != 1.0:
                    qr, qi = qr / d1, qi / d1
                s1 = complex(qr, qi)
                if ref2 >= 0:
                    # the parabola through the three frames has the slope s1 + c d1 at u = 0:
                    # c = (s1 - (x1 - x2) / (d2 - d1)) / d2
                    x2 = all_x[ref2, h, c]
                    zr, zi = x1.real - x2.real, x1.imag - x2.imag
                    qr, qi = zr + zi * 0.0, zi - zr * 0.0
                    if d21 == 2.0:
                        qr, qi = qr * 0.5, qi * 0.5
                    elif d21 != 1.0:
                        qr, qi = qr / d21, qi / d21
                    zr, zi = s1.real - qr, s1.imag - qi
                    qr, qi = zr + zi * 0.0, zi - zr * 0.0
                    if d2 == 2.0:
                        qr, qi = qr * 0.5, qi * 0.5
                    elif d2 != 1.0:
                        qr, qi = qr / d2, qi / d2
                    b[i, h, c] = s1 + complex(qr, qi) * d1
                else:
                    b[i, h, c] = s1
