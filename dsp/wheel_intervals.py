"""The wheel decoder's pass over a block's edges: tooth intervals per pitch and where the
pattern breaks.

:func:`dsp.wheel.decode_edges` looks at every interval between buffered edges: its tooth
count and wheel position, the interval per pitch ``r``, its ratio to the one before, and
the first interval whose ratio leaves the tolerance (a missed or extra edge, a dropout).
:func:`wheel_intervals` is that in numpy (the reference); :func:`interval_loops` the same
arithmetic edge by edge for numba (:func:`dsp.kernels.wheel_intervals`, the compiled path):
at 0.5 s blocks some 1 400 edges a step, a dozen array operations replaced by one pass
(issue 24). The same numbers, bit for bit: integer positions with Python's (numpy's)
floor division and modulo, the interval divided by its pitch count converted to a float,
the ratio one division (numba contracts nothing without fastmath). Plain Python: the
tests can run the loops uncompiled.
"""

from __future__ import annotations

import numpy as np


def wheel_intervals(
    buf: np.ndarray, d: np.ndarray, c0: int, teeth: int, gap: int, r_prev: float, tol: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """Tooth counts, positions and interval ratios of the buffered edges (numpy).

    ``buf`` (k,) edge times (s), ``d = diff(buf)`` (k - 1,), ``c0`` the tooth count of
    ``buf[0]``, ``r_prev`` the per-pitch interval before ``buf[0]`` (s), ``tol`` the
    decoder's tolerance. Returns the tooth counts ``c`` and wheel positions ``n_rel``
    (k,) int64 (pitches), the per-pitch intervals ``r``, each one's predecessor ``prev``
    and their ratios ``ratio`` (k - 1,), and the first interval whose ratio lies outside
    ``1 -+ tol`` (-1 if none).
    """
    per_rev = teeth - gap
    c = c0 + np.arange(buf.size)
    n_rel = (c // per_rev) * teeth + (c % per_rev)  # dsp.wheel._position
    pitches = np.diff(n_rel)
    r = d / pitches
    prev = np.concatenate(([r_prev], r[:-1]))
    ratio = r / prev
    bad = np.flatnonzero((ratio < 1 - tol) | (ratio > 1 + tol))
    return c, n_rel, r, prev, ratio, int(bad[0]) if bad.size else -1


def interval_loops(
    buf: np.ndarray,
    d: np.ndarray,
    c0: int,
    teeth: int,
    gap: int,
    r_prev: float,
    tol: float,
    c: np.ndarray,
    n_rel: np.ndarray,
    r: np.ndarray,
    prev: np.ndarray,
    ratio: np.ndarray,
) -> int:
    """:func:`wheel_intervals` edge by edge: writes ``c``, ``n_rel`` (k,), ``r``, ``prev``,
    ``ratio`` (k - 1,) and returns the first interval out of tolerance (-1 if none).
    Compiled with numba's numpy error model (:func:`dsp.kernels.wheel_intervals`): a
    repeated edge's zero interval divides by zero into inf or NaN, out of tolerance, as
    numpy's division does, not a ZeroDivisionError."""
    per_rev = teeth - gap
    lo, hi = 1 - tol, 1 + tol
    for i in range(buf.size):
        c[i] = c0 + i
        n_rel[i] = (c[i] // per_rev) * teeth + (c[i] % per_rev)
    first_bad = -1
    before = r_prev
    for i in range(d.size):
        r[i] = d[i] / float(n_rel[i + 1] - n_rel[i])
        prev[i] = before
        ratio[i] = r[i] / before
        if first_bad < 0 and (ratio[i] < lo or ratio[i] > hi):
            first_bad = i
        before = r[i]
    return first_bad
