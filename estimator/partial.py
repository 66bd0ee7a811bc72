"""Estimation when the accelerometers leave one rigid-body motion unmeasured.

Two triaxial sensors (a third one dead for the whole run, or never fitted)
see the acceleration of every point on the line through them, and the
rotation about any axis across it, but not the rotation about the line itself:
that motion moves neither sensor. Per (frame, order) the motion is then

    m = m0 + w e

with ``m0`` the minimum-norm fit, ``e`` the unseen direction (6,) and ``w`` an
unknown complex amplitude. The equations of motion are affine in the motion,
so a pair's whitened residual is

    r(theta, w) = (H0 theta - y0) + w_re (B1 theta - b1) + w_im (B2 theta - b2)

bilinear in theta and w. The unseen rotation is still driven by the known
excitation and carried by the inertia and the cog, so the equations the
sensors do give (five of six per order) determine theta once the sweep has
varied the motion enough. We solve it by variable projection: for a given
theta each pair's best w is a 2-unknown least-squares fit; what is left,
``r = P(theta) (H0 theta - y0)`` with ``P`` the projector away from the w
columns, is minimised over theta by Gauss-Newton with the Kaufman Jacobian
``J = P (H0 + w_re B1 + w_im B2)`` (its ``J^T r`` is the exact gradient).

At the solution, the pairs enter the estimate as the rows ``J theta = J theta^
- r``: the information state then holds their information about theta with
the per-pair w fitted alongside (two real rows per pair fewer in the degrees
of freedom), and the result is built as for fully measured frames.

This needs the pairs themselves (a few hundred bytes each), not only sums:
memory grows with the number of such frames, bounded by ``MAX_PAIRS``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from estimator.rls import RlsSolution, RlsState

# Beyond this many stored (frame, order) pairs, new ones are linearised once at the
# current estimate and not stored (never solved again): a 60 s sweep at 1500-4500 rpm
# with three orders gives about 4500; an hour-long one would otherwise grow without bound.
MAX_PAIRS = 20000
MAX_ITERATIONS = 40
STEP_TOL = 1e-9  # converged when no parameter moves by more than this share of its scale


@dataclass(frozen=True)
class PartialRows:
    """Whitened rows of P pairs, each (P, 12, n) / (P, 12): the fit part (H0, y0),
    the unseen motion's real and imaginary columns (B1, b1), (B2, b2), and the
    systematic-error sensitivity ``dr`` (P, 12, n_sys) at the completed motion."""

    H0: np.ndarray
    y0: np.ndarray
    B1: np.ndarray
    b1: np.ndarray
    B2: np.ndarray
    b2: np.ndarray
    dr: np.ndarray


def project_out(rows: PartialRows, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Best w per pair at ``theta`` and what is left.

    Returns ``J`` (P, 12, n), the residual ``r`` (P, 12) with w fitted, and ``w``
    (P, 2) as [Re, Im].
    """
    r0 = rows.H0 @ theta - rows.y0
    c = np.stack([rows.B1 @ theta - rows.b1, rows.B2 @ theta - rows.b2], axis=2)  # (P, 12, 2)
    g = np.einsum("pki,pkj->pij", c, c)
    # a pair whose w columns vanish (no excitation along e) keeps w = 0
    g += (1e-14 * np.trace(g, axis1=1, axis2=2) + 1e-300)[:, None, None] * np.eye(2)
    cg = c @ np.linalg.inv(g)  # (P, 12, 2)
    w = -np.einsum("pki,pk->pi", cg, r0)  # -(C^T C)^-1 C^T r0
    a = rows.H0 + w[:, 0, None, None] * rows.B1 + w[:, 1, None, None] * rows.B2
    ja = a - cg @ np.einsum("pki,pkn->pin", c, a)  # (1 - C G^-1 C^T) A
    return ja, r0 + np.einsum("pki,pi->pk", c, w), w


@dataclass(frozen=True)
class Contribution:
    """What a set of pairs adds to the information state, linearised at ``theta``:
    the rows ``J theta' = J theta - r`` (each pair counts 10 rows: two of its 12 went
    into its own w) and their systematic-error sensitivity ``J^T dr``."""

    state: RlsState
    sens: np.ndarray  # (n, n_sys)

    @classmethod
    def empty(cls, n: int, n_sys: int) -> Contribution:
        return cls(RlsState(np.zeros((n, n)), np.zeros(n)), np.zeros((n, n_sys)))

    @classmethod
    def of(cls, rows: PartialRows, theta: np.ndarray) -> tuple[Contribution, np.ndarray]:
        """The pairs' contribution at ``theta``, and their w (P, 2)."""
        j, r, w = project_out(rows, theta)
        jf = j.reshape(-1, j.shape[2])
        y = jf @ theta - r.reshape(-1)
        state = RlsState(info=jf.T @ jf, vec=jf.T @ y, yty=float(y @ y), rows=10.0 * len(j))
        return cls(state, np.einsum("pkn,pks->ns", j, rows.dr)), w

    def plus(self, other: Contribution) -> Contribution:
        return Contribution(other.added_to(self.state), self.sens + other.sens)

    def added_to(self, state: RlsState) -> RlsState:
        """``state`` with these rows added."""
        a = self.state
        return RlsState(
            state.info + a.info, state.vec + a.vec, state.yty + a.yty, state.rows + a.rows
        )


@dataclass(frozen=True)
class PartialSolution:
    """The pairs' contribution at the joint solution with the fully measured state."""

    contribution: Contribution
    theta: np.ndarray
    w: np.ndarray  # (P, 2)
    iterations: int
    converged: bool


def solve_partial(
    base: RlsState,
    rows_at: Callable[[np.ndarray, np.ndarray], PartialRows],
    theta0: np.ndarray,
    w0: np.ndarray,
    scale: np.ndarray,
    solve: Callable[[RlsState], RlsSolution],
) -> PartialSolution:
    """Gauss-Newton on the projected residuals of the pairs plus the quadratic ``base``.

    ``rows_at(theta, w)`` gives the pairs' rows linearised at ``theta`` (the row
    weighting and the few linearised terms follow the estimate, as for the
    streaming state) with ``dr`` taken at the motions completed by ``w``.
    Parameters the data do not determine stay at ``theta0``.
    """
    theta, w = np.asarray(theta0, float).copy(), np.asarray(w0, float)
    converged = False
    iterations = 0
    while iterations < MAX_ITERATIONS:
        iterations += 1
        contribution, w = Contribution.of(rows_at(theta, w), theta)
        sol = solve(contribution.added_to(base))
        new = np.where(sol.observable, sol.theta, theta)
        step = float(np.max(np.abs(new - theta) / scale))
        theta = new
        if step < STEP_TOL:
            converged = True
            break
    contribution, w = Contribution.of(rows_at(theta, w), theta)
    return PartialSolution(contribution, theta, w, iterations, converged)
