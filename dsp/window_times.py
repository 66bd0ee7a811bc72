"""The times and speeds at frames' window start, centre and end, frame by frame, for the
compiled path.

:func:`dsp.window_amplitudes.window_amplitudes` finds them with :func:`dsp.angle.time_at` of
the batch's ``f + 2 n`` distinct angles, then picks each frame's three (an index array,
a finiteness test and two gathers: some ten array operations a step besides the lookup).
:func:`window_times` is the same lookup written into the frames' rows directly, which the
compiled path (:func:`dsp.kernels.window_times`) runs through numba in one call: each
angle ``(j + (a - 1) n) spacing`` as numpy makes it (the integer made a float, times
``spacing``), its piece and Newton's steps on the piece's cubic as
:func:`dsp.angle.time_at` takes them, the same operations in the same order, so the same
bits (an angle shared by two frames' windows is solved twice, to the same bits).
Plain Python: the loops run uncompiled too, which is how the tests step through them.

Measured (issue 24; the run's 60 s log compiled, 120 steps of about 25 frames): the
lookup and its array operations about 16 us a step (wall time of its lines, load 3), the
compiled call about 4 us; :func:`dsp.window_amplitudes.window_amplitudes` with it and
:mod:`dsp.fused_frames` 4.6-5.7 -> 4.1-4.7 ms a minute (CPU best of 9, load 3.3-4.6).
"""

from __future__ import annotations

import numpy as np


def window_times(
    js: np.ndarray,
    n: int,
    spacing: float,
    t_lo: np.ndarray,
    t_hi: np.ndarray,
    phi_lo: np.ndarray,
    phi_hi: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    c3: np.ndarray,
    times: np.ndarray,
    omegas: np.ndarray,
) -> bool:
    """Write ``times`` (s) and ``omegas`` (rad/s) (f, 3) of frames ``js`` (f,) at the angles
    ``(j - n) spacing``, ``j spacing``, ``(j + n) spacing`` (rad), from the angle table's
    columns (:class:`dsp.angle.AngleTable`); NaN outside every piece, as
    :func:`dsp.angle.time_at`. Returns whether every time is finite."""
    finite = True
    for i in range(js.size):
        for a in range(3):
            phi = (js[i] + (a - 1) * n) * spacing
            j = np.searchsorted(phi_lo, phi, side="right") - 1
            if j < 0 or not phi <= phi_hi[j]:
                times[i, a] = np.nan
                omegas[i, a] = np.nan
                finite = False
                continue
            a1, a2, a3 = c1[j], c2[j], c3[j]
            a2x2 = 2.0 * a2
            target = phi - phi_lo[j]
            tau = target / (phi_hi[j] - phi_lo[j]) * (t_hi[j] - t_lo[j])
            for _ in range(4):
                f = tau * (a1 + tau * (a2 + tau * a3)) - target
                fp = a1 + tau * (a2x2 + 3.0 * tau * a3)
                tau -= f / fp
            omegas[i, a] = a1 + tau * (a2x2 + 3.0 * tau * a3)
            times[i, a] = t_lo[j] + tau
            finite = finite and np.isfinite(times[i, a])
    return finite
