"""Sensor self-calibration from what the rigid-body fit leaves over.

Nine channels measure a six-DOF rigid motion: three readings per order per
frame are redundant. Small sensor errors p (relative gains, orientation,
position of each sensor) change the readings by ``D p`` (``D`` from
:func:`estimator.streaming.channel_derivatives`); the rigid fit absorbs the
part of ``D p`` that looks like a rigid motion and leaves

    r = (1 - J G) D p + noise

in its residual (J: rigid design matrix, G: the fit's gain). Over a sweep the
motions change with order and rpm, so ``(1 - J G) D`` changes too and the
errors become observable, except those that mimic a rigid motion for every
frame (a common translation, rotation or gain of all sensors). We accumulate
the normal equations of ``p`` with the declared tolerances as a Gaussian
prior: the estimate is ``p = (A + T^-1)^-1 b``. Unobservable directions stay
at zero with their prior variance, so they still widen the intervals.

The estimator then corrects its parameters to first order,
``theta -= (d theta / d p) p``, and uses the posterior covariance of p
instead of the prior for the type-B part of the intervals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CalibrationState:
    """Normal equations of the sensor errors: ``info`` (n_sys, n_sys), ``vec`` (n_sys,),
    weighted residual sum of squares ``rr`` and residual degrees of freedom ``dof``."""

    info: np.ndarray
    vec: np.ndarray
    rr: float = 0.0
    dof: float = 0.0


def calibration_init(n_sys: int) -> CalibrationState:
    return CalibrationState(info=np.zeros((n_sys, n_sys)), vec=np.zeros(n_sys))


def calibration_update(
    state: CalibrationState,
    residual: np.ndarray,
    projector: np.ndarray,
    derivs: np.ndarray,
    weights: np.ndarray,
) -> CalibrationState:
    """Add the rigid-fit residuals of some orders of one frame.

    Parameters
    ----------
    residual : (k, u) complex
        Readings minus the fitted rigid motion, per order, used channels.
    projector : (u, u) float
        ``1 - J G``: what the rigid fit leaves of any reading vector.
    derivs : (k, u, n_sys) complex
        ``d reading / d p`` per order.
    weights : (k, u) float
        Inverse noise variance of each reading (real and imaginary part each).
    """
    m = np.einsum("uv,kvs->kus", projector, derivs)  # (k, u, s)
    mw = m * weights[:, :, None]
    # Real-valued normal equations of complex rows: Re(M^H W M), Re(M^H W r)
    info = state.info + np.einsum("kus,kut->st", mw.conj(), m).real
    vec = state.vec + np.einsum("kus,ku->s", mw.conj(), residual).real
    rr = state.rr + float(np.sum(weights * np.abs(residual) ** 2))
    dof = state.dof + 2.0 * residual.size
    return CalibrationState(info=info, vec=vec, rr=rr, dof=dof)


@dataclass(frozen=True)
class CalibrationSolution:
    """Estimated sensor errors ``p`` and their posterior covariance."""

    p: np.ndarray
    cov: np.ndarray
    variance_factor: float


def calibration_solve(state: CalibrationState, prior_std: np.ndarray) -> CalibrationSolution:
    """Posterior mean and covariance of the sensor errors with a zero-mean prior ``prior_std``.

    Solved in prior-scaled coordinates ``q = p / prior_std`` through an
    eigen-decomposition: the data information can exceed the prior by twelve
    orders of magnitude on some directions and be zero on others, which a
    plain solve of ``A + T^-1`` would not survive.
    """
    t = np.maximum(np.asarray(prior_std, float), 1e-300)
    a = state.info * np.outer(t, t)
    b = state.vec * t
    evals, evecs = np.linalg.eigh(0.5 * (a + a.T))
    evals = np.maximum(evals, 0.0)

    def posterior(scale: float) -> tuple[np.ndarray, np.ndarray]:
        inv = (evecs / (evals / scale + 1.0)) @ evecs.T
        return inv @ (b / scale), inv

    q, _ = posterior(1.0)
    p = q * t
    rss = max(state.rr - 2 * float(p @ state.vec) + float(p @ state.info @ p), 0.0)
    dof = max(state.dof - len(t), 1.0)
    # Data information scaled down by the misfit (model error beyond the noise
    # makes the data less informative, never more).
    factor = max(1.0, rss / dof)
    q, inv = posterior(factor)
    cov = inv * np.outer(t, t)
    return CalibrationSolution(p=q * t, cov=0.5 * (cov + cov.T), variance_factor=factor)
