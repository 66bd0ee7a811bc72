"""Recursive weighted least squares in information form, with forgetting.

The estimator stacks, frame by frame, real-valued rows ``y = H theta + e`` with
weights ``w = 1 / var(e)``. We carry the information matrix and vector

    Lambda_k = lam * Lambda_{k-1} + H^T W H
    eta_k    = lam * eta_{k-1}    + H^T W y
    theta_k  = Lambda_k^-1 eta_k,       P_k = Lambda_k^-1

rather than the textbook covariance form ``K = P H^T (lam W^-1 + H P H^T)^-1``.
Why: the covariance form needs a diffuse prior ``P_0 = big * 1`` whose bias
and round-off never fully vanish, while the information form starts from
``Lambda_0 = 0`` exactly, so with ``lam = 1`` it *is* the batch solution
(test: agreement to 1e-9), and a parameter that no row has excited yet shows
up as a null direction of ``Lambda`` instead of as a huge, meaningless number.
The solve is a symmetric eigen-decomposition of a matrix of the size of theta
(about 15): microseconds.

:func:`rls_update` and :func:`rls_solve` are the pure-function reference;
:class:`RecursiveLeastSquares` is a thin stateful wrapper around them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RlsState:
    """Information-form state.

    Attributes
    ----------
    info : (n, n) float
        Information matrix ``Lambda = sum lam^(k-j) H_j^T W_j H_j``.
    vec : (n,) float
        Information vector ``eta = sum lam^(k-j) H_j^T W_j y_j``.
    yty : float
        Weighted sum of squared observations (for the residual sum of squares).
    rows : float
        Effective number of rows (discounted by the forgetting factor).
    """

    info: np.ndarray
    vec: np.ndarray
    yty: float = 0.0
    rows: float = 0.0


def rls_init(n: int) -> RlsState:
    """An empty state for ``n`` parameters: no information at all."""
    return RlsState(info=np.zeros((n, n)), vec=np.zeros(n))


def rls_update(
    state: RlsState, H: np.ndarray, y: np.ndarray, w: np.ndarray | None = None, lam: float = 1.0
) -> RlsState:
    """Add rows ``y = H theta`` with weights ``w`` after discounting the past by ``lam``.

    Parameters
    ----------
    H : (m, n) float
    y : (m,) float
    w : (m,) float, optional
        Row weights (inverse variances); default 1.
    lam : float
        Forgetting factor in (0, 1]; 1 keeps every frame.
    """
    H = np.atleast_2d(np.asarray(H, dtype=float))
    y = np.asarray(y, dtype=float).reshape(-1)
    w = np.ones(len(y)) if w is None else np.asarray(w, dtype=float).reshape(-1)
    hw = H.T * w  # (n, m)
    # Lambda <- lam Lambda + H^T W H ;  eta <- lam eta + H^T W y
    return RlsState(
        info=lam * state.info + hw @ H,
        vec=lam * state.vec + hw @ y,
        yty=lam * state.yty + float(np.sum(w * y * y)),
        rows=lam * state.rows + len(y),
    )


@dataclass(frozen=True)
class RlsSolution:
    """Estimate from an information state.

    ``theta`` and ``cov`` are computed on the observable subspace only;
    ``observable[i]`` is False for a parameter with (numerically) no
    information, whose value is then 0 and whose variance is ``inf``.
    """

    theta: np.ndarray
    cov: np.ndarray
    observable: np.ndarray
    rss: float
    dof: float


def rls_solve(
    state: RlsState,
    rcond: float = 1e-10,
    scale: np.ndarray | None = None,
    anchored: tuple[int, ...] | list[int] = (),
) -> RlsSolution:
    """``theta = Lambda^-1 eta`` on the observable subspace.

    Parameters
    ----------
    scale : (n,) float, optional
        Typical magnitude of each parameter. The rank decision is made on the
        information matrix of the scaled parameters ``theta / scale`` so that
        parameters of very different units (kg m^2 vs kg m) are compared fairly.
    anchored : indices, optional
        Parameters whose information includes a prior (sensor calibrations with
        their declared tolerance): never discarded. The rank decision for the
        others is made on the rows' information about them alone. Why: with a
        clean sensor the rows' information is 1e12 times a prior's, and a
        relative threshold on the joint matrix would throw the prior-held
        directions away together with the parameters they couple to.
    """
    n = state.vec.size
    s = np.ones(n) if scale is None else np.asarray(scale, dtype=float)
    ss = s[:, None] * s[None, :]  # np.outer's product, without its wrapper
    info = state.info * ss
    vec = state.vec * s
    if len(anchored):
        inv, observable, kept = _anchored_inverse(info, np.asarray(anchored, int), rcond)
    else:
        evals, evecs, keep, observable, _ = rank_decision(info, rcond)
        if n and keep[0]:
            # every direction kept (evals ascend; the common case once the sweep is in):
            # the arrays ``evecs[:, keep]`` would copy, as they are (C order, the same bits)
            e = np.ascontiguousarray(evecs)
            inv = (e / evals) @ e.T
            kept = n
        else:
            inv = (evecs[:, keep] / evals[keep]) @ evecs[:, keep].T
            kept = int(np.count_nonzero(keep))
    theta_s = inv @ vec
    theta = theta_s * s
    cov = inv * ss
    if not observable.all():  # (all observable, the common case: nothing to blank)
        eye = np.eye(n, dtype=bool)
        cov[~observable, :] = np.where(eye[~observable, :], np.inf, 0.0)
        cov[:, ~observable] = np.where(eye[:, ~observable], np.inf, 0.0)
        theta = np.where(observable, theta, 0.0)
    rss = max(state.yty - float(vec @ theta_s), 0.0)
    dof = max(state.rows - kept, 1.0)
    return RlsSolution(theta=theta, cov=cov, observable=observable, rss=rss, dof=dof)


def rank_decision(
    info: np.ndarray, rcond: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Eigen-decomposition of a scaled information matrix and the directions the rows
    determine (eigenvalue above ``rcond`` times the largest): (eigenvalues,
    eigenvectors, kept mask, observable mask per parameter, largest eigenvalue)."""
    evals, evecs = np.linalg.eigh(info)
    top = float(evals[-1]) if len(evals) and evals[-1] > 0 else 0.0
    keep = evals > rcond * top if top > 0 else np.zeros(len(evals), dtype=bool)
    if len(keep) and keep[0]:
        # every direction kept (evals ascend): no parameter has weight on a discarded one
        return evals, evecs, keep, np.ones(len(keep), dtype=bool), top
    # A parameter is observable when it has no weight on a discarded direction.
    observable = np.sum(evecs[:, ~keep] ** 2, axis=1) < 1e-6
    return evals, evecs, keep, observable, top


def _anchored_inverse(
    info: np.ndarray, anchored: np.ndarray, rcond: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """Pseudo-inverse of the scaled ``info`` with the ``anchored`` parameters always
    kept: (inverse, observable mask, number of directions kept).

    With a prior on the anchored parameters, ``info`` is singular exactly where the
    rows leave a combination of the *others* untouched: its null space is the null
    space of the free block (an anchored component would meet the prior). So the
    rank decision is made on the free block alone.
    """
    n = len(info)
    free = np.setdiff1d(np.arange(n), anchored)
    evals, evecs, keep, free_observable, top = rank_decision(info[np.ix_(free, free)], rcond)
    observable = np.ones(n, dtype=bool)
    observable[free] = free_observable
    # Drop the free block's null directions V by deflation, (info + c V V^T)^-1 -
    # V V^T / c, rather than by rotating into the eigenbasis: a rotation would mix
    # the round-off of the prior-held directions into the well-measured ones.
    null = np.zeros((n, int(np.sum(~keep))))
    null[free] = evecs[:, ~keep]
    c = top if top > 0 else 1.0
    deflated = info - (null * evals[~keep]) @ null.T + c * null @ null.T
    inv = np.linalg.inv(deflated) - null @ null.T / c
    return inv, observable, n - null.shape[1]


def batch_wls(H: np.ndarray, y: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """Reference batch weighted least squares ``argmin sum w (y - H theta)^2`` (full rank)."""
    H = np.asarray(H, dtype=float)
    y = np.asarray(y, dtype=float)
    sw = np.ones(len(y)) if w is None else np.sqrt(np.asarray(w, dtype=float))
    theta, *_ = np.linalg.lstsq(H * sw[:, None], y * sw, rcond=None)
    return theta


class RecursiveLeastSquares:
    """Stateful wrapper: ``update(H, y, w)`` per frame, ``solution`` at any time."""

    def __init__(self, n: int, lam: float = 1.0, scale: np.ndarray | None = None) -> None:
        if not 0.0 < lam <= 1.0:
            raise ValueError(f"forgetting factor must be in (0, 1], got {lam}")
        self.state = rls_init(n)  # information matrix and vector
        self.lam = lam  # forgetting factor
        self.scale = scale  # typical parameter magnitudes (rank decisions)

    def update(self, H: np.ndarray, y: np.ndarray, w: np.ndarray | None = None) -> None:
        self.state = rls_update(self.state, H, y, w, self.lam)

    @property
    def solution(self) -> RlsSolution:
        return rls_solve(self.state, scale=self.scale)
