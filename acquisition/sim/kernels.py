"""Compiled per-sample work of the simulated bench: the order carriers and the Horner sum.

:func:`acquisition.sim.synthesis.synthesize_accel` spends, per sample, a complex ``exp``
for the base carrier ``exp(i phi / 2)``, a strided complex product per half order for
its powers, a BLAS product of the table's coefficients with those carriers, and a
Horner pass over the product's rows in the table's normalised rpm ``u``. The product
is BLAS's best and stays; the rest is a dozen numpy passes over the samples. Compiled
here:

* :func:`carriers`: the base carrier from an exact one at an anchor sample every
  ``spacing`` samples (``cos``, ``sin`` of the anchor's half angle) times
  ``exp(i d)``, ``d`` the half angle travelled since the anchor (``|d| <= 1/4`` rad by
  the choice of ``spacing``), by its Taylor series to ``d^15`` (truncation below
  ``1e-19``); then its powers by the running complex product, one row per half order
  (``cos h phi``, ``sin h phi`` rows: the layout BLAS reads as is). Anchors sit at
  absolute sample indices (multiples of ``spacing``), so a sample's carriers depend on
  its index only, never on the block it falls in.
* :func:`horner`: the rows of the product summed in ``u`` per channel, sample
  loops innermost (vectorised), the arithmetic of the numpy path's in-place Horner.

What moves: numpy's ``exp`` rounds its own way; the anchored carriers agree with it to
a few units in the last place (measured under 1e-14 absolute on the twelve half
orders' cos and sin, ``tests/acquisition/sim/test_kernels.py`` checks 1e-13), so the
samples move at the rounding level, 1e-14 of the channel's rms. The Horner kernel is
the numpy path's arithmetic, operation for operation (numba contracts no ``a * b + c``
into a fused multiply-add unless asked to).

As :mod:`dsp.kernels`, numba is optional and imported on first use only (its import and
the cached machine code cost about 0.5 s of CPU per process), and used only when asked
(``PTINERTIA_NUMBA=1``, the same switch: long runs, campaigns and studies).
"""

from __future__ import annotations

import importlib.util
import math
import os
from collections.abc import Callable

import numpy as np

# numba is optional and imported on first use only, as in dsp.kernels
AVAILABLE = importlib.util.find_spec("numba") is not None
# PTINERTIA_NUMBA=1: the simulator uses the kernels; benchmarks and tests switch it per call
USE = AVAILABLE and os.environ.get("PTINERTIA_NUMBA", "0") == "1"
# largest half angle (rad) from an anchor: the Taylor series below is exact to 1e-19 there
MAX_HALF_ANGLE = 0.25
_compiled: dict[str, Callable[..., None]] = {}


def _jit(name: str, func: Callable[..., None]) -> Callable[..., None]:
    if name not in _compiled:
        from numba import njit  # heavy (0.3 s): only where the kernels are used

        _compiled[name] = njit(cache=True, nogil=True)(func)
    return _compiled[name]


def anchor_spacing(omega_max_rad_s: float, rate_hz: float, longest: int = 64) -> int:
    """Samples between anchors: the half angle travelled stays within ``MAX_HALF_ANGLE``."""
    per_sample = 0.5 * omega_max_rad_s / rate_hz  # rad of half angle per sample
    return max(1, min(longest, math.floor(MAX_HALF_ANGLE / per_sample)))


def carriers(
    phi: np.ndarray, anchor_phi: np.ndarray, offset: int, spacing: int, out: np.ndarray
) -> None:
    """:func:`_carriers` then :func:`_powers`, compiled on the first call (numba's cache keeps the machine code)."""
    _jit("carriers", _carriers)(phi, anchor_phi, offset, spacing, out)
    _jit("powers", _powers)(out)


def horner(y: np.ndarray, u: np.ndarray, out: np.ndarray, first: int) -> None:
    """:func:`_horner` compiled (on the first call)."""
    _jit("horner", _horner)(y, u, out, first)


def _carriers(
    phi: np.ndarray, anchor_phi: np.ndarray, offset: int, spacing: int, out: np.ndarray
) -> None:
    """Rows 0, 1 of ``out`` (2 n_o, n): ``cos(phi / 2)``, ``sin(phi / 2)``.

    ``phi`` (n,) rad the samples' crank angles; sample ``s`` takes anchor
    ``(offset + s) // spacing`` of ``anchor_phi`` (rad), whose half angle must lie
    within ``MAX_HALF_ANGLE`` of the sample's.
    """
    n = phi.size
    # the anchors' exact carriers first, then every sample from its anchor in one flat loop
    m = anchor_phi.size
    ac = np.empty(m)
    asn = np.empty(m)
    for j in range(m):
        ac[j] = math.cos(0.5 * anchor_phi[j])
        asn[j] = math.sin(0.5 * anchor_phi[j])
    for s in range(n):
        j = (offset + s) // spacing
        d = 0.5 * (phi[s] - anchor_phi[j])
        d2 = d * d
        # Taylor series of cos d and sin d to d^14 and d^15 (|d| <= 1/4: the rest < 1e-19)
        c = 1.0 + d2 * (-1.0 / 2 + d2 * (1.0 / 24 + d2 * (-1.0 / 720 + d2 * (
            1.0 / 40320 + d2 * (-1.0 / 3628800 + d2 * (1.0 / 479001600 + d2 * (
                -1.0 / 87178291200)))))))  # fmt: skip
        sn = d * (1.0 + d2 * (-1.0 / 6 + d2 * (1.0 / 120 + d2 * (-1.0 / 5040 + d2 * (
            1.0 / 362880 + d2 * (-1.0 / 39916800 + d2 * (1.0 / 6227020800 + d2 * (
                -1.0 / 1307674368000))))))))  # fmt: skip
        out[0, s] = ac[j] * c - asn[j] * sn
        out[1, s] = ac[j] * sn + asn[j] * c


def _powers(out: np.ndarray) -> None:
    """Rows ``2 k``, ``2 k + 1`` of ``out`` (2 n_o, n) the carrier of rows 0, 1 to the ``k + 1``.

    A row at a time, by the running product (contiguous; indexing the one array, not row
    views of it, and a kernel of its own let LLVM vectorise: measured 2.7x faster).
    """
    n_o = out.shape[0] // 2
    n = out.shape[1]
    for k in range(1, n_o):
        for s in range(n):
            # every load before the stores (else each store forces a reload)
            pr = out[2 * k - 2, s]
            pi = out[2 * k - 1, s]
            br = out[0, s]
            bi = out[1, s]
            out[2 * k, s] = pr * br - pi * bi
            out[2 * k + 1, s] = pr * bi + pi * br


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
