"""Intervals of derived quantities: principal moments and axes, rigid-body mode frequencies.

The estimator gives the covariance of the parameters (inertia terms, cog, mass);
principal moments, principal axes and mode frequencies are nonlinear in them, so
their 95 % intervals are propagated by sampling: draw the parameters from their
Gaussian, recompute, take percentiles. Sampling needs no derivative and stays
right where a first-order formula fails (near-equal principal moments make the
axes ill-defined, which shows as a wide cone instead of a wrong number). A fixed
seed keeps a report reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator.result import Z95
from powertrain.mounted import Mount, MountedPowertrain
from powertrain.rigidbody import TERMS, RigidBody, consistency_problems

COG = ("Gx", "Gy", "Gz")


def tensors(terms: np.ndarray) -> np.ndarray:
    """(..., 3, 3) tensors from (..., 6) ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` (products as integral(x y dm))."""
    t = np.asarray(terms, float)
    out = np.empty((*t.shape[:-1], 3, 3))
    out[..., 0, 0], out[..., 1, 1], out[..., 2, 2] = t[..., 0], t[..., 1], t[..., 2]
    out[..., 0, 1] = out[..., 1, 0] = -t[..., 3]
    out[..., 0, 2] = out[..., 2, 0] = -t[..., 4]
    out[..., 1, 2] = out[..., 2, 1] = -t[..., 5]
    return out


@dataclass(frozen=True)
class ParameterCovariance:
    """Values and covariance of ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz, Gx, Gy, Gz]`` (+ ``mass`` if estimated).

    ``correlated`` is False when only standard deviations were available (a result
    document): the intervals then ignore correlations.
    """

    names: tuple[str, ...]
    value: np.ndarray
    cov: np.ndarray
    correlated: bool


def parameter_covariance(doc: dict[str, Any], final: Any = None) -> ParameterCovariance:
    """From the final estimate's full covariance when given, else from the document's stds.

    Parameters
    ----------
    doc : the result document.
    final : ``estimator.result.Estimate`` or None.
    """
    names = [*TERMS, *COG]
    mass = doc.get("mass_kg")
    if mass and mass.get("std") is not None:
        names.append("mass")
    if final is not None:
        idx = [final.names.index(n) for n in names if n != "mass"]
        value = [float(final.theta[i]) for i in idx]
        cov = np.array(final.cov[np.ix_(idx, idx)], float)
        if "mass" in names:
            i_mu = final.names.index("inv_mass")
            mu = float(final.theta[i_mu])
            # m = 1 / mu: d m / d mu = -1 / mu^2 (delta method for the mass row and column)
            grad = -1.0 / mu**2
            full = np.zeros((len(names), len(names)))
            full[:-1, :-1] = cov
            cross = np.array(final.cov[np.ix_(idx, [i_mu])], float)[:, 0] * grad
            full[:-1, -1] = full[-1, :-1] = cross
            full[-1, -1] = float(final.cov[i_mu, i_mu]) * grad**2
            cov = full
            value.append(1.0 / mu)
        cov = np.where(np.isfinite(cov), cov, 0.0)
        return ParameterCovariance(tuple(names), np.array(value), cov, True)
    inertia = doc["inertia_kgm2"]
    value = [inertia["value"][k] for k in TERMS] + list(doc["cog_m"]["value"])
    std = [inertia["std"][k] for k in TERMS] + list(doc["cog_m"]["std"])
    if mass and "mass" in names:
        value.append(mass["value"])
        std.append(mass["std"])
    s = np.array([0.0 if v is None else float(v) for v in std])
    return ParameterCovariance(tuple(names), np.array(value, float), np.diag(s**2), False)


@dataclass(frozen=True)
class PrincipalStats:
    """Principal moments (ascending) and axes with their 95 % intervals.

    Attributes
    ----------
    moments : (3,) kg m^2; moments_ci95 : (3, 2) kg m^2.
    axes : (3, 3) rows = unit principal axes, bench frame (right-handed).
    cone95_deg : (3,) half-angle of the cone holding 95 % of the sampled axes, deg.
    """

    moments: np.ndarray
    moments_ci95: np.ndarray
    axes: np.ndarray
    cone95_deg: np.ndarray


def _principal(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    moments, vec = np.linalg.eigh(inertia)
    flip = np.linalg.det(vec) < 0
    vec[..., :, 2] = np.where(flip[..., None], -vec[..., :, 2], vec[..., :, 2])
    return moments, vec


def principal_stats(
    terms: np.ndarray, cov: np.ndarray, samples: int = 4000, seed: int = 0
) -> PrincipalStats:
    """Principal moments and axes of the tensor of ``terms`` (6,), intervals from ``cov`` (6, 6)."""
    terms = np.asarray(terms, float)
    moments, vec = _principal(tensors(terms))
    rng = np.random.default_rng(seed)
    draws = rng.multivariate_normal(terms, np.asarray(cov, float), size=samples, method="eigh")
    m_s, v_s = _principal(tensors(draws))
    ci = np.percentile(m_s, [2.5, 97.5], axis=0).T
    # angle between each sampled axis and the nominal one (an axis has no sign)
    cos = np.abs(np.einsum("sik,ik->sk", v_s, vec))
    cone = np.degrees(np.arccos(np.clip(np.percentile(cos, 5, axis=0), -1.0, 1.0)))
    return PrincipalStats(moments, ci, vec.T.copy(), cone)


@dataclass(frozen=True)
class ModeStats:
    """Rigid-body modes of the estimated body on the bench's mounts.

    Attributes
    ----------
    frequency_hz : (6,) undamped, zero speed; frequency_ci95 : (6, 2) by rank.
    energy : (6, 6) kinetic energy share per DOF (rows) of each mode (columns).
    labels : DOF names; dominant : per mode, the DOF with most energy.
    """

    frequency_hz: np.ndarray
    frequency_ci95: np.ndarray
    energy: np.ndarray
    labels: tuple[str, ...]
    dominant: tuple[str, ...]


def mode_stats(
    body: RigidBody,
    mounts: tuple[Mount, ...],
    spin_inertia: float,
    spin_axis: np.ndarray,
    pc: ParameterCovariance | None,
    samples: int = 300,
    seed: int = 0,
) -> ModeStats:
    """Modes of ``body`` on ``mounts``; intervals by sampling the estimate (``pc``) when given."""
    modes = MountedPowertrain(body, mounts, spin_inertia, spin_axis).modes()
    ci = np.full((6, 2), np.nan)
    if pc is not None and samples > 0:
        rng = np.random.default_rng(seed)
        draws = rng.multivariate_normal(pc.value, pc.cov, size=samples, method="eigh")
        freqs = []
        for d in draws:
            inertia = tensors(d[:6])
            if consistency_problems(inertia):
                continue  # a draw no real body has: it has no modes either
            mass = float(d[9]) if "mass" in pc.names else body.mass
            if mass <= 0:
                continue
            sample = RigidBody(mass, d[6:9], inertia)
            freqs.append(MountedPowertrain(sample, mounts).modes().frequency_hz)
        if len(freqs) >= 20:
            ci = np.percentile(np.array(freqs), [2.5, 97.5], axis=0).T
    return ModeStats(
        modes.frequency_hz, ci, modes.energy, tuple(modes.labels), tuple(modes.dominant())
    )


def interval(value: float, std: float | None) -> tuple[float, float] | None:
    """``value +- 1.96 std`` (None when the std is unknown or infinite)."""
    if std is None or not np.isfinite(std):
        return None
    return value - Z95 * std, value + Z95 * std
