"""Correction of the leakage a speed sweep causes between neighbouring half orders.

Within one 720 deg window the half orders are exactly orthogonal only if their
amplitudes are constant. In a sweep an order's amplitude drifts across the
window, ``A(u) = a + b u`` with ``u = (phi - c) / 720 deg`` in [-1/2, 1/2], and the
ramp ``b`` leaks into order ``h`` with the coefficient

    kappa(m) = int w(u) u exp(i 2 pi m u) du / int w(u) du,    m = 2 (h' - h),

about ``-i (-1)^m / (2 pi m)``: 0.16 of the ramp into each adjacent half order.
At 50 rpm/s and 1500 rpm an rpm^2 amplitude ramps by 0.5 % across the window,
so a neighbour three times larger shifts ``h`` by ~0.25 %, more than the
0.1 % an inertia estimate can afford. Resolving the ramp inside one cycle is
impossible (0.5 order is the Rayleigh limit of a 720 deg window) and a longer
window would break the two-revolution latency, so the ramps are taken from
the *previous* frames instead: the change of every internally tracked half
order (0.5 up to ``correction_max_order``) since the frame one cycle (720 deg)
earlier gives ``b`` (one cycle, because leakage from an odd number of half
orders away flips sign every revolution and cancels only over a whole cycle), and

    X_h <- X_h - sum_h' [ b_h' e^{i (h'-h) c} kappa(2(h'-h)) + conj(b_h') e^{-i (h'+h) c} kappa(-2(h'+h)) ]

(the second term is the negative-frequency half of ``Re{}``). Only orders
inside the internal set are corrected for; what lies outside is estimated by
the frame's ``leakage`` figure. On the simulated i3 bench, 1500 -> 4500 rpm at
50 rpm/s, the worst H1/H1.5/H2 error (a channel whose H1.5 lies 66 dB below
its H1) falls from 2 % to 5e-4; leaving H3 out of the internal set (orders up
to 2.5) would leave 1.2 %, up to 3 gives 5.8e-4, up to 4 (the default for
orders 1, 1.5, 2) 5.1e-4. The ramp of the previous cycle lags by one cycle:
the residual grows as rate^2 / rpm^3 (see :mod:`dsp.orders` for the limits).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from dsp.frames import rise

# The ramp is taken between the frame and the newest valid frame one, two or three
# cycles (720 deg) before it: a short re-sync gap is bridged.
SLOPE_PERIODS = 3


@functools.cache
def _gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of ``n``-point Gauss-Legendre, computed once per process.

    ``leggauss(200)`` solves a 200 x 200 eigenproblem: 60 ms at every tracker set-up,
    as long as tracking ten seconds of 25.6 kHz stream.
    """
    x, w = np.polynomial.legendre.leggauss(n)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def kappa(m: np.ndarray, taper_frac: float) -> np.ndarray:
    """``kappa(m)`` of the tapered cycle window, ``taper_frac = taper / 720 deg``.

    Gauss-Legendre on the rising taper, the flat part and the falling taper
    separately (each piece is smooth), exact to rounding.
    """
    m = np.asarray(m, dtype=float)
    flat_m = m.ravel()
    x, wq = _gauss_legendre(200)
    half = 0.5 * taper_frac
    pieces = [(-0.5 - half, -0.5 + half), (-0.5 + half, 0.5 - half), (0.5 - half, 0.5 + half)]
    num = np.zeros(flat_m.shape, complex)
    den = 0.0
    for k, (a, b) in enumerate(pieces):
        u = 0.5 * (b - a) * x + 0.5 * (a + b)
        wu = wq * 0.5 * (b - a)
        if k == 0:
            win = rise((u - a) / taper_frac)
        elif k == 2:
            win = 1.0 - rise((u - a) / taper_frac)
        else:
            win = np.ones_like(u)
        num += (wu * win * u) @ np.exp(2j * np.pi * np.outer(u, flat_m))
        den += float(np.sum(wu * win))
    return (num / den).reshape(m.shape)


def coupling(
    k2: np.ndarray, frames_per_rev: int, taper_deg: float
) -> tuple[np.ndarray, np.ndarray]:
    """Leakage matrices for every frame phase ``j mod (2 frames_per_rev)``.

    Returns
    -------
    same, image : (2 frames_per_rev, n, n) complex
        ``corr = same[j % P] @ b + image[j % P] @ conj(b)`` for ramps ``b`` (n, n_ch)
        of the half orders ``k2 / 2``.
    """
    period = 2 * frames_per_rev
    frac = math.radians(taper_deg) / (4.0 * math.pi)
    k = np.asarray(k2, dtype=np.int64)
    d_same = k[None, :] - k[:, None]  # 2 (h' - h), rows h, columns h'
    d_image = -(k[None, :] + k[:, None])  # 2 (-h' - h)
    kap_same = kappa(d_same.astype(float), frac)
    kap_image = kappa(d_image.astype(float), frac)
    j = np.arange(period)[:, None, None]
    # e^{i (h'-h) c_j} with c_j = 2 pi j / fpr: (h'-h) c_j = 2 pi d j / (2 fpr), reduced exactly
    same = np.exp(2j * np.pi * ((d_same[None] * j) % period) / period) * kap_same[None]
    image = np.exp(2j * np.pi * ((d_image[None] * j) % period) / period) * kap_image[None]
    np.einsum("jii->ji", same)[:] = 0.0  # an order's own ramp does not bias it (kappa(0) = 0)
    return same, image
