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
the *previous* frames instead: the frames one and two cycles (720 deg) earlier,
with the frame itself, give a parabola ``A(u) = a + b u + c u^2`` of every
internally tracked half order (0.5 up to ``correction_max_order``), whose slope
at the window's centre ``b = (3 X_j - 4 X_j' + X_j'') / 2`` is the change across
the window. Whole cycles, because leakage from an odd number of half orders
away flips sign every revolution and cancels only over a whole cycle; the fit
is in crank angle, like the window and ``kappa``, so the frames sit at
``u = 0, -1, -2`` exactly. Then

    X_h <- X_h - sum_h' [ b_h' e^{i (h'-h) c} kappa(2(h'-h)) + conj(b_h') e^{-i (h'+h) c} kappa(-2(h'+h)) ]

(the second term is the negative-frequency half of ``Re{}``). Only orders
inside the internal set are corrected for; what lies outside is estimated by
the frame's ``leakage`` figure. On the simulated i3 bench, 1500 -> 4500 rpm at
50 rpm/s, the worst H1/H1.5/H2 error (a channel whose H1.5 lies 66 dB below
its H1) falls from 2 % to 1.8e-4 (phase 0.006 deg), 5e-4 in the stream's
second cycle, which has one earlier cycle and takes the chord; leaving H3 out
of the internal set (orders up to 2.5) would leave 1.2 %, up to 3 gives
3.1e-4, up to 4 (the default for orders 1, 1.5, 2) 1.8e-4.

Order 0 (the spectrum channel's mean, ``dsp.assemble._spectrum``) takes part as
any half order: as a source its ramp is that of the mean, ``Re{X_0}`` with
``X_0`` the mean itself (the formula's two terms, each half of it, add up to the
``2 b_0 kappa(-2h)`` a real ramp leaks); as a target the raw sum is twice the
mean, so its correction is halved (the plan halves row 0 of the matrices).

Why the parabola: a chord of the previous cycle, ``X_j - X_j'``, is the ramp
half a cycle back; where an amplitude bends (near a rigid-body mode in a quick
sweep: at 60 rpm/s the i3's H1.5 bends by 6-9 % of itself per cycle, second
difference, between 670 and 720 rpm) that lag leaks the bend, 1/(2 pi) of it,
into the neighbours. The parabola's own ``c u^2`` term, though it leaks too (``int w u^2 exp(...)``, a
third of the ramp's coefficient), is not subtracted: fitted from raw frames it
carries the second difference of the neighbours' leaked ramps, of the same
size, and subtracting it made the measured cases worse (the i3's H2 at
600 -> 900 rpm in 5 s: median error 0.63 % with it, 0.24 % without; a
closed-form rpm^8 order at 60 rpm/s: median leak 2.7e-4 with it, 8.8e-5
without). The price of the parabola is noise: the ramp is ``(3, -4, 1) / 2``
of three noisy frames instead of ``(1, -1)`` of two, and at 40 dB SNR the
scatter of ``X`` rises from 1.03-1.11 to 1.18-1.26 of the window's white-noise
prediction. A frame with one earlier cycle only (the second cycle of a stream,
or a re-sync gap that leaves one) falls back to the chord; without any it stays
uncorrected (``leakage_uncorrected``).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from dsp import kernels
from dsp.frames import rise

# The ramp is fitted through the frame and the two newest valid frames one, two or three
# cycles (720 deg) before it (one, if only one is there): a short re-sync gap is bridged.
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
    # kappa depends on the difference alone: evaluated once per distinct value (about 4n of
    # the 2 n^2 entries; tracker set-up 8 -> 1.4 ms). The quadrature's product then has fewer
    # columns, and BLAS may round a column's sum differently: up to 1e-16 absolute on
    # kappas of 0.03-0.16 (the default and realistic runs' results are bit-identical).
    distinct, at = np.unique(np.concatenate([d_same.ravel(), d_image.ravel()]), return_inverse=True)
    kap = kappa(distinct.astype(float), frac)[at]
    kap_same, kap_image = (
        kap[: d_same.size].reshape(d_same.shape),
        kap[d_same.size :].reshape(d_image.shape),
    )
    j = np.arange(period)[:, None, None]
    # e^{i (h'-h) c_j} with c_j = 2 pi j / fpr: (h'-h) c_j = 2 pi d j / (2 fpr), reduced exactly
    same = np.exp(2j * np.pi * ((d_same[None] * j) % period) / period) * kap_same[None]
    image = np.exp(2j * np.pi * ((d_image[None] * j) % period) / period) * kap_image[None]
    np.einsum("jii->ji", same)[:] = 0.0  # an order's own ramp does not bias it (kappa(0) = 0)
    return same, image


_REAL: dict[int, tuple[np.ndarray, np.ndarray, tuple[np.ndarray, int]]] = {}


def real_coupling(same: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, int]:
    """:func:`coupling`'s ``same``, ``image`` (P, n, n) as one real matrix per phase, for
    :func:`dsp.fused_ramps.apply_ramps`: ``corr = same @ b + image @ conj(b)`` is
    ``Re corr = (S_r + I_r) Re b + (I_i - S_i) Im b``, ``Im corr = (S_i + I_i) Re b +
    (S_r - I_r) Im b``. Returned transposed (row ``k`` a source: ``Re b_k``, then ``Im b_k``
    from row ``n``; columns the real parts, then the imaginary parts, zeros up to ``m8``,
    a multiple of 8), flattened (P 2 n m8,), and ``m8``. Made once per pair (a plan's
    arrays, never modified) and kept."""
    hit = _REAL.get(id(same))
    if hit is not None and hit[0] is same and hit[1] is image:
        return hit[2]
    n = same.shape[1]
    m8 = (2 * n + 7) // 8 * 8
    out = np.zeros((same.shape[0], 2 * n, m8))
    sr, si, ir, ii = same.real, same.imag, image.real, image.imag
    out[:, :n, :n] = (sr + ir).transpose(0, 2, 1)
    out[:, :n, n : 2 * n] = (si + ii).transpose(0, 2, 1)
    out[:, n:, :n] = (ii - si).transpose(0, 2, 1)
    out[:, n:, n : 2 * n] = (sr - ir).transpose(0, 2, 1)
    if len(_REAL) > 16:
        _REAL.clear()  # plans come and go in studies: keep a few
    _REAL[id(same)] = (same, image, (out.ravel(), m8))
    return out.ravel(), m8


def ramp_correction(
    history: tuple[np.ndarray, ...],
    js: np.ndarray,
    chains: np.ndarray,
    x: np.ndarray,
    tacho_bad: np.ndarray,
    same: np.ndarray,
    image: np.ndarray,
    frames_per_rev: int,
    enabled: bool,
) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray]:
    """Remove ramp leakage (:mod:`dsp.leakage`); keep raw amplitudes as the next history.

    ``x`` (f, n_int, n_ch) are the raw amplitudes of frames ``js`` (``chains`` their
    parity chains), ``history`` the ``(j, chain, x)`` of the frames before them (empty at
    first), ``same``, ``image`` the coupling of :func:`dsp.leakage.coupling`. Returns the
    new history, the corrected amplitudes and which (frame, channel) were corrected.

    The ramp of frame ``j`` is the slope at ``u = 0`` of the parabola through ``X_j`` and
    the two newest valid frames ``j'``, ``j''`` at the same phase of the 720 deg cycle
    (``j - j'`` a multiple of ``2 fpr``; ``u`` in windows, ``(j' - j) / (2 fpr)``):
    leakage from an odd number of half orders away flips sign from one revolution to
    the next and would pollute a ramp taken across it. With ``j'`` alone it is the
    chord ``(X_j - X_j') * 2 fpr / (j - j')``; with neither the frame is uncorrected.
    """
    fpr = frames_per_rev
    period = 2 * fpr
    look = SLOPE_PERIODS * period
    if history:
        hj, hc, hx = history
    else:
        hj, hc, hx = np.empty(0, np.int64), np.empty(0, np.int64), x[:0]
    all_j = np.concatenate((hj, js))
    all_c = np.concatenate((hc, chains))
    all_x = np.concatenate((hx, x))
    keep = slice(max(all_j.size - look, 0), None)
    history = (all_j[keep], all_c[keep], all_x[keep])
    f, n_ch = js.size, x.shape[2]
    if not enabled:
        return history, x, np.zeros((f, n_ch), bool)

    n_int = x.shape[1]
    if kernels.USE:
        # the ramps and the two coupling products as one real product per frame and
        # channel, in one compiled call (dsp.fused_frames; the coupling: dsp.fused_ramps,
        # not numpy's bits, within 1e-12)
        out = np.empty((f, n_int, n_ch), complex)
        good = np.empty((f, n_ch), bool)
        coupling, m8 = real_coupling(same, image)
        kernels.correct_ramps(
            all_j, all_c, all_x, x, js, chains, tacho_bad, period, SLOPE_PERIODS, coupling, m8,
            out, good,
        )  # fmt: skip
        return history, out, good
    else:
        b, good = _slopes(all_j, all_c, all_x, js, chains, tacho_bad, period)
    phase = js % period
    corr = same[phase] @ b
    corr += image[phase] @ np.conj(b)
    return history, x - corr, good


def _slopes(
    all_j: np.ndarray,
    all_c: np.ndarray,
    all_x: np.ndarray,
    js: np.ndarray,
    chains: np.ndarray,
    tacho_bad: np.ndarray,
    period: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The ramps ``b`` (f, n_int, n_ch) and where they are ``good`` (f, n_ch), in numpy
    (the reference of :func:`dsp.ramp_slopes.ramp_slopes`; arguments as there)."""
    f, n_ch = js.size, all_x.shape[2]
    x = all_x[all_j.size - f :]  # the new frames'
    first = int(all_j[0])
    gapless = int(all_j[-1]) - first == all_j.size - 1  # the rule: no frame skipped

    # frame j -> its position in all_* (increasing), -1 if absent
    def position(want: np.ndarray) -> np.ndarray:
        if gapless:
            pos = want - first
            return np.where((pos >= 0) & (pos < all_j.size), pos, -1)
        pos = np.minimum(np.searchsorted(all_j, want), all_j.size - 1)
        return np.where(all_j[pos] == want, pos, -1)

    base = position(js)
    finite = np.isfinite(all_x).all(axis=1)  # (h + f, n_ch)
    # candidates one, two, three cycles back (k, f, n_ch): the newest usable one gives the
    # ramp, the next older one, where there is one, its bend
    pos = position(js[None, :] - np.arange(1, SLOPE_PERIODS + 1)[:, None] * period)
    at = np.maximum(pos, 0)
    usable = ((pos >= 0) & (all_c[at] == chains[None, :]))[:, :, None] & finite[at]
    rows = np.arange(f)[:, None]
    newest = np.argmax(usable, axis=0)  # (f, n_ch): first usable k, 0 if none
    ref = np.where(usable.any(axis=0), pos[newest, rows], -1)
    older = usable & (np.arange(SLOPE_PERIODS)[:, None, None] > newest[None])
    ref2 = np.where(older.any(axis=0), pos[np.argmax(older, axis=0), rows], -1)
    good = (ref >= 0) & finite[base] & ~tacho_bad[:, None]
    bent = good & (ref2 >= 0)
    refc, ref2c = np.maximum(ref, 0), np.maximum(ref2, 0)
    # all_x[ref[f, c], :, c]: advanced indices first, so (f, n_ch, n_int) -> (f, n_int, n_ch)
    cols = np.arange(n_ch)[None, :]
    x1 = all_x[refc, :, cols].transpose(0, 2, 1)
    x2 = all_x[ref2c, :, cols].transpose(0, 2, 1)
    # how far back, in windows (720 deg): the frames sit at u = 0, -d1, -d2
    d1 = ((js[:, None] - all_j[refc]) / period)[:, None, :]
    d2 = ((js[:, None] - all_j[ref2c]) / period)[:, None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        s1 = (x - x1) / d1  # the slope of the chord, i.e. the ramp half a chord back
        # the parabola through the three frames, A(u) = a + b u + c u^2 (Newton form), has
        # the slope b = s1 + c d1 at the window's centre; with d1 = 1, d2 = 2 it is
        # b = (3 X_j - 4 X_j' + X_j'') / 2
        c = (s1 - (x1 - x2) / (d2 - d1)) / d2
        b = s1 + np.where(bent[:, None, :], c, 0.0) * d1
    return np.where(good[:, None, :], b, 0.0), good  # ramp per 720 deg window
