"""Rigid body from the mass line: mass, cog and inertia fitted to the constants ``A0``.

The second half of the modal mass-line method (:mod:`estimator.classical.massline`), after the
band and the per-FRF fit of :mod:`estimator.classical.massline_band`. It is its own module
because the fit, its linear start and its uncertainty (random, and the declared
set-up tolerances propagated through the model) form one unit that needs no FRFs.

``m``, ``G`` and the six inertia terms are fitted to all ``A0`` at once
(weighted Gauss-Newton, complex-step Jacobian), starting from the linear
two-step solution (rigid motion per excitation, then eq. 12 linear in
``1/m``, ``G``, ``I``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from estimator.classical.massline_band import FrfGeometry, MassLineError, mass_line_accelerance
from estimator.equations import inertia_columns
from powertrain.rigidbody import consistency_problems, inertia_matrix, rotation_matrix, skew
from powertrain.sensors import rigid_channel_matrix

PARAMETERS = ("mass", "Gx", "Gy", "Gz", "Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
#: a rigid body is refused when the mass-line constants are further than this from it
#: (relative rms)
MAX_RIGID_MISFIT = 0.05


@dataclass(frozen=True)
class MassLineTolerances:
    """Declared 1-sigma uncertainties of the set-up, propagated into the intervals (type B).

    ``force_gain`` is one calibration shared by every hit; the others are
    independent per hit, per channel or per sensor.
    """

    force_gain_rel: float = 0.0
    hit_position_m: float = 0.0
    hit_direction_rad: float = 0.0
    sensor_gain_rel: float = 0.0
    sensor_position_m: float = 0.0
    sensor_alignment_rad: float = 0.0


@dataclass(frozen=True)
class RigidBodyFit:
    """Mass, cog and inertia from the mass-line constants.

    Attributes
    ----------
    theta : (10,) ``[m, Gx, Gy, Gz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` (kg, m, kg m^2).
    cov : (10, 10) random + systematic.
    cov_random, cov_systematic : (10, 10).
    variance_factor : ``max(1, chi2 / dof)`` applied to the random part.
    chi2, dof : weighted misfit of ``A0`` against the rigid body.
    rigid_misfit : relative rms misfit of ``A0``.
    iterations : Gauss-Newton steps.
    """

    theta: np.ndarray
    cov: np.ndarray
    cov_random: np.ndarray
    cov_systematic: np.ndarray
    variance_factor: float
    chi2: float
    dof: int
    rigid_misfit: float
    iterations: int

    @property
    def mass(self) -> float:
        return float(self.theta[0])

    @property
    def cog(self) -> np.ndarray:
        return self.theta[1:4].copy()

    @property
    def terms(self) -> np.ndarray:
        return self.theta[4:].copy()

    @property
    def inertia(self) -> np.ndarray:
        return inertia_matrix(*self.theta[4:])

    @property
    def std(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))


def _model(theta: np.ndarray, geometry: FrfGeometry) -> np.ndarray:
    m, g, t = theta[0], theta[1:4], theta[4:]
    ixx, iyy, izz, ixy, ixz, iyz = t
    inertia = np.array([[ixx, -ixy, -ixz], [-ixy, iyy, -iyz], [-ixz, -iyz, izz]])
    return mass_line_accelerance(m, g, inertia, geometry)


def _jacobian(theta: np.ndarray, geometry: FrfGeometry) -> np.ndarray:
    """(n_ch n_e, 10) by complex step: exact to rounding, no step-size trade-off."""
    cols = []
    for k in range(len(theta)):
        step = 1e-30 * max(abs(theta[k]), 1.0)
        t = theta.astype(complex)
        t[k] += 1j * step
        cols.append(_model(t, geometry).imag.ravel() / step)
    return np.array(cols).T


def linear_start(a0: np.ndarray, geometry: FrfGeometry) -> np.ndarray:
    """The linear two-step solution, ``theta`` (10,): rigid motion per hit, then eq. 12.

    Per hit (unit force ``f`` at ``a``), with ``gamma_O``, ``Omega'`` fitted about O::

        skew(Omega') G - (1/m) f = skew(Omega') O - gamma_O       (translation)
        I Omega' - skew(f) G     = a x f                          (rotation about G)

    both linear in ``(1/m, G, I)``.
    """
    o = geometry.channel_positions.mean(axis=0)
    rigid = rigid_channel_matrix(geometry.channel_positions, geometry.channel_directions, o)
    sv = np.linalg.svd(rigid, compute_uv=False)
    if len(sv) < 6 or sv[-1] < 1e-6 * sv[0]:
        raise MassLineError(
            f"the {len(rigid)} response channels cannot determine the 6 rigid-body motions: "
            "need three non-collinear triaxial sensors (or equivalent axes)"
        )
    motion, *_ = np.linalg.lstsq(rigid, a0, rcond=None)  # (6, n_e): [gamma_O; Omega'] per hit
    rows, rhs = [], []
    for e in range(a0.shape[1]):
        gam, om = motion[:3, e], motion[3:, e]
        f, a = geometry.force_directions[e], geometry.force_positions[e]
        trans = np.zeros((3, 10))
        trans[:, 0] = -f
        trans[:, 1:4] = skew(om)
        rot = np.zeros((3, 10))
        rot[:, 1:4] = -skew(f)
        rot[:, 4:] = inertia_columns(om)
        rows += [trans, rot]
        rhs += [skew(om) @ o - gam, np.cross(a, f)]
    x = np.vstack(rows)
    y = np.concatenate(rhs)
    scale = np.maximum(np.linalg.norm(x, axis=0), 1e-300)
    sol, *_ = np.linalg.lstsq(x / scale, y, rcond=None)
    sol = sol / scale
    if not sol[0] > 0:
        raise MassLineError(
            f"the mass-line accelerances give 1/m = {sol[0]:.4g} 1/kg (not positive): check the "
            "force directions (sign of the reference direction) and the FRF units"
        )
    return np.concatenate([[1.0 / sol[0]], sol[1:]])


def _perturbations(
    geometry: FrfGeometry, tol: MassLineTolerances
) -> list[tuple[float, Callable[[float], FrfGeometry]]]:
    """(sigma, geometry as a function of the perturbation) for each uncertain input."""
    out: list[tuple[float, Callable[[float], FrfGeometry]]] = []

    def replace(**kw: np.ndarray) -> FrfGeometry:
        args = {
            "channel_positions": geometry.channel_positions,
            "channel_directions": geometry.channel_directions,
            "force_positions": geometry.force_positions,
            "force_directions": geometry.force_directions,
            "channel_names": geometry.channel_names,
            "excitation_names": geometry.excitation_names,
            "channel_sensor": geometry.channel_sensor,
        }
        args.update(kw)
        return FrfGeometry(**args)  # type: ignore[arg-type]

    n_e = len(geometry.force_positions)
    if tol.hit_position_m > 0:
        for e in range(n_e):
            for axis in range(3):

                def fp(x: float, e: int = e, axis: int = axis) -> FrfGeometry:
                    p = geometry.force_positions.copy()
                    p[e, axis] += x
                    return replace(force_positions=p)

                out.append((tol.hit_position_m, fp))
    if tol.hit_direction_rad > 0:
        for e in range(n_e):
            f = geometry.force_directions[e]
            helper = np.eye(3)[int(np.argmin(np.abs(f)))]
            perp1 = np.cross(f, helper)
            perp1 /= np.linalg.norm(perp1)
            for turn in (perp1, np.cross(f, perp1)):

                def fd(x: float, e: int = e, turn: np.ndarray = turn) -> FrfGeometry:
                    d = geometry.force_directions.copy()
                    d[e] = rotation_matrix(turn, x) @ d[e]
                    return replace(force_directions=d)

                out.append((tol.hit_direction_rad, fd))
    sensors = np.unique(geometry.channel_sensor)
    if tol.sensor_position_m > 0:
        for s in sensors:
            for axis in range(3):

                def sp(x: float, s: int = int(s), axis: int = axis) -> FrfGeometry:
                    p = geometry.channel_positions.copy()
                    p[geometry.channel_sensor == s, axis] += x
                    return replace(channel_positions=p)

                out.append((tol.sensor_position_m, sp))
    if tol.sensor_alignment_rad > 0:
        for s in sensors:
            for turn in np.eye(3):

                def sa(x: float, s: int = int(s), turn: np.ndarray = turn) -> FrfGeometry:
                    d = geometry.channel_directions.copy()
                    mask = geometry.channel_sensor == s
                    d[mask] = d[mask] @ rotation_matrix(turn, x).T
                    return replace(channel_directions=d)

                out.append((tol.sensor_alignment_rad, sa))
    return out


def rigid_body_from_mass_line(
    a0: npt.ArrayLike,
    a0_std: npt.ArrayLike,
    geometry: FrfGeometry,
    tolerances: MassLineTolerances | None = None,
    max_iterations: int = 50,
) -> RigidBodyFit:
    """Mass, cog and inertia fitted to the mass-line constants of all hits at once (eq. 13).

    Weighted Gauss-Newton on ``A0 = T_ch M_G^-1 T_f^T`` from :func:`linear_start`.
    Random covariance ``s^2 (J^T W J)^-1`` with ``s^2 = max(1, chi2 / dof)``;
    systematic covariance from ``tolerances`` through the sensitivity
    ``d theta / d p = -(J^T W J)^-1 J^T W d model / d p``.

    Three excitations at least: the rotation equations of two hits,
    ``I Omega'_k = GA_k x f_k``, hold for ``I + c n n^T`` too (``n`` normal to
    both angular accelerations), so two hits leave the tensor one term short
    (the paper's "two force directions" gives mass and cog, not all of ``I``).

    Raises
    ------
    MassLineError
        Fewer than 3 excitations, geometry that cannot determine the 10
        parameters, a non-physical result, or constants no rigid body explains
        (relative misfit above ``MAX_RIGID_MISFIT``).
    """
    a0 = np.asarray(a0, dtype=float)
    std = np.asarray(a0_std, dtype=float)
    tol = tolerances or MassLineTolerances()
    n_ch, n_e = a0.shape
    if a0.size < 10 or n_e < 3:
        raise MassLineError(
            f"{n_ch} channels x {n_e} excitations: need at least 3 excitations for mass, cog "
            "and inertia (two leave the tensor undetermined by c n n^T, n normal to both "
            "angular accelerations)"
        )
    floor = 1e-9 * float(np.max(np.abs(a0)))
    w = 1.0 / np.maximum(std, floor).ravel()
    theta = linear_start(a0, geometry)
    sv = np.linalg.svd(_jacobian(theta, geometry) * w[:, None], compute_uv=False)
    if sv[-1] < 1e-10 * sv[0]:
        raise MassLineError(
            f"the {n_e} excitations and {n_ch} channels cannot separate mass, cog and inertia "
            f"(condition {sv[0] / max(sv[-1], 1e-300):.3g}): the tensor needs hits whose angular "
            "accelerations span all three directions (hit at more points, in more directions)"
        )
    iterations = 0
    while iterations < max_iterations:
        iterations += 1
        r = (_model(theta, geometry).real.ravel() - a0.ravel()) * w
        jw = _jacobian(theta, geometry) * w[:, None]
        step, *_ = np.linalg.lstsq(jw, -r, rcond=None)
        theta = theta + step
        scale = np.abs(theta) + np.r_[1.0, 0.1, 0.1, 0.1, np.full(6, np.abs(theta[4:7]).max())]
        if np.all(np.abs(step) <= 1e-12 * scale):
            break
    jw = _jacobian(theta, geometry) * w[:, None]
    model = _model(theta, geometry).real
    r = (model.ravel() - a0.ravel()) * w
    dof = a0.size - len(theta)
    chi2 = float(r @ r)
    misfit = float(np.sqrt(np.sum((model - a0) ** 2) / max(np.sum(a0**2), 1e-300)))
    if misfit > MAX_RIGID_MISFIT:
        raise MassLineError(
            f"the mass-line constants are not those of one rigid body ({100 * misfit:.1f} % "
            f"misfit, limit {100 * MAX_RIGID_MISFIT:.0f} %): band above an elastic mode, or a "
            "point or direction of the set-up is wrong"
        )
    problems = consistency_problems(inertia_matrix(*theta[4:]))
    if not theta[0] > 0 or problems:
        raise MassLineError(
            f"the mass-line fit gives no physical body (mass {theta[0]:.4g} kg"
            + (f", {problems[0]}" if problems else "")
            + ")"
        )
    normal_inv = np.linalg.inv(jw.T @ jw)
    factor = max(1.0, chi2 / dof) if dof > 0 else 1.0
    cov_random = normal_inv * factor
    # Systematic part: each uncertain input moves the model; the fit follows by
    # d theta = -(J^T W J)^-1 J^T W d model.
    gain = normal_inv @ jw.T  # (10, n) maps weighted residual changes to theta
    sens = []
    for sigma, perturbed in _perturbations(geometry, tol):
        h = 1e-6
        dm = (_model(theta, perturbed(h)).real - _model(theta, perturbed(-h)).real) / (2 * h)
        sens.append(-gain @ (dm.ravel() * w) * sigma)
    if tol.force_gain_rel > 0:
        # Gauge reads (1 + g) F: every accelerance is low by (1 + g), mass and inertia high.
        sens.append(-gain @ (-model.ravel() * w) * tol.force_gain_rel)
    if tol.sensor_gain_rel > 0:
        for c in range(n_ch):
            dm = np.zeros_like(model)
            dm[c] = model[c]
            sens.append(-gain @ (dm.ravel() * w) * tol.sensor_gain_rel)
    s = np.array(sens).T if sens else np.zeros((len(theta), 0))
    cov_sys = s @ s.T
    return RigidBodyFit(
        theta=theta,
        cov=cov_random + cov_sys,
        cov_random=cov_random,
        cov_systematic=cov_sys,
        variance_factor=factor,
        chi2=chi2,
        dof=dof,
        rigid_misfit=misfit,
        iterations=iterations,
    )
