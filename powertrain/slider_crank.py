"""Exact kinematics and inertia of one slider-crank (piston, con rod, crank pin).

Geometry in the plane of the cylinder, spanned by the cylinder axis ``c``
(crank centre towards the head) and ``t = s x c`` (``s`` the crank axis). The
crank pin is at ``r (cos theta, sin theta)``, theta the crank angle from this
cylinder's TDC, increasing with rotation (right hand about ``s``). Everything
here is at unit crank speed: at a constant speed ``omega`` velocities scale by
``omega`` and accelerations, forces and torques by ``omega^2``. Derivatives with
respect to theta carry the suffixes ``_t`` and ``_tt``.

Con-rod models
--------------
The rod is a rigid body of mass ``m_rod``, cog at ``a`` from the big end and
inertia ``J`` about its cog (axis parallel to ``s``). The classic two-mass
model puts ``m_rod a / l`` at the piston pin (it reciprocates) and the rest at
the crank pin (it rotates). Those two masses have the rod's mass and cog, so
every *force* is the same, but their inertia about the cog is
``J_2m = m_rod a (l - a)``, not the rod's ``J``: the two-mass model is exactly a
rod with ``J = J_2m``. When ``conrod_inertia`` is unknown we use that value,
which *is* the two-mass model; when it is known, the difference shows only in
the roll moment (about ``s``) on the block, by
``dM_roll = -(J - J_2m) omega^2 psi_tt (1 - psi_t)`` (``psi`` the rod angle):
the rod's own angular momentum change plus its share in the crank torque.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import binom

from powertrain.errors import PhysicsError


@dataclass(frozen=True)
class CylinderKinematics:
    """Positions and their theta-derivatives for one cylinder, at unit crank speed.

    Every attribute is an array shaped like ``theta``. Coordinates are along
    the cylinder axis ``c`` (suffix ``_c``) and ``t = s x c`` (suffix ``_t`` of
    the name, before the derivative suffix), in m; angles in rad.

    Attributes
    ----------
    x, x_t, x_tt : piston pin along ``c`` from the crank centre, and its
        derivatives (m, m/rad, m/rad^2). The piston moves along ``c`` only.
    psi, psi_t, psi_tt : con-rod angle (rad) of the vector big end -> small end
        from ``c``, right hand about ``s`` (``-arcsin(lambda sin theta)``).
    gc, gc_t, gc_tt, gt, gt_t, gt_tt : con-rod cog in the (c, t) plane.
    pc, pt : crank pin (m); its second derivatives are ``-pc`` and ``-pt``.
    """

    theta: np.ndarray
    x: np.ndarray
    x_t: np.ndarray
    x_tt: np.ndarray
    psi: np.ndarray
    psi_t: np.ndarray
    psi_tt: np.ndarray
    gc: np.ndarray
    gc_t: np.ndarray
    gc_tt: np.ndarray
    gt: np.ndarray
    gt_t: np.ndarray
    gt_tt: np.ndarray
    pc: np.ndarray
    pt: np.ndarray


@dataclass(frozen=True)
class SliderCrank:
    """One cylinder's moving parts, SI.

    Parameters
    ----------
    crank_radius : m, half the stroke.
    conrod_length : m, big-end to small-end centres.
    conrod_cog_from_big_end : m, ``a``.
    piston_mass : kg, piston with pin and rings.
    conrod_mass : kg.
    conrod_inertia : kg m^2 about the rod cog, or None for the two-mass model.
    """

    crank_radius: float
    conrod_length: float
    conrod_cog_from_big_end: float
    piston_mass: float
    conrod_mass: float
    conrod_inertia: float | None = None

    def __post_init__(self) -> None:
        r, length, a = self.crank_radius, self.conrod_length, self.conrod_cog_from_big_end
        if not (r > 0 and length > 0):
            raise PhysicsError(f"crank radius {r} m and con-rod length {length} m must be positive")
        if r / length >= 1:
            raise PhysicsError(f"lambda = r / l = {r / length:.4f} must be < 1")
        if not 0 <= a <= length:
            raise PhysicsError(
                f"con-rod cog at {a} m from the big end lies outside the rod (0..{length} m)"
            )
        if self.piston_mass < 0 or self.conrod_mass < 0:
            raise PhysicsError(
                f"masses must be >= 0 (piston {self.piston_mass} kg, con rod {self.conrod_mass} kg)"
            )
        if self.conrod_inertia is not None and self.conrod_inertia < 0:
            raise PhysicsError(f"con-rod inertia must be >= 0, got {self.conrod_inertia} kg m^2")

    @property
    def lam(self) -> float:
        """lambda = r / l."""
        return self.crank_radius / self.conrod_length

    @property
    def reciprocating_mass(self) -> float:
        """kg: piston plus the two-mass share ``m_rod a / l`` of the rod."""
        return (
            self.piston_mass + self.conrod_mass * self.conrod_cog_from_big_end / self.conrod_length
        )

    @property
    def rotating_mass(self) -> float:
        """kg: the two-mass share ``m_rod (1 - a / l)`` of the rod at the crank pin."""
        return self.conrod_mass * (1.0 - self.conrod_cog_from_big_end / self.conrod_length)

    @property
    def two_mass_inertia(self) -> float:
        """kg m^2: the rod inertia about its cog implied by the two-mass model, ``m a (l - a)``."""
        a = self.conrod_cog_from_big_end
        return self.conrod_mass * a * (self.conrod_length - a)

    @property
    def rod_inertia(self) -> float:
        """kg m^2: the rod inertia used, given or the two-mass one."""
        return self.two_mass_inertia if self.conrod_inertia is None else float(self.conrod_inertia)

    def kinematics(self, theta: npt.ArrayLike) -> CylinderKinematics:
        """Exact kinematics at crank angles ``theta`` (rad from this cylinder's TDC)."""
        return kinematics(
            theta, self.crank_radius, self.conrod_length, self.conrod_cog_from_big_end
        )

    def piston_motion(self, theta: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Piston position ``x`` (m) and ``dx/dtheta`` (m/rad) at ``theta`` (:func:`piston_motion`)."""
        return piston_motion(theta, self.crank_radius, self.conrod_length)

    def kinetic_energy(self, theta: npt.ArrayLike, omega: float = 1.0) -> np.ndarray:
        """J: kinetic energy of piston and rod (the crank-pin-fixed masses excluded: it is constant)."""
        k = self.kinematics(theta)
        return (
            0.5
            * omega**2
            * (
                self.piston_mass * k.x_t**2
                + self.conrod_mass * (k.gc_t**2 + k.gt_t**2)
                + self.rod_inertia * k.psi_t**2
            )
        )

    def inertia_torque(self, theta: npt.ArrayLike, omega: float = 1.0) -> np.ndarray:
        """N m about ``s`` delivered to the crank by piston and rod inertia at constant ``omega``.

        ``T omega = -dKE/dt``; written as the virtual work of the inertia forces
        (``-sum m a . dx/dtheta``), which is the same thing without a numerical
        derivative.
        """
        return self.inertia_torque_of(self.kinematics(theta), omega)

    def inertia_torque_of(self, k: CylinderKinematics, omega: float = 1.0) -> np.ndarray:
        """:meth:`inertia_torque` from kinematics at hand (an engine's loads reuse theirs)."""
        return -(omega**2) * (
            self.piston_mass * k.x_tt * k.x_t
            + self.conrod_mass * (k.gc_tt * k.gc_t + k.gt_tt * k.gt_t)
            + self.rod_inertia * k.psi_tt * k.psi_t
        )


def kinematics(theta: npt.ArrayLike, r: float, length: float, a: float = 0.0) -> CylinderKinematics:
    """Exact slider-crank kinematics at unit crank speed (see :class:`CylinderKinematics`).

    Parameters
    ----------
    theta : (n,) rad from TDC.
    r : crank radius, m.
    length : con-rod length, m.
    a : con-rod cog from the big end, m.
    """
    th = np.asarray(theta, dtype=float)
    lam = r / length
    s, c, root, x, x_t = _piston(th, r, length)
    x_tt = -r * (c + lam * (np.cos(2 * th) + lam**2 * s**4) / root**3)
    # beta = arcsin(lambda sin theta) leans the rod towards -t; psi = -beta.
    psi = -np.arcsin(lam * s)
    psi_t = -lam * c / root
    psi_tt = lam * s * (1.0 - lam**2) / root**3
    # The rod cog splits big end (rotating) and small end (reciprocating) in a : l - a.
    w = a / length
    gc = (1 - w) * r * c + w * x
    gc_t = -(1 - w) * r * s + w * x_t
    gc_tt = -(1 - w) * r * c + w * x_tt
    gt = (1 - w) * r * s
    gt_t = (1 - w) * r * c
    gt_tt = -(1 - w) * r * s
    return CylinderKinematics(
        theta=th, x=x, x_t=x_t, x_tt=x_tt, psi=psi, psi_t=psi_t, psi_tt=psi_tt,
        gc=gc, gc_t=gc_t, gc_tt=gc_tt, gt=gt, gt_t=gt_t, gt_tt=gt_tt, pc=r * c, pt=r * s,
    )  # fmt: skip


def piston_motion(theta: npt.ArrayLike, r: float, length: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`kinematics`' piston position ``x`` and ``dx/dtheta`` alone (the same bits),
    for the cylinder volume and the gas torque, which need nothing else."""
    _, _, _, x, x_t = _piston(np.asarray(theta, dtype=float), r, length)
    return x, x_t


def _piston(
    th: np.ndarray, r: float, length: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """sin, cos, ``cos(beta)`` (beta the rod obliquity), ``x``, ``dx/dtheta`` at ``th``."""
    lam = r / length
    s, c = np.sin(th), np.cos(th)
    root = np.sqrt(1.0 - (lam * s) ** 2)
    return s, c, root, r * c + length * root, -r * s * (1.0 + lam * c / root)


def piston_position_coefficients(lam: float, max_order: int, rtol: float = 1e-17) -> np.ndarray:
    """Exact Fourier series of the piston position: ``x / r = sum_k C[k] cos(k theta)``.

    From ``x = r cos theta + l sqrt(1 - lambda^2 sin^2 theta)``, the binomial
    series of the root and ``sin^2n = 4^-n [C(2n, n) + 2 sum_k (-1)^k C(2n, n-k) cos 2k theta]``:
    ``C[2k] = (1/lambda) sum_{n >= k} (-1)^n binom(1/2, n) lambda^2n 4^-n 2^(k>0) (-1)^k C(2n, n-k)``.
    Only order 1 and even orders are non-zero. Summed until a term falls below
    ``rtol`` of the sum.

    Returns
    -------
    (max_order + 1,) float, index = order.
    """
    if not 0 < lam < 1:
        raise PhysicsError(f"lambda must be in (0, 1), got {lam}")
    out = np.zeros(max_order + 1)
    if max_order >= 1:
        out[1] = 1.0
    for k in range(0, max_order // 2 + 1):
        # n = 0 contributes only to the mean (the 1 of the root's series).
        total = 1.0 if k == 0 else 0.0
        for n in range(max(k, 1), 100_000):
            term = (
                (-1) ** n * binom(0.5, n) * lam ** (2 * n) / 4.0**n
                * (1 if k == 0 else 2 * (-1) ** k) * binom(2 * n, n - k)
            )  # fmt: skip
            total += term
            if n > k + 2 and abs(term) <= rtol * abs(total):
                break
        else:  # pragma: no cover - lambda < 1 always converges well before
            raise PhysicsError(f"piston series for lambda = {lam} did not converge")
        out[2 * k] += total / lam
    return out


def piston_acceleration_coefficients(lam: float, max_order: int) -> np.ndarray:
    """Exact series of the piston acceleration: ``x_tt / r = sum_k A[k] cos(k theta)``.

    ``A[k] = -k^2 C[k]`` of :func:`piston_position_coefficients`. First terms
    (textbook): ``A[1] = -1``, ``A[2] = -(lambda + lambda^3/4 + 15 lambda^5/128 + ...)``,
    ``A[4] = lambda^3/4 + 3 lambda^5/16 + ...``, ``A[6] = -(9 lambda^5/128 + ...)``.
    The reciprocating inertia force along ``c`` is ``-m_rec r omega^2 sum A[k] cos k theta``.
    """
    c = piston_position_coefficients(lam, max_order)
    k = np.arange(max_order + 1)
    out = -(k**2) * np.where(k == 0, 0.0, c)
    return out
