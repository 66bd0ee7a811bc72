"""What makes an order's readings evidence of the rigid motion: a response above noise
(the regression F test of the rigid fit) and little leakage from bending neighbours.

Used by the order gates (:mod:`estimator.gating`): an order with no known excitation is
used only where it responds (:func:`responds`) and well above the rigid-body modes
(:data:`UNLOADED_MODE_RATIO`); any order is rejected where the bending of its
neighbours leaks more into it than its noise allows (:func:`neighbour_leakage`).
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.special import fdtri

from estimator.kinematics import RigidFit


# Share of another order's uncorrected change that leaks into an order n half orders
# away: the sweep correction removes the linear change of every order across the
# window, what bends is left, and a change across a window leaks like a ramp's
# spectrum, 1 / (2 pi n) (an upper bound for our tapered windows); beyond two half
# orders we neglect it.
def leak_share(n_half_orders: np.ndarray) -> np.ndarray:
    n = np.rint(np.asarray(n_half_orders, float))
    with np.errstate(divide="ignore"):
        return np.where((n >= 1) & (n <= 2), 1.0 / (2.0 * np.pi * n), 0.0)


@functools.lru_cache(maxsize=8)
def leak_matrix(orders: tuple[float, ...]) -> np.ndarray:
    h = np.asarray(orders)
    return leak_share(2 * np.abs(h[:, None] - h[None, :])) ** 2


def neighbour_leakage(orders: np.ndarray, bend: np.ndarray, power: np.ndarray) -> np.ndarray:
    """(..., k) channel variance, (m/s^2)^2, that the bending of the nearby orders leaks
    into each order (from their relative bend and mean-square readings, (..., k)).

    Measured on the simulated i3 in 30-60 rpm/s sweeps just above its modes, where
    H1.5 and H1 bend by 2-15 %: the H2 error is 0.3-0.9 times this estimate.
    """
    # one matrix-vector product per frame (as for one frame alone: the same bits)
    return np.matmul(leak_matrix(tuple(orders.tolist())), (bend**2 * power)[..., None])[..., 0]


# An order with no known load sets the scale of the inertia through the mount reactions
# alone (the unbalance that drives it is fitted with it), and near the modes those rows
# took the dsp's errors there into the inertia: the simulated inline 4 (realistic, 0.5 g m)
# with its order 1 used from 1.25 times the top mode (25 Hz) missed Ixx/Izz/Gy by 10-18 %
# in 5 of 12 seeds; used from 2.5 times, every interval held in seeds 0-11.
UNLOADED_MODE_RATIO = 2.5
# An order with no known excitation is used when its response is the rigid motion's and
# not noise's (``responds``): the regression F test at this level...
RESPONSE_QUANTILE = 0.999
# ... and above this share of the frame's strongest order's mean square: noise-free, the
# dsp leaves 1e-14 of it in the unexcited orders of the simulated inline 4, which the
# F test (with no noise to compare with) would pass.
RESPONSE_FLOOR = 1e-10


@functools.lru_cache(maxsize=16)
def _f_quantile(dfn: int, dfd: int) -> float:
    return float(fdtri(dfn, dfd, RESPONSE_QUANTILE))


def responds(relative: np.ndarray, power: np.ndarray, fit: RigidFit) -> np.ndarray:
    """(..., k) whether each order's readings are a rigid motion rather than noise, from
    its relative rigidity residual and mean square ``power`` (same shape; the last axis
    the orders of one frame).

    The regression F test of the rigid fit: with n channels and r fitted motions, the
    fitted sum of squares over 2 r against the residual's over 2 (n - r) is F(2 r,
    2 (n - r)) for noise alone. In the relative residual rho (residual rms over the
    readings' rms, ``n rho^2`` of the sum of squares per ``n - r`` residual dof) it
    is ``F = (n - (n - r) rho^2) / (r rho^2)``; nine channels pass below rho = 0.28.
    Measured on the simulated inline 4 (40 dB, 0.5 g m unbalance): order 1 at rho =
    0.03-0.09, the unexcited order 1.5 (noise alone) at 0.48-1.3.
    """
    power = np.asarray(power, float)
    n, r = fit.sw.size, fit.rank
    if n <= r:
        return np.zeros(power.shape, dtype=bool)
    rho2 = np.asarray(relative, float) ** 2
    with np.errstate(divide="ignore"):
        f = (n - (n - r) * rho2) / (r * rho2)
    strongest = np.maximum(power.max(axis=-1, keepdims=True), 1e-300)
    return (f > _f_quantile(2 * r, 2 * (n - r))) & (power > RESPONSE_FLOOR * strongest)
