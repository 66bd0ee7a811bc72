"""The compiled arithmetic of the channel noise and the rigidity gate's noise levels
(``PTINERTIA_NUMBA=1``): :func:`noise_medians` and :func:`window_means`
(:mod:`estimator.channel_noise`), :func:`noise_sums` and :func:`excess_rows`
(:mod:`estimator.rigidity`), each one loop where numpy makes ten to thirty calls. Why,
what it gains and how close it stays to the numpy reference: :mod:`estimator.compiled_runs`.
"""

from __future__ import annotations

import numpy as np

from estimator.kinematics import RigidFit
from estimator.row_kernels import jit


def noise_sums(
    var: np.ndarray, fit: RigidFit, compiled: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`estimator.rigidity.noise_levels_many`' arithmetic before the chi-square
    quantile, for m channel noise variances ``var`` (m, n_ch) of ``fit``'s channels:
    (m,) the noise's mean weighted residual sum of squares ``2 sum l``, Satterthwaite's
    scale ``g`` and degrees of freedom ``h``; NaN where a variance is not finite, and
    ``g`` 0 (``h`` 2) where ``sum l`` or ``sum l^2`` is not positive."""
    m_diag, m_sq = fit.residual_projector_parts
    out = np.empty((3, len(var)))
    (jit(noise_rows) if compiled else noise_rows)(
        np.ascontiguousarray(var, float), np.ascontiguousarray(fit.sw, float), m_diag, m_sq, out
    )
    return out[0], out[1], out[2]


def noise_rows(
    var: np.ndarray, sw: np.ndarray, m_diag: np.ndarray, m_sq: np.ndarray, out: np.ndarray
) -> None:
    """:func:`noise_sums`' loop."""
    m, n = var.shape
    d = np.empty(n)
    for j in range(m):
        known = True
        for c in range(n):
            d[c] = sw[c] ** 2 * var[j, c]
            known = known and np.isfinite(var[j, c])
        s1 = 0.0
        s2 = 0.0
        for a in range(n):
            s1 += m_diag[a] * d[a]
            for b in range(n):
                s2 += m_sq[a, b] * (d[a] * d[b])
        if not known:
            out[0, j] = np.nan
            out[1, j] = np.nan
            out[2, j] = np.nan
        elif s1 > 0 and s2 > 0:
            out[0, j] = 2.0 * s1
            out[1, j] = s2 / s1
            out[2, j] = 2.0 * s1**2 / s2
        else:
            out[0, j] = 0.0
            out[1, j] = 0.0
            out[2, j] = 2.0


def excess_rows(
    relative: np.ndarray,
    noise_var: np.ndarray,
    dof: int,
    mean: np.ndarray,
    q: np.ndarray,
    compiled: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`estimator.rigidity.excess_many`' arithmetic: (n, k) the relative residuals
    less the noise's ``mean`` and beyond its quantile ``q`` ((n,) each, NaN: unknown)."""
    out = np.empty((2, *relative.shape))
    (jit(excess_pairs) if compiled else excess_pairs)(
        np.ascontiguousarray(relative, float),
        np.ascontiguousarray(noise_var, float),
        float(dof),
        np.asarray(mean, float),
        np.asarray(q, float),
        out,
    )
    return out[0], out[1]


def excess_pairs(
    relative: np.ndarray,
    noise_var: np.ndarray,
    dof: float,
    mean: np.ndarray,
    q: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`excess_rows`' loop."""
    n_f, n_o = relative.shape
    for f in range(n_f):
        known = np.isfinite(mean[f])
        for o in range(n_o):
            rel = relative[f, o]
            rss = 2.0 * dof * noise_var[f, o]
            for i in range(2):
                c = mean[f] if i == 0 else q[f]
                if not known:
                    out[i, f, o] = rel
                elif rss > c:
                    out[i, f, o] = rel * np.sqrt(1.0 - c / rss)
                else:
                    out[i, f, o] = rel * 0.0


def noise_medians(triples: np.ndarray, compiled: bool = True) -> np.ndarray:
    """:class:`estimator.channel_noise.ChannelNoise`'s per-frame estimates before their
    bias: (m, n_ch) the median over the orders of ``|x - 2 x1 + x0|^2 / 12`` of m frames'
    (k, n_ch) complex amplitudes ``x`` and the two 720 deg before each, ``triples``
    (m, 3, k, n_ch) [x, x1, x0]; NaN where one order is (numpy's median: the mean of the
    middle pair for even k). The same operations as the numpy path
    (:func:`estimator.channel_noise.median_of_orders`): the same bits."""
    out = np.empty((triples.shape[0], triples.shape[3]))
    (jit(median_rows) if compiled else median_rows)(np.ascontiguousarray(triples, complex), out)
    return out


def median_rows(triples: np.ndarray, out: np.ndarray) -> None:
    """:func:`noise_medians`' loop (an insertion sort of the k orders)."""
    m, _, k, n = triples.shape
    v = np.empty(k)
    for f in range(m):
        for c in range(n):
            nan = False
            for o in range(k):
                d = triples[f, 0, o, c] - 2 * triples[f, 1, o, c] + triples[f, 2, o, c]
                e = (d.real**2 + d.imag**2) / 12.0
                nan = nan or np.isnan(e)
                j = o
                while j > 0 and v[j - 1] > e:
                    v[j] = v[j - 1]
                    j -= 1
                v[j] = e
            if nan:
                out[f, c] = np.nan
            elif k % 2:
                out[f, c] = v[k // 2]
            else:
                out[f, c] = (v[k // 2 - 1] + v[k // 2]) / 2


def window_means(stack: np.ndarray, length: int, compiled: bool = True) -> np.ndarray:
    """:func:`estimator.channel_noise._window_variances`: the mean of each run of
    ``length`` consecutive rows of ``stack`` (m, n_ch), summed in stream order, NaN for
    a channel not finite in one of them; the same bits."""
    out = np.empty((stack.shape[0] - length + 1, stack.shape[1]))
    (jit(window_rows) if compiled else window_rows)(np.ascontiguousarray(stack, float), length, out)
    return out


def window_rows(stack: np.ndarray, length: int, out: np.ndarray) -> None:
    """:func:`window_means`' loop."""
    for w in range(out.shape[0]):
        for c in range(stack.shape[1]):
            total = stack[w, c] + stack[w + 1, c]
            finite = np.isfinite(stack[w, c]) and np.isfinite(stack[w + 1, c])
            for j in range(2, length):
                total = total + stack[w + j, c]
                finite = finite and np.isfinite(stack[w + j, c])
            out[w, c] = total / length if finite else np.nan
