"""The compiled synthesis' operands: the rpm dependence of numerically absent orders left out.

:func:`acquisition.sim.synthesis.synthesize_accel` multiplies, per table interval, the
coefficients of ``u^k`` (k = 0 .. degree, every channel) with the carriers of every
half order: 1080 multiply-adds per sample for 12 half orders, 9 channels and degree 4,
half of the compiled path's time. An order the model holds at the rounding level of
its own sum (the i3's orders 0.5, 2.5, 3.5, 5 and 5.5, which its three cylinders
cancel: amplitudes near 1e-13 of the channel's largest) needs no polynomial in rpm:
its ``u^1 .. u^degree`` coefficients are left out, so the ``u^k`` rows (k >= 1) meet
only the carriers of the other orders. What is left out is bounded: the sum over the
dropped orders of ``max |C_k|`` (k >= 1, every interval; ``|u| <= 1``) stays within
:data:`DROP_RTOL` of the channel's largest amplitude, for every channel; so the samples
move by at most that, 1e-14 of the largest amplitude (on the i3 it is 2e-15, and the
samples move by under 5e-15 of each channel's rms with the compiled carriers). An order
that carries anything, an error-made one included, keeps its polynomial.

The carriers' rows are laid out with the kept orders first (their ``cos``, ``sin`` rows
one block that BLAS reads as is), the dropped after.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# the bound on what is left out, relative to each channel's largest amplitude
DROP_RTOL = 1e-14


@dataclass(frozen=True)
class CompactDesign:
    """Matmul operands of the compiled synthesis.

    Attributes
    ----------
    position : (n_o,) int
        Carrier pair of order ``j`` (``h = (j + 1) / 2``) in rows ``2 position[j]``,
        ``2 position[j] + 1``; the kept orders take positions ``0 .. n_kept - 1``.
    n_kept : int
        Orders whose rpm dependence is kept.
    constant : list of (n_int, n_ch, 2 n_o) float
        Per segment, the ``u^0`` rows against every carrier row (that layout).
    varying : list of (n_int, degree n_ch, 2 n_kept) float
        Per segment, the ``u^1 .. u^degree`` rows (row ``(k - 1) n_ch + c``) against the
        kept orders' carrier rows; zero rows at a hold.
    dropped_bound : float
        The bound on what is left out, relative to each channel's largest amplitude.
    """

    position: np.ndarray
    n_kept: int
    constant: list[np.ndarray]
    varying: list[np.ndarray]
    dropped_bound: float


def compact_design(coeffs: list[np.ndarray], real_coeffs: list[np.ndarray]) -> CompactDesign:
    """The operands of an amplitude table (its ``coeffs`` and ``real_coeffs``, see
    :class:`~acquisition.sim.amplitude_table.AmplitudeTable`): kept orders first, the
    others' rpm dependence dropped while their bound stays within :data:`DROP_RTOL`."""
    n_o = coeffs[0].shape[2]
    largest = np.zeros(coeffs[0].shape[3])  # (n_ch,) each channel's largest amplitude
    bound = np.zeros((n_o, largest.size))  # max over intervals of sum_k>=1 |C_k| per order
    for c in coeffs:
        largest = np.maximum(largest, np.abs(c[:, 0]).max(axis=(0, 1)))
        if c.shape[1] > 1:
            bound = np.maximum(bound, np.abs(c[:, 1:]).sum(axis=1).max(axis=0))
    share = bound / np.where(largest > 0, largest, np.inf)  # (n_o, n_ch)
    dropped: list[int] = []
    total = np.zeros(largest.size)
    for j in np.argsort(share.max(axis=1), kind="stable"):
        if np.any(total + share[j] > DROP_RTOL):
            break
        total += share[j]
        dropped.append(int(j))
    kept = [j for j in range(n_o) if j not in dropped]
    position = np.empty(n_o, dtype=np.intp)
    position[kept + dropped] = np.arange(n_o)
    # carrier row of each column of the table's real design (interleaved cos, sin per order)
    rows = np.empty(2 * n_o, dtype=np.intp)
    rows[0::2] = 2 * position
    rows[1::2] = 2 * position + 1
    n_ch = largest.size
    constant, varying = [], []
    for d in real_coeffs:  # (n_int, n_k n_ch, 2 n_o), columns per order
        permuted = np.empty_like(d)
        permuted[:, :, rows] = d
        constant.append(np.ascontiguousarray(permuted[:, :n_ch]))
        varying.append(np.ascontiguousarray(permuted[:, n_ch:, : 2 * len(kept)]))
    return CompactDesign(position, len(kept), constant, varying, float(total.max(initial=0.0)))
