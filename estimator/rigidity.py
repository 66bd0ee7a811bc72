"""How much of a frame's rigid-fit residual the measured channel noise cannot explain.

The elastic-mode gate (:class:`estimator.gating.OrderGates`) compares each
order's relative rigidity residual with its level in the sweep's first frames.
Noise alone grows that residual along a sweep: an order amplitude averages one
720 deg cycle, so its noise variance grows with rpm, and at 40 dB below the
signal the order noise of the simulated i3 reached the residual limit at
80-95 Hz of H1.5 and confirmed a mode in every seed. So the gate judges only
the part of the residual the noise cannot explain.

The test. With channel noise of variance ``s_c`` per real part (measured along
the sweep from three frames 720 deg apart, :meth:`estimator.channel_noise.
ChannelNoise.variance`, never from the frame's own residual), the weighted
residual sum of squares of a rigid fit is the quadratic form ``r = y^T M y``
of the readings with ``M = I - J_w (J_w^T J_w)^-1 J_w^T`` (weighted), over two
real parts. Its noise part is ``sum_i l_i chi2_2`` with ``l_i`` the eigenvalues
of ``D^1/2 M D^1/2``, ``D = diag(w_c s_c)``. When the weights are the inverse
noise variances every non-zero ``l_i`` is the same and that is exactly
``chi2`` with ``2 (n - 6)`` degrees of freedom (n channels, six complex
unknowns per order; five for a fit that leaves one motion unseen); otherwise
Satterthwaite's ``g chi2_h``, ``g = sum l^2 / sum l``, ``h = 2 (sum l)^2 / sum
l^2``, from two traces, no eigenvalues. The residual beyond that chi-square's
upper ``NOISE_QUANTILE`` point is the excess; a rigid body with noise alone
leaves none in all but one frame in ``1 / (1 - NOISE_QUANTILE)``.

Two scales, because the gate compares a frame with the sweep's first frames:
the baseline must estimate the share the sensor errors leave without bias
(the residual less the noise's *mean*, ``2 sum l``), while a frame is judged
on what is left beyond the *quantile*. A baseline taken beyond the quantile
is biased low where noise and sensor errors are of a size (realistic i3: it
then read the steady sensor-error share at higher rpm as growth and
confirmed a mode at 67 Hz on a rigid body).
"""

from __future__ import annotations

from typing import cast

import numpy as np
from scipy.special import gammainccinv

from estimator import row_kernels
from estimator.compiled_noise import excess_rows, noise_sums
from estimator.kinematics import RigidFit, RigidMotion

# Upper quantile of the noise's chi-square the residual must pass to count at all.
NOISE_QUANTILE = 0.999


def noise_quantile(fit: RigidFit, variance: np.ndarray) -> tuple[float, float, float]:
    """The residual sum of squares noise alone stays below with ``NOISE_QUANTILE``.

    Parameters
    ----------
    fit : the frame's rigid-fit geometry (its weights, its channels).
    variance : (n_ch,) noise variance of the real part of each fitted channel's
        order amplitude, (m/s^2)^2.

    Returns
    -------
    quantile : weighted residual sum of squares, the units of ``fit``'s residual.
    mean : the noise's mean weighted residual sum of squares.
    dof : the effective degrees of freedom ``h`` (``2 (n - rank)`` when the weights
        are the inverse noise variances).
    """
    m = fit.residual_projector
    d = fit.sw**2 * np.asarray(variance, float)
    s1 = float(np.sum(np.diag(m) * d))  # sum l = tr(M D)
    s2 = float(np.sum(m**2 * np.outer(d, d)))  # sum l^2 = tr(M D M D)
    if not (s1 > 0 and s2 > 0):
        return 0.0, 0.0, 0.0
    g, h = s2 / s1, 2.0 * s1**2 / s2  # two real parts: twice the degrees of freedom
    # chi2_h upper point through the incomplete gamma function: the same number as
    # scipy.stats.chi2.ppf, 5 us instead of 70 us per frame
    return g * 2.0 * float(gammainccinv(h / 2.0, 1.0 - NOISE_QUANTILE)), 2.0 * s1, h


def noise_levels(fit: RigidFit, variance: np.ndarray | None) -> tuple[float, float] | None:
    """The noise's (mean, quantile) weighted residual sum of squares of ``fit`` for the
    channel noise ``variance`` (:func:`noise_quantile`); None when the noise is unknown
    (None or NaN for a fitted channel). The same for every frame fitted with ``fit``."""
    if variance is None:
        return None
    var = np.asarray(variance, float)
    if fit.channels is not None:
        var = var[fit.channels]
    if var.shape != fit.sw.shape or not np.all(np.isfinite(var)):
        return None
    q, mean, _ = noise_quantile(fit, var)
    return mean, q


def excess_beyond(
    motion: RigidMotion, fit: RigidFit, levels: tuple[float, float] | None
) -> tuple[np.ndarray, np.ndarray]:
    """(n_orders,) twice: the relative rigidity residual less the noise's mean (the
    share the sensor errors or a mode leave, for the baseline), and beyond the noise's
    quantile (what a frame is judged on); ``levels`` from :func:`noise_levels`.

    ``relative * sqrt(1 - c / r)`` (0 when ``r <= c``), with ``r`` each order's
    weighted residual sum of squares and ``c`` the noise's mean or quantile: on the
    scale of ``motion.relative_residual``, and equal to it when the noise is unknown
    (``levels`` None) or nil.
    """
    rel = np.asarray(motion.relative_residual, float)
    if levels is None:
        return rel, rel
    mean, q = levels
    dof = max(fit.sw.size - fit.rank, 1)
    rss = 2.0 * dof * np.asarray(motion.noise_var, float)  # noise_var = rss / (2 dof)

    def beyond(c: float) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            return rel * np.sqrt(np.where(rss > c, 1.0 - c / rss, 0.0))

    return beyond(mean), beyond(q)


def noise_levels_many(
    fit: RigidFit, variances: list[np.ndarray | None]
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`noise_levels` of the frames fitted with ``fit``, one channel noise
    ``variance`` per frame (frames in a row often share one: each distinct one is
    done once): (n,) means and (n,) quantiles, NaN where the noise is unknown."""
    rows: dict[int, int] = {}  # id of a variance -> its row in ``var``
    var_list: list[np.ndarray] = []
    at: list[int] = []
    ids = {id(v) for v in variances}
    if len(ids) == len(variances) and id(None) not in ids:  # (each frame its own: as is)
        var_list = cast(list[np.ndarray], variances)
    else:
        for j, v in enumerate(variances):
            if v is None:
                continue
            if id(v) not in rows:
                rows[id(v)] = len(var_list)
                var_list.append(v)
            at.append(j)
    if not var_list:
        return np.full(len(variances), np.nan), np.full(len(variances), np.nan)
    var = np.array(var_list, dtype=float)  # (m, n_setup): one gather for all of them
    if fit.channels is not None and var.ndim == 2:
        # (np.take: C-ordered as the rows were; var[:, channels] is laid out by column,
        # and the sums below would take another order)
        var = var.take(fit.channels, axis=1)  # (the method: np.take's wrapper costs more)
    if var.shape[1:] != fit.sw.shape:
        return np.full(len(variances), np.nan), np.full(len(variances), np.nan)
    if row_kernels.USE:  # PTINERTIA_NUMBA=1: the sums in one loop
        mean_all, g, h = noise_sums(var, fit)
        q_all = g * 2.0 * gammainccinv(h / 2.0, 1.0 - NOISE_QUANTILE)  # (NaN: unknown)
        if len(var_list) == len(variances):
            return mean_all, q_all
        mean, q = np.full(len(variances), np.nan), np.full(len(variances), np.nan)
        pick = np.array([rows[id(variances[j])] for j in at])
        mean[at], q[at] = mean_all[pick], q_all[pick]
        return mean, q
    d = fit.sw**2 * var
    m_diag, m_sq = fit.residual_projector_parts
    s1 = np.add.reduce(m_diag * d, axis=1)  # sum l = tr(M D), per frame
    # sum l^2 = tr(M D M D), each summed as one frame's (n_ch, n_ch) array is
    s2 = np.add.reduce((m_sq * (d[:, :, None] * d[:, None, :])).reshape(len(d), -1), axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        g, h = s2 / s1, 2.0 * s1**2 / s2
        some = (s1 > 0) & (s2 > 0)
        q_all = np.where(some, g * 2.0 * gammainccinv(h / 2.0, 1.0 - NOISE_QUANTILE), 0.0)
    mean_all = np.where(some, 2.0 * s1, 0.0)
    known = np.all(np.isfinite(var), axis=1)
    if len(var_list) == len(variances):  # each frame its own, known variance: rows as is
        return np.where(known, mean_all, np.nan), np.where(known, q_all, np.nan)
    mean, q = np.full(len(variances), np.nan), np.full(len(variances), np.nan)
    pick = np.array([rows[id(variances[j])] for j in at])
    mean[at] = np.where(known[pick], mean_all[pick], np.nan)
    q[at] = np.where(known[pick], q_all[pick], np.nan)
    return mean, q


def excess_many(
    relative: np.ndarray, noise_var: np.ndarray, fit: RigidFit, mean: np.ndarray, q: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`excess_beyond` of n frames fitted with ``fit``: their (n, k) relative
    residuals and noise variances, the (n,) noise levels of :func:`noise_levels_many`
    (NaN: unknown, the whole residual)."""
    dof = max(fit.sw.size - fit.rank, 1)
    if row_kernels.USE:  # PTINERTIA_NUMBA=1: in one loop
        return excess_rows(relative, noise_var, dof, mean, q)
    rss = 2.0 * dof * noise_var  # noise_var = rss / (2 dof)
    known = np.isfinite(mean)[:, None]
    # both levels as one (2, n, 1) array: each element's operations as for one level
    c = np.array((mean, q))[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore"):  # (one context: a few us each)
        part = relative * np.sqrt(np.where(rss > c, 1.0 - c / rss, 0.0))
    both = np.where(known, part, relative)
    return both[0], both[1]


def excess_residual(
    motion: RigidMotion, fit: RigidFit, variance: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`excess_beyond` at the noise levels of ``variance`` (one frame)."""
    return excess_beyond(motion, fit, noise_levels(fit, variance))
