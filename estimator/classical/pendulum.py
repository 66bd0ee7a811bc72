"""Pendulum and rolling-plate methods: the inertia tensor from torsional periods (paper eqs. 4-8).

A body swinging about an axis ``Delta`` through its cog with unit direction
``u = (u, v, w)`` (eq. 4) has the inertia ``I_Delta = u^T I u`` (eq. 5); a
torsional suspension of stiffness ``C`` gives it the period
``T = 2 pi sqrt(I_Delta / C)`` (eq. 6), so each configuration is one linear
equation in the six terms (eq. 7)::

    u^2 Ixx + v^2 Iyy + w^2 Izz - 2 uv Ixy - 2 uw Ixz - 2 vw Iyz = C T^2 / (4 pi^2)

(the products carry a minus sign because the tensor holds ``-Ixy``). On a
rolling plate the body turns about the plate's pivot ``Delta'``, parallel to
``Delta`` at the distance ``d(G, Delta')``; the plate's own inertia and the
parallel-axis term come off the right-hand side (eq. 8)::

    u^T I u = C T^2 / (4 pi^2) - I_plate - M d(G, Delta')^2

with ``M`` the mass of the tested body (the parallel-axis term is the body's;
the paper's wording attaches it to the plate). ``C`` is the whole restoring
stiffness: for a plate pivoting about a horizontal axis it includes the
gravity term.

Six or more configurations are solved by generalised least squares with the
full covariance of the right-hand sides: period, stiffness and axis-angle
errors are independent per configuration; the plate inertia, the body mass
and the cog are shared by every configuration, so their errors are
correlated across rows. The cog comes from two or more plumb lines
(:func:`estimator.classical.plumb_lines.cog_from_lines`).

The axis set's conditioning is checked first (:mod:`estimator.classical.pendulum_axes`);
the plumb lines and the misfit test are in :mod:`estimator.classical.plumb_lines`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from estimator.classical.pendulum_axes import (
    PendulumError,
    check_axis_set,
    quadratic_rows,
    unit_axes,
)
from estimator.classical.plumb_lines import variance_factor
from powertrain.rigidbody import TERMS, inertia_matrix


def axis_inertia(inertia: npt.ArrayLike, axes: npt.ArrayLike) -> np.ndarray:
    """(n,) kg m^2 ``u^T I u`` about each axis through the cog (eq. 5)."""
    a = unit_axes(axes)
    return np.einsum("ni,ij,nj->n", a, np.asarray(inertia, dtype=float), a)


def period_from_inertia(inertia_total: npt.ArrayLike, stiffness: npt.ArrayLike) -> np.ndarray:
    """s, ``T = 2 pi sqrt(I / C)`` (eq. 6) for I in kg m^2 and C in N m/rad."""
    return 2 * np.pi * np.sqrt(np.asarray(inertia_total, float) / np.asarray(stiffness, float))


def inertia_from_period(period: npt.ArrayLike, stiffness: npt.ArrayLike) -> np.ndarray:
    """kg m^2, ``C T^2 / (4 pi^2)`` (eq. 6)."""
    return np.asarray(stiffness, float) * np.asarray(period, float) ** 2 / (4 * np.pi**2)


def distance_to_axis(point: np.ndarray, axis_point: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Offset of ``point`` from the line through ``axis_point`` along unit ``axis``, (..., 3) m."""
    r = point - axis_point
    return r - np.sum(r * axis, axis=-1, keepdims=True) * axis


@dataclass(frozen=True)
class Swing:
    """One pendulum configuration.

    Parameters
    ----------
    axis : (3,) direction of the swing axis ``Delta`` through the cog, bench frame.
    period : s, measured torsional period.
    stiffness : N m/rad, torsional stiffness of the suspension (all of the restoring moment).
    period_std, stiffness_std : 1 sigma, s and N m/rad.
    axis_std : rad, 1 sigma of the axis direction (isotropic, independent per configuration).
    plate_point : (3,) m, rolling plate only: a point of the pivot ``Delta'``, body coordinates.
    plate_point_std : m, 1 sigma of that point across the axis.
    name : label.
    """

    axis: np.ndarray
    period: float
    stiffness: float
    period_std: float = 0.0
    stiffness_std: float = 0.0
    axis_std: float = 0.0
    plate_point: np.ndarray | None = None
    plate_point_std: float = 0.0
    name: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "axis", unit_axes(self.axis)[0])
        if not (self.period > 0 and self.stiffness > 0):
            raise PendulumError(
                f"configuration {self.name!r}: period {self.period} s and stiffness "
                f"{self.stiffness} N m/rad must be > 0"
            )
        for what in ("period_std", "stiffness_std", "axis_std", "plate_point_std"):
            if not getattr(self, what) >= 0:
                raise PendulumError(
                    f"configuration {self.name!r}: {what} must be >= 0, got {getattr(self, what)}"
                )
        if self.plate_point is not None:
            object.__setattr__(self, "plate_point", np.asarray(self.plate_point, float).reshape(3))


@dataclass(frozen=True)
class Plate:
    """The rolling plate and what the parallel-axis term needs.

    Parameters
    ----------
    inertia : kg m^2, the plate's own inertia about its pivot (with its fixtures).
    body_mass : kg, mass ``M`` of the tested body.
    cog : (3,) m, the body's cog (from :func:`cog_from_lines` or stated).
    inertia_std, body_mass_std : 1 sigma.
    cog_cov : (3, 3) m^2.
    """

    inertia: float
    body_mass: float
    cog: np.ndarray
    inertia_std: float = 0.0
    body_mass_std: float = 0.0
    cog_cov: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))


@dataclass(frozen=True)
class InertiaFit:
    """The tensor from the swings.

    Attributes
    ----------
    terms : (6,) kg m^2, ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` about the cog.
    cov : (6, 6) kg^2 m^4.
    condition : condition number of the axis set (see module docstring).
    measured : (n,) kg m^2, right-hand sides (inertia about each ``Delta``).
    fitted : (n,) kg m^2, ``u^T I u`` of the estimate.
    row_std : (n,) kg m^2, 1 sigma of each right-hand side.
    variance_factor : see :func:`variance_factor` (1 with 6 swings).
    chi2, dof : misfit against the stated uncertainties.
    """

    terms: np.ndarray
    cov: np.ndarray
    condition: float
    measured: np.ndarray
    fitted: np.ndarray
    row_std: np.ndarray
    variance_factor: float
    chi2: float
    dof: int

    @property
    def inertia(self) -> np.ndarray:
        return inertia_matrix(*self.terms)

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def as_dict(self) -> dict[str, float]:
        return dict(zip(TERMS, self.terms.tolist(), strict=True))


def _right_hand_side(
    swings: tuple[Swing, ...], axes: np.ndarray, plate: Plate | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """y (n,), the total swinging inertia (n,), and the plate distances d^2 (n,)."""
    total = inertia_from_period([s.period for s in swings], [s.stiffness for s in swings])
    if plate is None:
        return total, total, np.zeros(len(swings))
    points = np.array([s.plate_point for s in swings])
    d2 = np.sum(distance_to_axis(plate.cog, points, axes) ** 2, axis=1)
    return total - plate.inertia - plate.body_mass * d2, total, d2


def _row_covariance(
    swings: tuple[Swing, ...],
    axes: np.ndarray,
    total: np.ndarray,
    d2: np.ndarray,
    plate: Plate | None,
    inertia: np.ndarray | None,
    calibration: float = 0.0,
) -> np.ndarray:
    """(n, n) covariance of the right-hand sides (first-order propagation)."""
    n = len(swings)
    period = np.array([s.period for s in swings])
    stiff = np.array([s.stiffness for s in swings])
    # d(C T^2 / 4 pi^2) = total (2 dT / T + dC / C)
    var = (2 * total * np.array([s.period_std for s in swings]) / period) ** 2 + (
        total * np.array([s.stiffness_std for s in swings]) / stiff
    ) ** 2
    cov = np.diag(var)
    # One calibration of the rig's stiffness scales every total inertia together.
    cov += calibration**2 * np.outer(total, total)
    if inertia is not None:
        # An axis turned by delta (perpendicular to u) changes u^T I u + M d^2 by g . delta,
        # g = 2 (I u - M ((G - P') . u) (G - P')); two perpendicular angles of std s each.
        g = 2 * (axes @ inertia)
        if plate is not None:
            r = plate.cog - np.array([s.plate_point for s in swings])
            g = g - 2 * plate.body_mass * np.einsum("ni,ni->n", r, axes)[:, None] * r
        g_perp = g - np.einsum("ni,ni->n", g, axes)[:, None] * axes
        ang = np.array([s.axis_std for s in swings])
        cov += np.diag(ang**2 * np.sum(g_perp**2, axis=1))
    if plate is not None:
        ones = np.ones(n)
        cov += plate.inertia_std**2 * np.outer(ones, ones)
        cov += plate.body_mass_std**2 * np.outer(d2, d2)
        # y = ... - M |P_perp (G - P')|^2: d y / d G = -2 M P_perp (G - P'), shared G.
        offsets = distance_to_axis(plate.cog, np.array([s.plate_point for s in swings]), axes)
        jac_g = -2 * plate.body_mass * offsets
        cov += jac_g @ plate.cog_cov @ jac_g.T
        lateral = np.array([s.plate_point_std for s in swings])
        cov += np.diag((2 * plate.body_mass * lateral) ** 2 * d2)
    return cov


def inertia_from_swings(
    swings: tuple[Swing, ...] | list[Swing],
    plate: Plate | None = None,
    stiffness_calibration: float = 0.0,
) -> InertiaFit:
    """The six inertia terms about the cog from six or more swings (eqs. 7, 8).

    Generalised least squares ``theta = (A^T S^-1 A)^-1 A^T S^-1 y`` with ``S``
    the full covariance of the right-hand sides; with six swings it is the
    exact solution of eq. 7 and ``S`` only sets the covariance.

    Parameters
    ----------
    swings : at least 6 configurations.
    plate : the rolling plate (eq. 8); None for the classic pendulum (eq. 7).
    stiffness_calibration : relative 1 sigma of a stiffness calibration shared by every
        swing (one rig); ``Swing.stiffness_std`` is the independent part.

    Raises
    ------
    PendulumError
        Degenerate axis set (see :func:`check_axis_set`), or a rolling plate
        configuration without ``plate_point``.
    """
    swings = tuple(swings)
    axes = unit_axes([s.axis for s in swings])
    cond = check_axis_set(axes)
    if plate is not None:
        missing = [s.name or str(i + 1) for i, s in enumerate(swings) if s.plate_point is None]
        if missing:
            raise PendulumError(
                f"rolling plate: configurations {missing} have no plate_point (a point of "
                "the pivot axis) for the M d(G, Delta')^2 term"
            )
    a = quadratic_rows(axes)
    y, total, d2 = _right_hand_side(swings, axes, plate)
    inertia = None
    # Pass 1 weighs by period and stiffness only; pass 2 adds the axis-angle term, which
    # needs the tensor itself (I u), taken from pass 1.
    for _ in range(2):
        cov_y = _row_covariance(swings, axes, total, d2, plate, inertia, stiffness_calibration)
        if not np.all(np.isfinite(cov_y)) or np.linalg.eigvalsh(cov_y)[0] <= 0:
            # Exact data (no stated uncertainty): ordinary least squares, unit weights.
            cov_y = cov_y + np.eye(len(y)) * max(1e-30, 1e-12 * float(np.max(np.abs(y))) ** 2)
        chol = np.linalg.cholesky(cov_y)
        aw = np.linalg.solve(chol, a)
        yw = np.linalg.solve(chol, y)
        theta, *_ = np.linalg.lstsq(aw, yw, rcond=None)
        inertia = inertia_matrix(*theta)
    normal_inv = np.linalg.inv(aw.T @ aw)
    resid = yw - aw @ theta
    dof = len(y) - 6
    chi2 = float(resid @ resid)
    factor = variance_factor(chi2, dof)
    return InertiaFit(
        terms=theta,
        cov=normal_inv * factor,
        condition=cond,
        measured=y,
        fitted=a @ theta,
        row_std=np.sqrt(np.diag(cov_y)),
        variance_factor=factor,
        chi2=chi2,
        dof=dof,
    )
