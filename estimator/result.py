"""The final estimate: values, covariance, physical consistency, the result JSON.

Covariance = random part + systematic part:

* random: ``s^2 Lambda^-1`` with ``s^2 = max(1, rss / dof)`` (a posteriori
  variance factor: model misfit beyond the measured noise widens it, never
  narrows it);
* systematic: ``Lambda^-1 S diag(tol^2) S^T Lambda^-1`` from the declared
  sensor tolerances (see :mod:`estimator.streaming`).

95 % intervals are ``value +- 1.96 std``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimator.equations import INERTIA_TERMS
from estimator.hypotheses import Accumulator
from estimator.rls import RlsSolution
from estimator.setup import EstimatorSetup
from estimator.unbalance import unbalance_report

Z95 = 1.959963984540054
RATIO_CAP = 1e12  # what the result JSON writes for an infinite residual ratio


def tensor_from_terms(terms: np.ndarray) -> np.ndarray:
    """(3, 3) tensor from ``[Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`` (products as integral(x y dm))."""
    ixx, iyy, izz, ixy, ixz, iyz = terms
    return np.array([[ixx, -ixy, -ixz], [-ixy, iyy, -iyz], [-ixz, -iyz, izz]])


def principal_axes(inertia: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Principal moments (ascending) and axes (columns, right-handed)."""
    moments, axes = np.linalg.eigh(inertia)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1
    return moments, axes


def enforce_physical(inertia: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Nearest tensor with positive principal moments obeying the triangle inequality.

    Returns the (possibly) corrected tensor and the list of problems found.
    """
    moments, axes = principal_axes(inertia)
    problems: list[str] = []
    fixed = moments.copy()
    if fixed[0] <= 0:
        problems.append(f"not positive definite (smallest principal moment {fixed[0]:.4g} kg m^2)")
        fixed = np.maximum(fixed, 1e-6 * max(fixed[-1], 1e-9))
    if fixed[0] + fixed[1] < fixed[2]:
        problems.append(f"principal moments {np.round(moments, 4).tolist()} violate I1 + I2 >= I3")
        # Smallest change in the sum of squares: move the excess equally.
        excess = (fixed[2] - fixed[0] - fixed[1]) / 3
        fixed = fixed + np.array([excess, excess, -excess])
    if not problems:
        return inertia, problems
    return (axes * fixed) @ axes.T, problems


def _vs(value: float, std: float) -> dict[str, Any]:
    return {"value": float(value), "std": float(std) if math.isfinite(std) else None}


@dataclass
class EstimatorStats:
    """The streaming estimator's frame bookkeeping, as the estimate reports it."""

    used: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    orders_rejected: Counter[str] = field(default_factory=Counter)
    rpm_lo: float = float("inf")
    rpm_hi: float = float("-inf")
    ambiguous_frames: int = 0  # frames whose half-order sign the residual test judged
    referenced_frames: int = 0  # those of them with a 720 deg reference (the test checks it)
    # overlapping frames left out (not rejected: their data are in their neighbours)
    skipped: int = 0

    def count_used(self, rpm: float, tested: bool, referenced: bool) -> None:
        """One more used frame at ``rpm``; ``tested``: its half-order sign judged by the
        residual test, ``referenced``: with a 720 deg reference the test checks."""
        self.used += 1
        # (comparisons, not int(), min() and max(): four builtin calls a frame; a used
        # frame's rpm is finite, so the range is the same)
        if tested:
            self.ambiguous_frames += 1
        if referenced:
            self.referenced_frames += 1
        if rpm < self.rpm_lo:
            self.rpm_lo = rpm
        if rpm > self.rpm_hi:
            self.rpm_hi = rpm


@dataclass(frozen=True)
class Estimate:
    """Estimated parameters with covariance and bookkeeping."""

    names: tuple[str, ...]
    theta: np.ndarray
    cov: np.ndarray
    cov_random: np.ndarray
    cov_systematic: np.ndarray
    observable: np.ndarray
    mass_known: bool
    mass_nominal: float
    unbalance_point: np.ndarray
    frames_used: int
    frames_skipped: int
    frames_rejected: dict[str, int]
    orders_rejected: dict[str, int]
    rpm_range: tuple[float, float] | None
    half_order: dict[str, Any] | None
    variance_factor: float
    # the elastic mode the residual gate confirmed (order, frequency_hz where it was
    # confirmed), when the f^2 tail was fitted out; None otherwise
    elastic_mode: dict[str, float] | None = None
    # frames fitted with one rigid-body motion unseen (two sensors): how they were used
    unseen_motion: dict[str, Any] | None = None
    # each channel's weight in the rigid fit when measured from its noise (median 1)
    channel_weights: dict[str, float] | None = None
    # the fit's chi-square per dof far above 1 (estimator.misfit): where, and the
    # likely inputs; None when the model fits
    misfit: dict[str, Any] | None = None
    # (3,) the crank axis s, along which the unbalance is located (None: not known, as
    # in recordings made before it was recorded: the location is then left out)
    crank_axis: np.ndarray | None = None

    @property
    def consistent(self) -> bool:
        """The model fits the data and the tensor is physical: an estimate to stand behind."""
        return (
            self.misfit is None
            and not enforce_physical(self.inertia)[1]
            and not (self.half_order or {}).get("reference_doubtful", False)
        )

    def std(self, name: str) -> float:
        i = self.names.index(name)
        return float(np.sqrt(self.cov[i, i])) if self.observable[i] else float("inf")

    def value(self, name: str) -> float:
        return float(self.theta[self.names.index(name)])

    @property
    def inertia(self) -> np.ndarray:
        return tensor_from_terms(self.theta[:6])

    @property
    def cog(self) -> np.ndarray:
        return self.theta[6:9].copy()

    @property
    def usable(self) -> bool:
        return self.frames_used > 0 and bool(np.any(self.observable[:9]))

    def mass(self) -> tuple[float, float] | None:
        if self.mass_known or "inv_mass" not in self.names:
            return None
        i = self.names.index("inv_mass")
        mu = self.theta[i]
        if not self.observable[i] or mu <= 0:
            return None
        return 1.0 / mu, math.sqrt(self.cov[i, i]) / mu**2

    def unbalance(self) -> dict[str, Any] | None:
        """The residual unbalance (:func:`unbalance_report`), None when not estimated."""
        if "unb_re" not in self.names:
            return None
        idx = [self.names.index(n) for n in ("unb_re", "unb_im")]
        if not np.all(self.observable[idx]):
            return None
        couple = "unb_couple_re" in self.names and all(
            self.observable[self.names.index(n)] for n in ("unb_couple_re", "unb_couple_im")
        )
        if couple:
            idx += [self.names.index("unb_couple_re"), self.names.index("unb_couple_im")]
        mass = None if self.mass_known else self.mass()
        if mass is not None:  # the static part is z / m: carry 1/m's uncertainty too
            idx.append(self.names.index("inv_mass"))
        return unbalance_report(
            self.theta[idx],
            self.cov[np.ix_(idx, idx)],
            couple,
            mass is not None,
            self.unbalance_point,
            self.crank_axis,
        )

    def to_json(self, truth: dict[str, Any] | None = None) -> dict[str, Any]:
        """The result document of ``ptinertia run --json`` (see README)."""
        terms = {name: _vs(self.value(name), self.std(name)) for name in INERTIA_TERMS}
        unobservable = [n for n, ok in zip(self.names, self.observable, strict=True) if not ok]
        inertia, problems = enforce_physical(self.inertia)
        moments, axes = principal_axes(inertia)
        mass = self.mass()
        doc: dict[str, Any] = {
            "inertia_kgm2": {
                "value": {k: v["value"] for k, v in terms.items()},
                "std": {k: v["std"] for k, v in terms.items()},
                "ci95": {
                    k: (
                        [v["value"] - Z95 * v["std"], v["value"] + Z95 * v["std"]]
                        if v["std"] is not None
                        else None
                    )
                    for k, v in terms.items()
                },
            },
            "cog_m": {
                "value": [self.value(n) for n in ("Gx", "Gy", "Gz")],
                "std": [_finite(self.std(n)) for n in ("Gx", "Gy", "Gz")],
            },
            "mass_kg": None if mass is None else {"value": mass[0], "std": mass[1]},
            "unbalance": self.unbalance(),
            "crank_offset_deg": (
                _vs(
                    math.degrees(self.value("crank_offset")), math.degrees(self.std("crank_offset"))
                )
                if "crank_offset" in self.names
                and self.observable[self.names.index("crank_offset")]
                else None
            ),
            "principal": {
                "moments_kgm2": moments.tolist(),
                "axes": axes.T.tolist(),
                "consistency": {"problems": problems, "enforced": bool(problems)},
            },
            "frames": {
                "used": self.frames_used,
                "skipped_overlapping": self.frames_skipped,
                "rejected": dict(sorted(self.frames_rejected.items())),
                "orders_rejected": dict(sorted(self.orders_rejected.items())),
            },
            "rpm_range": list(self.rpm_range) if self.rpm_range else None,
            "mount_stiffness_scale": {
                n.split(":", 1)[1]: _vs(self.value(n), self.std(n))
                for n in self.names
                if n.startswith("kscale:")
            }
            or None,
            "half_order": (
                None
                if self.half_order is None
                else {
                    **self.half_order,
                    "residual_ratio": capped_ratio(self.half_order["residual_ratio"]),
                }
            ),
            "elastic_mode": (
                None
                if self.elastic_mode is None
                else {
                    **self.elastic_mode,
                    "correction": "inertia and cog fitted as theta + (f / 100 Hz)^2 a, "
                    "theta (extrapolated to 0 Hz) reported",
                }
            ),
            "unobservable": unobservable,
            "variance_factor": self.variance_factor,
            # false: the model misfits grossly ("misfit"), the tensor is not physical
            # ("principal"/"consistency") or the half-order test leans against the phase
            # reference ("half_order"/"reference_doubtful"): not an estimate to stand behind
            "consistent": self.consistent,
            "misfit": self.misfit,
        }
        if self.unseen_motion is not None:
            doc["unseen_motion"] = self.unseen_motion
        if self.channel_weights is not None:
            doc["channel_weights"] = self.channel_weights
        if truth is not None:
            doc["truth"] = truth
        return doc


@dataclass(frozen=True)
class EstimateUpdate:
    """The running estimate after a used frame: time (s) and rpm of that frame, and the estimate.

    The pipeline publishes it to its sinks; a recording stores it on ``/estimate``
    and gives it back (``replay``). It lives with :class:`Estimate`, below both.
    """

    time_s: float
    rpm: float
    estimate: Estimate


def capped_ratio(ratio: float | None) -> float | None:
    """A residual ratio for the result JSON, which allows no infinities: capped at 1e12.

    The ratio of the losing half-order hypothesis's residual to the winner's is
    infinite when the winner fits exactly (noise-free data); 1e12 says the same.
    """
    return None if ratio is None else min(float(ratio), RATIO_CAP)


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def build_estimate(
    acc: Accumulator,
    sol: RlsSolution,
    sys_std: np.ndarray,
    names: tuple[str, ...],
    setup: EstimatorSetup,
    stats: EstimatorStats,
    half_order: dict[str, Any] | None = None,
    elastic_mode: dict[str, float] | None = None,
    unseen_motion: dict[str, Any] | None = None,
    channel_weights: dict[str, float] | None = None,
    misfit: dict[str, Any] | None = None,
) -> Estimate:
    """The estimate of a solved state: ``acc`` the state (its ``sens`` the systematic
    sensitivity ``S``), ``sol`` its solution, ``sys_std`` (n_sys,) the declared
    tolerances; the rest is reported as given."""
    n = len(names)
    obs = sol.observable
    factor = max(1.0, sol.rss / sol.dof) if sol.dof > 0 else 1.0
    if obs.all():
        # every parameter observable (the common case): the products below on the
        # arrays the blocks would copy, as they are (C order: the same bits)
        cov_rand = sol.cov * factor
        inv = np.ascontiguousarray(sol.cov)
        dtheta = -inv @ np.ascontiguousarray(acc.sens)  # (n, n_sys): d theta / d p
        cov_sys = (dtheta * sys_std**2) @ dtheta.T
    else:
        cov_rand = sol.cov.copy()
        block = np.ix_(obs, obs)
        cov_rand[block] *= factor
        cov_sys = np.zeros((n, n))
        if np.any(obs):
            inv = sol.cov[block]
            dtheta = -inv @ acc.sens[obs]  # (n_obs, n_sys): d theta / d p
            cov_sys[block] = (dtheta * sys_std**2) @ dtheta.T
    return Estimate(
        names=names,
        theta=sol.theta,
        cov=cov_rand + cov_sys,
        cov_random=cov_rand,
        cov_systematic=cov_sys,
        observable=obs,
        mass_known=setup.mass_known,
        mass_nominal=setup.mass_nominal,
        unbalance_point=np.asarray(setup.unbalance_point, float),
        crank_axis=np.asarray(setup.crank_axis, float),
        frames_used=stats.used,
        frames_skipped=stats.skipped,
        frames_rejected=dict(stats.rejected),
        orders_rejected=dict(stats.orders_rejected),
        rpm_range=(stats.rpm_lo, stats.rpm_hi) if stats.used else None,
        half_order=half_order,
        variance_factor=factor,
        elastic_mode=elastic_mode,
        unseen_motion=unseen_motion,
        channel_weights=channel_weights,
        misfit=misfit,
    )
