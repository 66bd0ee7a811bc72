"""The cog from plumb lines: the least-squares intersection of the lines of a body hung
from two or more points, and the misfit test shared with the pendulum fit."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from estimator.classical.pendulum_axes import PendulumError, unit_axes

#: a misfit less probable than this under the stated errors widens the intervals
MISFIT_ALPHA = 0.01
#: plumb lines closer to parallel than this leave the cog along them undetermined
MIN_LINE_SPREAD_DEG = 1.0


def variance_factor(chi2: float, dof: int, alpha: float = MISFIT_ALPHA) -> float:
    """``chi2 / dof`` when the misfit is improbable under the stated errors, else 1.

    With the few degrees of freedom of a pendulum test (7 swings: 1) the Birge
    ratio ``max(1, chi2 / dof)`` would widen honest intervals most of the time;
    widening only on a significant misfit keeps them calibrated and still
    guards against understated uncertainties.
    """
    # scipy.stats is heavy to import: only a pendulum evaluation needs it
    from scipy import stats

    if dof <= 0 or not stats.chi2.sf(chi2, dof) < alpha:
        return 1.0
    return max(1.0, chi2 / dof)


@dataclass(frozen=True)
class CogFit:
    """The cog from plumb lines.

    Attributes
    ----------
    cog : (3,) m, bench frame.
    cov : (3, 3) m^2.
    distances : (n_lines,) m, distance of the cog from each line (0 for lines that meet).
    variance_factor : see :func:`variance_factor`; ``dof = 2 n - 3``, so lines that
        miss each other beyond their stated uncertainty widen the interval.
    chi2, dof : misfit of the lines against their stated uncertainty.
    """

    cog: np.ndarray
    cov: np.ndarray
    distances: np.ndarray
    variance_factor: float
    chi2: float
    dof: int


def cog_from_lines(
    points: npt.ArrayLike,
    directions: npt.ArrayLike,
    position_std: npt.ArrayLike,
    angle_std: npt.ArrayLike = 0.0,
) -> CogFit:
    """Least-squares intersection of the plumb lines of a body hung from different points.

    Minimises ``sum_k |P_k (G - p_k)|^2 / s_k^2`` with ``P_k = 1 - d_k d_k^T``; the
    lateral uncertainty of line k is ``s_k^2 = position_std_k^2 + (angle_std_k L_k)^2``
    with ``L_k`` the distance along the line from ``p_k`` to the cog (an angle
    error swings the line about its marked point). Two lines give three
    equations' worth of data for three unknowns plus one check (their gap).

    Parameters
    ----------
    points : (n, 3) m, a marked point of each line (the suspension point), body coordinates.
    directions : (n, 3), direction of each line (any length).
    position_std : () or (n,) m, 1 sigma lateral position of each line.
    angle_std : () or (n,) rad, 1 sigma direction of each line.

    Raises
    ------
    PendulumError
        Fewer than two lines, or lines (nearly) parallel.
    """
    p = np.atleast_2d(np.asarray(points, dtype=float))
    d = unit_axes(directions)
    n = len(p)
    if n < 2 or p.shape != d.shape:
        raise PendulumError(
            f"the cog needs at least 2 suspension lines with a point and a direction each, "
            f"got {n} points and {len(d)} directions"
        )
    pos = np.broadcast_to(np.asarray(position_std, dtype=float), (n,))
    ang = np.broadcast_to(np.asarray(angle_std, dtype=float), (n,))
    proj = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    s = np.linalg.svd(d, compute_uv=False)
    # Two lines at angle a give singular values sqrt(1 +- cos a): spread = 2 atan(s1 / s0).
    spread = math.degrees(2 * math.atan2(s[1], s[0]))
    if spread < MIN_LINE_SPREAD_DEG:
        angle = spread
        raise PendulumError(
            f"the {n} suspension lines are (nearly) parallel (spread {angle:.3g} deg): "
            "the cog along them is not determined; hang the body from points that give "
            "lines at a large angle"
        )
    cog = np.zeros(3)
    for _ in range(3):  # the angle term depends on the cog: a fixed point in 2-3 steps
        along = np.einsum("ni,ni->n", cog - p, d)
        var = pos**2 + (ang * along) ** 2
        weights = 1.0 / np.maximum(var, 1e-30)  # exact lines: huge equal weights
        normal = np.einsum("n,nij->ij", weights, proj)
        rhs = np.einsum("n,nij,nj->i", weights, proj, p)
        cog = np.linalg.solve(normal, rhs)
    cov = np.linalg.inv(normal)
    offsets = np.einsum("nij,nj->ni", proj, cog - p)
    distances = np.linalg.norm(offsets, axis=1)
    dof = 2 * n - 3
    chi2 = float(np.sum(weights * distances**2))
    factor = variance_factor(chi2, dof)
    return CogFit(cog, cov * factor, distances, factor, chi2, dof)
