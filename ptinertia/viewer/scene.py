"""Geometry of the 3D view, as pure functions (no Rerun here, so it is tested without a viewer).

* The powertrain is drawn as the uniform box that has the estimated principal
  moments and mass: its proportions *are* the inertia estimate, and its edges
  lie along the principal axes.
* The cog uncertainty is the ``k``-sigma ellipsoid of the (Gx, Gy, Gz) covariance.
* The rigid-body motion of a frame is turned from accelerations into a
  displacement (``u = gamma / -(h omega)^2`` per order) and animated
  stroboscopically: each scene tick advances the phase by a fixed step, so one
  engine cycle plays over a couple of seconds instead of 40 ms.
"""

from __future__ import annotations

import math

import numpy as np

from estimator.kinematics import RigidMotion


def equivalent_box(moments: np.ndarray, mass: float) -> np.ndarray:
    """Half sizes of the uniform box with the given principal moments and mass.

    A uniform box of half sizes ``a_i`` has ``I_1 = m (a_2^2 + a_3^2) / 3`` (and
    cyclic), so ``a_i^2 = 3 (I_j + I_k - I_i) / (2 m)``.

    Parameters
    ----------
    moments : (3,) float, kg m^2, principal moments (any order).
    mass : float, kg.

    Returns
    -------
    (3,) float, m, half size along each principal axis, in the order of ``moments``.
    A moment that breaks the triangle inequality gives a flat box (half size 1 % of the largest)
    rather than an error: the view must keep drawing whatever the estimate does.
    """
    i = np.asarray(moments, dtype=float)
    sq = 1.5 * (i.sum() - 2.0 * i) / max(float(mass), 1e-12)
    top = float(np.sqrt(max(sq.max(), 1e-12)))
    return np.sqrt(np.maximum(sq, (0.01 * top) ** 2))


def covariance_ellipsoid(cov: np.ndarray, k: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Half sizes and axes of the ellipsoid ``x^T cov^-1 x = k^2``.

    Parameters
    ----------
    cov : (3, 3) float, m^2, covariance of the cog.
    k : number of standard deviations.

    Returns
    -------
    half_sizes : (3,) float, m.
    axes : (3, 3) float, columns are the (right-handed) ellipsoid axes in the bench frame.
    """
    sym = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
    var, axes = np.linalg.eigh(sym)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    return k * np.sqrt(np.maximum(var, 0.0)), axes


def displacement_amplitudes(
    motion: RigidMotion, orders: tuple[float, ...] | np.ndarray, rpm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Complex displacement of the motion's origin and rotation, per order.

    Harmonic motion ``x = Re{X exp(i h omega t)}`` has acceleration
    ``-(h omega)^2 X``, so ``U = gamma_O / -(h omega)^2`` and ``Theta = Omega' / -(h omega)^2``.

    Returns
    -------
    u_o : (n_orders, 3) complex, m.
    theta : (n_orders, 3) complex, rad.
    """
    w2 = (np.asarray(orders, dtype=float) * rpm * 2.0 * np.pi / 60.0) ** 2
    return motion.gamma_o / -w2[:, None], motion.omega_dot / -w2[:, None]


def displacement_at(
    u_o: np.ndarray, theta: np.ndarray, orders: tuple[float, ...] | np.ndarray, phi: float
) -> tuple[np.ndarray, np.ndarray]:
    """Real displacement (3,) m and rotation (3,) rad at crank angle ``phi`` (rad)."""
    rot = np.exp(1j * np.asarray(orders, dtype=float) * phi)
    return (u_o * rot[:, None]).sum(axis=0).real, (theta * rot[:, None]).sum(axis=0).real


def rotation_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation by ``|rotvec|`` rad about ``rotvec``, (3, 3)."""
    v = np.asarray(rotvec, dtype=float)
    angle = float(np.linalg.norm(v))
    if angle < 1e-15:
        return np.eye(3)
    k = v / angle
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


def exaggerated_pose(
    origin: np.ndarray, u: np.ndarray, theta: np.ndarray, exaggeration: float
) -> tuple[np.ndarray, np.ndarray]:
    """Parent-from-child transform that moves the body by ``exaggeration`` times its motion.

    A body point ``x`` goes to ``R (x - O) + O + e u`` with ``R`` the finite
    rotation by ``e theta``: for small ``e`` that is ``x + e (u + theta x (x - O))``,
    the rigid displacement, and it stays a proper rigid motion when ``e`` is large.

    Returns
    -------
    translation : (3,) m; mat3x3 : (3, 3), so that ``x' = mat3x3 @ x + translation``.
    """
    r = rotation_matrix(exaggeration * np.asarray(theta, dtype=float))
    o = np.asarray(origin, dtype=float)
    return o + exaggeration * np.asarray(u, dtype=float) - r @ o, r


def peak_excursion(u_o: np.ndarray, theta: np.ndarray, radius: float) -> float:
    """Upper bound of how far a point within ``radius`` m of the origin moves (m)."""
    return float(np.abs(u_o).sum(axis=0).max() + radius * np.abs(theta).sum(axis=0).max())


def nice_exaggeration(excursion: float, target: float) -> float:
    """The largest 1-2-5 factor that keeps ``excursion * factor <= target`` (at least 1)."""
    if not (excursion > 0 and math.isfinite(excursion)):
        return 1.0
    raw = target / excursion
    if raw <= 1.0:
        return 1.0
    decade = 10.0 ** math.floor(math.log10(raw))
    for step in (5.0, 2.0, 1.0):
        if step * decade <= raw * (1 + 1e-12):
            return step * decade
    return decade
