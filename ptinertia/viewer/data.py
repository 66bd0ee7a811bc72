"""What the view plots, as arrays: estimates with their bands, the truth, batched frame rows.

Pure numpy (no Rerun), so the numbers that reach the plots are tested directly.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from estimator.result import Estimate
from powertrain.rigidbody import TERMS
from ptinertia.viewer import layout as lay

BAND_K = 2.0  # the bands are value +- 2 sigma
CORE = TERMS + lay.COG_TERMS
NAN2 = (math.nan, math.nan)


def _sqrt(var: float) -> float:
    return math.sqrt(var) if var >= 0 else math.nan


def _guarded(fn: Callable[[], Any]) -> Any:
    """``fn()``, or None when a broken covariance makes it fail (``math.sqrt`` of a negative
    variance): the view shows a gap there rather than stopping the run."""
    try:
        return fn()
    except (ValueError, ZeroDivisionError, FloatingPointError):
        return None


def extra_values(estimate: Estimate, extras: Sequence[str]) -> dict[str, tuple[float, float]]:
    """``name -> (value, std)`` of the extras asked for; NaN where not observable.

    ``mass`` (kg, when estimated), ``crank_offset`` (deg), ``unbalance`` (``m r``, kg m).
    """
    out: dict[str, tuple[float, float]] = {}
    if "mass" in extras:
        mass = _guarded(estimate.mass)
        out["mass"] = mass if mass is not None else NAN2
    if "crank_offset" in extras:
        out["crank_offset"] = NAN2
        if "crank_offset" in estimate.names:
            i = estimate.names.index("crank_offset")
            if estimate.observable[i]:
                std = _sqrt(float(estimate.cov[i, i]))
                out["crank_offset"] = (math.degrees(estimate.theta[i]), math.degrees(std))
    if "unbalance" in extras:
        unb = _guarded(estimate.unbalance)
        mr = None if unb is None else unb["mr_kgm"]
        out["unbalance"] = NAN2 if mr is None else (mr["value"], mr["std"] or math.nan)
    return out


def estimate_rows(estimate: Estimate, extras: Sequence[str] = ()) -> dict[str, tuple[float, float]]:
    """``name -> (value, std)`` of every plotted quantity of one estimate (NaN: not observable).

    The six inertia terms (kg m^2), ``Gx Gy Gz`` (m), then :func:`extra_values`.
    """
    out: dict[str, tuple[float, float]] = {}
    for name in CORE:
        i = estimate.names.index(name)
        ok = bool(estimate.observable[i])
        out[name] = (float(estimate.theta[i]), _sqrt(float(estimate.cov[i, i]))) if ok else NAN2
    out.update(extra_values(estimate, extras))
    return out


def band_columns(
    estimates: Sequence[Estimate], extras: Sequence[str], truth: dict[str, float]
) -> dict[str, np.ndarray]:
    """``name -> (n, 3 or 4)`` rows ``[value, value + 2 sigma, value - 2 sigma(, truth)]``.

    The core terms are read for all estimates at once; only the extras need
    per-estimate work (mass and unbalance go through the delta method).
    """
    names = estimates[0].names
    idx = np.array([names.index(n) for n in CORE])
    theta = np.stack([e.theta[idx] for e in estimates])
    var = np.stack([np.diagonal(e.cov)[idx] for e in estimates])
    obs = np.stack([e.observable[idx] for e in estimates])
    value = np.where(obs, theta, np.nan)
    # A negative variance (a numerically broken covariance) draws no band rather than a zero-width one.
    std = np.where(obs & (var >= 0), np.sqrt(np.abs(var)), np.nan)
    cols = {name: (value[:, j], std[:, j]) for j, name in enumerate(CORE)}
    if extras:
        rows = [extra_values(e, extras) for e in estimates]
        for name in extras:
            pairs = np.array([r[name] for r in rows], dtype=float)
            cols[name] = (pairs[:, 0], pairs[:, 1])
    out = {}
    for name, (v, s) in cols.items():
        parts = [v, v + BAND_K * s, v - BAND_K * s]
        if name in truth:
            parts.append(np.full_like(v, truth[name]))
        out[name] = np.column_stack(parts)
    return out


def truth_values(truth: dict[str, Any] | None) -> dict[str, float]:
    """The simulated truth of the plotted quantities (bench-truth or result-JSON shape)."""
    if not truth:
        return {}

    def value(x: Any) -> Any:
        return x["value"] if isinstance(x, dict) and "value" in x else x

    out: dict[str, float] = {}
    inertia = value(truth.get("inertia_kgm2"))
    if isinstance(inertia, dict):
        out.update({k: float(inertia[k]) for k in TERMS if inertia.get(k) is not None})
    cog = value(truth.get("cog_m"))
    if cog is not None:
        out.update({k: float(v) for k, v in zip(lay.COG_TERMS, cog, strict=True)})
    mass = value(truth.get("mass_kg"))
    if mass is not None:
        out["mass"] = float(mass)
    unb = truth.get("unbalance")
    if isinstance(unb, dict) and unb.get("mr_kgm") is not None:
        out["unbalance"] = float(value(unb["mr_kgm"]))
    return out


def order_columns(amplitudes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude (m/s^2) and phase (deg, in (-180, 180]) of ``(n, n_orders, n_ch)`` complex rows."""
    return np.abs(amplitudes), np.degrees(np.angle(amplitudes))
