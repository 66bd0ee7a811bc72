"""Rigid-body algebra in the bench frame: inertia tensors, their moves and checks.

Conventions (``physics-notes.md``): the tensor about the cog holds the products
with a minus sign, ``I = [[Ixx, -Ixy, -Ixz], [-Ixy, Iyy, -Iyz], [-Ixz, -Iyz, Izz]]``
with ``Ixy = integral(x y dm)``. Everything is SI (kg, m, kg m^2).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from powertrain.errors import PhysicsError

TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")


def inertia_matrix(
    Ixx: float, Iyy: float, Izz: float, Ixy: float = 0.0, Ixz: float = 0.0, Iyz: float = 0.0
) -> np.ndarray:
    """The (3, 3) tensor from its six terms (kg m^2), products as ``integral(x y dm)``."""
    return np.array(
        [[Ixx, -Ixy, -Ixz], [-Ixy, Iyy, -Iyz], [-Ixz, -Iyz, Izz]],
        dtype=float,
    )


def inertia_terms(inertia: npt.ArrayLike) -> dict[str, float]:
    """The six terms of a (3, 3) tensor, inverse of :func:`inertia_matrix`.

    The products are read from the symmetric part, so a slightly asymmetric
    estimate gives the mean of its two off-diagonal halves.
    """
    i = np.asarray(inertia, dtype=float)
    _check_shape(i, (3, 3), "inertia")
    sym = 0.5 * (i + i.T)
    return {
        "Ixx": float(sym[0, 0]),
        "Iyy": float(sym[1, 1]),
        "Izz": float(sym[2, 2]),
        "Ixy": float(-sym[0, 1]),
        "Ixz": float(-sym[0, 2]),
        "Iyz": float(-sym[1, 2]),
    }


def skew(v: npt.ArrayLike) -> np.ndarray:
    """Cross-product matrix: ``skew(v) @ w == np.cross(v, w)``.

    Parameters
    ----------
    v : (..., 3) array

    Returns
    -------
    (..., 3, 3) array, same dtype as ``v``.
    """
    v = np.asarray(v)
    out = np.zeros((*v.shape[:-1], 3, 3), dtype=np.result_type(v, float))
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def parallel_axis(inertia_g: npt.ArrayLike, mass: float, d: npt.ArrayLike) -> np.ndarray:
    """Inertia about a point at offset ``d`` (m) from the cog G.

    ``I_P = I_G + m (|d|^2 1 - d d^T)`` (Huygens-Steiner); equal to
    ``I_G - m skew(d) @ skew(d)``.

    Parameters
    ----------
    inertia_g : (3, 3) kg m^2, about G.
    mass : kg.
    d : (3,) m, the point minus G.
    """
    d = np.asarray(d, dtype=float)
    return np.asarray(inertia_g, dtype=float) + mass * (float(d @ d) * np.eye(3) - np.outer(d, d))


def rotate_inertia(inertia: npt.ArrayLike, rotation: npt.ArrayLike) -> np.ndarray:
    """The tensor of a body turned by ``rotation`` (3, 3): ``R I R^T``.

    Equivalently, ``rotation`` maps body-frame components to bench-frame ones.
    """
    r = np.asarray(rotation, dtype=float)
    return r @ np.asarray(inertia, dtype=float) @ r.T


def rotation_matrix(axis: npt.ArrayLike, angle: float) -> np.ndarray:
    """Right-hand rotation by ``angle`` (rad) about ``axis`` (any non-zero (3,) vector)."""
    a = np.asarray(axis, dtype=float)
    n = float(np.linalg.norm(a))
    if not np.isfinite(n) or n == 0.0:
        raise PhysicsError(f"rotation axis must be a non-zero vector, got {a.tolist()}")
    k = skew(a / n)
    # Rodrigues' formula.
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def principal(inertia: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments and axes.

    Returns
    -------
    moments : (3,) kg m^2, ascending.
    axes : (3, 3), column ``j`` is the unit axis of ``moments[j]`` in the bench
        frame; the columns form a right-handed frame (determinant +1).
    """
    i = np.asarray(inertia, dtype=float)
    _check_shape(i, (3, 3), "inertia")
    moments, axes = np.linalg.eigh(0.5 * (i + i.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] = -axes[:, 2]
    return moments, axes


def consistency_problems(inertia: npt.ArrayLike, tol: float = 1e-9) -> list[str]:
    """What makes a tensor impossible for a real body; empty if none.

    Checks symmetry, positive definiteness and the triangle inequality of the
    principal moments (``I1 + I2 >= I3`` for every ordering), which any mass
    distribution satisfies because ``I1 + I2 - I3 = 2 integral(z'^2 dm) >= 0``.
    ``tol`` is relative to the largest moment.
    """
    i = np.asarray(inertia, dtype=float)
    if i.shape != (3, 3):
        return [f"inertia must have shape (3, 3), got {i.shape}"]
    if not np.all(np.isfinite(i)):
        return ["inertia has non-finite terms"]
    problems = []
    scale = float(np.abs(i).max()) or 1.0
    asym = float(np.abs(i - i.T).max())
    if asym > tol * scale:
        problems.append(f"inertia is not symmetric (max |I - I^T| = {asym:.3g} kg m^2)")
    moments, _ = principal(i)
    if moments[0] <= tol * scale:
        problems.append(
            f"inertia is not positive definite (principal moments {np.round(moments, 6).tolist()} kg m^2)"
        )
    elif moments[0] + moments[1] < moments[2] * (1 - tol):
        problems.append(
            f"principal moments {np.round(moments, 6).tolist()} kg m^2 violate the triangle "
            f"inequality I1 + I2 >= I3 ({moments[0] + moments[1]:.6g} < {moments[2]:.6g})"
        )
    return problems


@dataclass(frozen=True)
class RigidBody:
    """Mass, cog and inertia about the cog, bench frame, SI.

    Parameters
    ----------
    mass : kg, > 0.
    cog : (3,) m.
    inertia : (3, 3) kg m^2 about the cog.

    Raises
    ------
    PhysicsError
        For a non-positive mass or an inertia no real body has.
    """

    mass: float
    cog: np.ndarray = field(repr=False)
    inertia: np.ndarray = field(repr=False)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mass) and self.mass > 0):
            raise PhysicsError(f"mass must be positive, got {self.mass} kg")
        cog = np.array(self.cog, dtype=float)
        _check_shape(cog, (3,), "cog")
        inertia = np.array(self.inertia, dtype=float)
        problems = consistency_problems(inertia)
        if problems:
            raise PhysicsError(problems[0])
        cog.setflags(write=False)
        inertia.setflags(write=False)
        object.__setattr__(self, "mass", float(self.mass))
        object.__setattr__(self, "cog", cog)
        object.__setattr__(self, "inertia", inertia)

    @property
    def terms(self) -> dict[str, float]:
        """The six inertia terms (kg m^2), see :func:`inertia_terms`."""
        return inertia_terms(self.inertia)

    def inertia_about(self, point: npt.ArrayLike) -> np.ndarray:
        """(3, 3) kg m^2 about ``point`` (m), axes parallel to the bench frame."""
        return parallel_axis(self.inertia, self.mass, np.asarray(point, dtype=float) - self.cog)


def _check_shape(a: np.ndarray, shape: tuple[int, ...], what: str) -> None:
    if a.shape != shape:
        raise PhysicsError(f"{what} must have shape {shape}, got {a.shape}")
