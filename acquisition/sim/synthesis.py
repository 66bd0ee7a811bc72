"""Pure synthesis of the simulated accelerations from the amplitude table.

``x_c(t) = sum_h Re{X_hc(rpm(t)) exp(i h phi(t))}`` over the half orders
``0.5 .. max_order``, ``phi`` and ``rpm`` from the :class:`~acquisition.sim.sweep.RpmProfile`,
``X`` from the :class:`~acquisition.sim.amplitude_table.AmplitudeTable` (m/s^2). A
sample's value depends only on its time, never on the block it belongs to.

Two paths: numpy (the default) and, with ``PTINERTIA_NUMBA=1``, the compiled kernels of
:mod:`acquisition.sim.kernels` with :mod:`acquisition.sim.compact_design`'s operands,
whose samples agree with numpy's at the rounding level (under 5e-15 of each channel's
rms on the i3; runs' results identical, the pipeline rounding samples to float32).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from acquisition.sim import kernels
from acquisition.sim.amplitude_table import AmplitudeTable
from acquisition.sim.block_kernels import CHUNK, segments_accel
from acquisition.sim.sweep import RpmProfile


def half_orders(max_order: float) -> np.ndarray:
    """``0.5, 1.0, ..., max_order`` (the half orders of a four-stroke engine)."""
    return np.arange(1, math.floor(2 * max_order + 1e-9) + 1) / 2.0


def order_basis(phi: np.ndarray, n_orders: int) -> np.ndarray:
    """Columns ``cos(h phi), sin(h phi)`` interleaved, ``h = 0.5 .. n_orders / 2``: (n, 2 n_orders).

    It is the float view of ``exp(i h phi)`` laid out (n, n_orders): no copy,
    and its transpose goes to BLAS as is (measured 3x faster than stacking the
    real and imaginary parts into rows).
    """
    z = np.exp(0.5j * np.asarray(phi, dtype=float))
    e = np.empty((z.size, n_orders), dtype=complex)
    e[:, 0] = z
    # powers by repeated products: 24 products lose < 1e-14, far cheaper than 24 complex exps
    for k in range(1, n_orders):
        np.multiply(e[:, k - 1], z, out=e[:, k])
    return e.view(np.float64)


def synthesize_accel(
    table: AmplitudeTable,
    profile: RpmProfile,
    t: np.ndarray,
    motion: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    anchors: tuple[np.ndarray, int, int] | None = None,
    compiled: bool | None = None,
) -> np.ndarray:
    """Noise-free accelerations at times ``t`` (s, increasing): (n_ch, n) float, m/s^2.

    The pure function behind :class:`SimulatedBench`; a sample's value depends
    only on its time, never on the block it belongs to. ``motion``: ``profile.evaluate(t)``
    when the caller has it already (the pressure channel needs the same angles).
    ``compiled``: the carriers and the Horner sum by :mod:`acquisition.sim.kernels`
    (default :data:`kernels.USE`), with the carriers' exact phases taken at ``anchors``
    ``(anchor_phi, offset, spacing)`` (see :func:`kernels.carriers`; default: every
    sample its own anchor).
    """
    t = np.asarray(t, dtype=float)
    seg, phi, omega = profile.evaluate(t) if motion is None else motion
    rpm = omega * (60.0 / (2.0 * math.pi))
    compiled = kernels.USE if compiled is None else compiled
    n_o = table.orders.size
    if compiled:
        # the orders with an rpm dependence first: u^0 rows against every carrier, u^1..
        # against the kept orders' only, every interval and chunk of a segment in one call
        # that holds no GIL
        rows = np.empty((2 * n_o, t.size))  # (2 n_o, n): cos, sin rows as BLAS reads them
        kernels.carriers(phi, *(anchors or (phi, 0, 1)), table.compact.position, rows)
        return segments_accel(table, np.asarray(seg), rpm, rows)
    rows = order_basis(phi, n_o).T  # a view of the sample-major carriers
    n_ch = table.coeffs[0].shape[3]
    out = np.empty((n_ch, t.size))
    if t.size == 0:
        return out
    # runs of samples in one segment and one table interval (seg is non-decreasing)
    seg_cuts = [0, *(np.flatnonzero(seg[1:] != seg[:-1]) + 1).tolist(), t.size]
    for a0, b0 in itertools.pairwise(seg_cuts):
        s = int(seg[a0])
        j, u = table.locate(s, rpm[a0:b0])
        cuts = [0, *(np.flatnonzero(j[1:] != j[:-1]) + 1).tolist(), b0 - a0]
        coeffs = table.real_coeffs[s]
        for a, b in itertools.pairwise(cuts):
            d = coeffs[j[a]]
            for c0 in range(a, b, CHUNK):
                c1 = min(b, c0 + CHUNK)
                y = (d @ rows[:, a0 + c0 : a0 + c1]).reshape(-1, n_ch, c1 - c0)
                acc = y[-1]
                if y.shape[0] > 1:
                    uu = u[c0:c1]
                    for k in range(y.shape[0] - 2, -1, -1):  # Horner in u, in place
                        acc *= uu
                        acc += y[k]
                out[:, a0 + c0 : a0 + c1] = acc
    return out
