"""The compiled synthesis of a run of samples in one sweep segment, in one call that holds no GIL.

:func:`acquisition.sim.synthesis.synthesize_accel` on the compiled path multiplies, per
table interval and chunk of :data:`CHUNK` samples, the interval's coefficients with the
carriers (BLAS), then sums the product's rows in the normalised rpm ``u`` by Horner. Done
from Python, each chunk was three calls, each releasing the GIL and taking it back: about
45 a block of 0.5 s, 5400 a minute of the i3 at 25.6 kHz. In a live run the simulator's
thread shares the GIL with the processing thread, which holds it for most of its time, and
every one of those calls meant waiting for it again (a convoy). Measured on 2026-11-26 (the
60 s compiled live run with recording, best of 3, twice, quiet machine): 0.52-0.57 s of wall
time, against 0.31-0.35 s with the simulator's items made before the run; the processing
thread's CPU 0.36-0.39 s against 0.28-0.32 s.

:func:`block_accel` runs the loop over intervals and chunks in one compiled call (the
product by ``np.dot``, which numba hands to the BLAS that scipy ships, on a contiguous copy
of the chunk's carriers; the Horner sums as before). The product is the same ``dgemm``
call as numpy's (the same operands, transposes and sizes: only the carriers' leading
dimension differs, and the kernel packs its operands before it multiplies), so the samples
are the same bits (tested against the Python loop).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

CHUNK = 1024  # samples per product: keeps the operands in cache (~1.5x faster than 2560)
_compiled: dict[str, Callable[..., Any]] = {}


def block_accel(
    rows: np.ndarray,
    first: int,
    j: np.ndarray,
    u: np.ndarray,
    constant: np.ndarray,
    varying: np.ndarray,
    kept: int,
    out: np.ndarray,
) -> None:
    """Accelerations of samples ``first .. first + j.size`` into ``out`` (n_ch, n), m/s^2.

    ``rows`` (2 n_o, n): the carriers (:func:`acquisition.sim.kernels.carriers`); ``j``,
    ``u``: the samples' table interval and normalised rpm (:func:`kernels.locate`) in one
    segment, whose :class:`~acquisition.sim.compact_design.CompactDesign` operands are
    ``constant`` (n_int, n_ch, 2 n_o) and ``varying`` (n_int, degree n_ch, ``kept``).
    """
    if "block" not in _compiled:
        from numba import njit  # heavy (0.3 s): only where the kernels are used

        global _horner_compiled
        _horner_compiled = njit(cache=True, nogil=True)(_horner)
        _compiled["block"] = njit(cache=True, nogil=True)(_block_accel)
    n_rows = constant.shape[1] + varying.shape[1]
    y = np.empty(n_rows * CHUNK)
    _compiled["block"](rows, first, j, u, constant, varying, kept, y, out)


def _block_accel(
    rows: np.ndarray,
    first: int,
    j: np.ndarray,
    u: np.ndarray,
    constant: np.ndarray,
    varying: np.ndarray,
    kept: int,
    y: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`block_accel`'s loop; ``y``: room for ``n_k n_ch`` rows of :data:`CHUNK`."""
    n = j.size
    n_ch = constant.shape[1]
    n_var = varying.shape[1]
    a = 0
    while a < n:
        b = a + 1
        while b < n and j[b] == j[a]:
            b += 1
        d0 = constant[j[a]]
        dk = varying[j[a]]
        for c0 in range(a, b, CHUNK):
            m = min(b, c0 + CHUNK) - c0
            s0 = first + c0
            yk = y[: (n_ch + n_var) * m].reshape(n_ch + n_var, m)
            np.dot(d0, np.ascontiguousarray(rows[:, s0 : s0 + m]), yk[:n_ch])
            if n_var:
                np.dot(dk, np.ascontiguousarray(rows[:kept, s0 : s0 + m]), yk[n_ch:])
            _horner_compiled(yk, u[c0 : c0 + m], out, s0)
        a = b


def _horner(y: np.ndarray, u: np.ndarray, out: np.ndarray, first: int) -> None:
    """``out[c, first + s] = sum_k y[k n_ch + c, s] u[s]^k`` by Horner, highest ``k`` first.

    ``y`` (n_k n_ch, n) the product's rows (power ``k`` of channel ``c`` in row
    ``k n_ch + c``), ``u`` (n,), ``out`` (n_ch, >= first + n).
    """
    n_ch = out.shape[0]
    n_k = y.shape[0] // n_ch
    n = y.shape[1]
    for c in range(n_ch):
        if n_k == 5:  # the table's default degree, the sum in registers: one pass
            y0 = y[c]
            y1 = y[n_ch + c]
            y2 = y[2 * n_ch + c]
            y3 = y[3 * n_ch + c]
            y4 = y[4 * n_ch + c]
            for s in range(n):
                us = u[s]
                out[c, first + s] = (((y4[s] * us + y3[s]) * us + y2[s]) * us + y1[s]) * us + y0[s]
            continue
        top = y[(n_k - 1) * n_ch + c]
        for s in range(n):
            out[c, first + s] = top[s]
        for k in range(n_k - 2, -1, -1):
            yk = y[k * n_ch + c]
            for s in range(n):
                out[c, first + s] = out[c, first + s] * u[s] + yk[s]


_horner_compiled: Any = None  # _horner compiled, set on block_accel's first call
