"""The residual unbalance as the result reports it: amplitude, phase, location and couple.

The estimator fits the crank's residual unbalance at order 1 as two linear parts
(:mod:`estimator.equations`): the static part ``z = m r exp(-i beta)`` (kg m) at
the reference point ``P_u`` on the crank axis and the couple ``q`` (kg m^2)
about it. A point unbalance z at ``a`` m along the crank axis s from ``P_u``
gives ``q = a z``; a two-plane (dynamic) unbalance adds a couple of any phase.
So the reported location is the ``a`` whose point unbalance explains most of the
couple, ``a = Re(q conj z) / |z|^2`` (least squares), and the couple is what is
left, ``u = q - a z = i c z / |z|`` with ``c = Im(q conj z) / |z|``: 0 for a
point unbalance, a pair of opposite unbalances ``|u| / L`` (kg m) a distance L
apart otherwise, the one on the +s side at ``couple_angle_deg``.

Where the static part is not detected (``m r`` below twice its std, the
report's rule) its angle and location mean nothing: the couple is then ``q``
itself, about ``P_u``, and the location is left out.

Uncertainties by the delta method (first-order propagation of the parameters'
covariance through the analytic gradients below). With an estimated mass the
parameters are ``z / m`` and ``1 / m`` (the translation rows are divided by
``m`` to stay linear); ``q`` enters only the rotation rows and is fitted as is.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

# An amplitude is told from zero above this many of its standard deviations: below, it is
# noise around zero and its angle (and the location) mean nothing (the angle's std runs
# to 1e7 deg). The run's table and the report print by the same rule.
DETECTED_STDS = 2.0


def detected(entry: dict[str, Any] | None) -> bool:
    """Whether an amplitude entry (``{"value", "std"}``) is told from zero."""
    if not entry or entry.get("std") is None:
        return False
    return bool(entry["value"] > DETECTED_STDS * entry["std"])


def _vs(value: float, var: float) -> dict[str, Any]:
    std = math.sqrt(var) if math.isfinite(var) and var >= 0 else None
    return {"value": float(value), "std": std}


def _polar(v: complex, cov: np.ndarray) -> tuple[dict[str, Any], dict[str, Any]]:
    """Amplitude and angle (``v = |v| exp(-i angle)``, deg) of ``v`` with the (2, 2)
    covariance of its real and imaginary parts."""
    amp = abs(v)
    tiny = max(amp, 1e-300)
    grad_amp = np.array([v.real, v.imag]) / tiny
    grad_angle = np.array([-v.imag, v.real]) / tiny**2
    return (
        _vs(amp, float(grad_amp @ cov @ grad_amp)),
        _vs(
            math.degrees(-math.atan2(v.imag, v.real)),
            math.degrees(1.0) ** 2 * float(grad_angle @ cov @ grad_angle),
        ),
    )


def unbalance_report(
    values: np.ndarray,
    cov: np.ndarray,
    couple: bool,
    per_mass: bool,
    point: np.ndarray,
    axis: np.ndarray | None,
) -> dict[str, Any]:
    """The ``unbalance`` entry of the result document.

    Parameters
    ----------
    values : ``[z_re, z_im]``, then ``[q_re, q_im]`` when ``couple``, then ``1/m`` when
        ``per_mass`` (z then stands for ``z / m``); kg m, kg m^2, 1/kg.
    cov : their covariance.
    point : (3,) m, ``P_u``; axis : (3,) the crank axis s (None: unknown, no ``point_m``
        of the located unbalance).

    Returns
    -------
    ``mr_kgm``, ``angle_deg`` (value, std) of the static part, ``point_m`` where it
    acts; with the couple estimated: ``reference_point_m`` (``P_u``), ``axial_m`` (the location along s from
    ``P_u``, None when the static part is not detected), ``point_m`` (``P_u + a s``,
    else ``P_u``), ``couple_kgm2`` and ``couple_angle_deg`` (what no point unbalance
    explains; the whole couple about ``P_u`` when the static part is not detected).
    """
    values = np.asarray(values, float)
    cov = np.asarray(cov, float)
    n = values.size
    zr, zi = values[0], values[1]
    mu = values[-1] if per_mass else 1.0
    z = complex(zr, zi) / mu
    # z = (zr + i zi) / mu: d(z_re, z_im) / d values
    jz = np.zeros((2, n))
    jz[:, :2] = np.eye(2) / mu
    if per_mass:
        jz[:, -1] = [-z.real / mu, -z.imag / mu]
    mr, angle = _polar(z, jz @ cov @ jz.T)
    point = np.asarray(point, float)
    out: dict[str, Any] = {
        "mr_kgm": mr,
        "angle_deg": angle,
        "point_m": point.tolist(),
    }
    if not couple:
        return out
    out["reference_point_m"] = point.tolist()
    q = complex(values[2], values[3])
    jq = np.zeros((2, n))
    jq[:, 2:4] = np.eye(2)
    if not detected(mr):  # the couple about P_u; no location
        amp, ang = _polar(q, jq @ cov @ jq.T)
        out.update(axial_m=None, couple_kgm2=amp, couple_angle_deg=ang)
        return out
    n2 = zr * zr + zi * zi  # |z/m|^2 (parameters)
    proj = q.real * zr + q.imag * zi  # Re(q conj z) m
    cross_ = q.imag * zr - q.real * zi  # Im(q conj z) m
    a = mu * proj / n2
    grad_a = np.zeros(n)
    grad_a[:4] = mu * np.array(
        [
            (q.real * n2 - 2 * proj * zr) / n2**2,
            (q.imag * n2 - 2 * proj * zi) / n2**2,
            zr / n2,
            zi / n2,
        ]
    )
    if per_mass:
        grad_a[-1] = proj / n2
    # c = Im(q conj z) / |z|, the same with z / m: no 1/m dependence
    size = math.sqrt(n2)
    c = cross_ / size
    grad_c = np.zeros(n)
    grad_c[:4] = [
        q.imag / size - c * zr / n2,
        -q.real / size - c * zi / n2,
        -zi / size,
        zr / size,
    ]
    u = 1j * c * z / abs(z)
    out.update(
        axial_m=_vs(a, float(grad_a @ cov @ grad_a)),
        couple_kgm2=_vs(abs(c), float(grad_c @ cov @ grad_c)),
        # u is z turned by +-90 deg: its angle is known as well as beta's
        couple_angle_deg={
            "value": math.degrees(-math.atan2(u.imag, u.real)),
            "std": angle["std"],
        },
    )
    if axis is not None:
        out["point_m"] = (point + a * np.asarray(axis, float)).tolist()
    return out
