"""Modal mass-line method: mass, cog and inertia from accelerance FRFs (paper eqs. 9-13).

Above the suspension modes and below the first elastic mode, a unit force
along ``f`` at ``A`` gives a rigid body the accelerations (eqs. 11-12)::

    gamma_G = f / m,   Omega' = I^-1 (GA x f),   gamma_B = gamma_G + Omega' x GB

so the accelerance from force ``(A, f)`` to a channel along ``d`` at ``B`` is
the constant ``d . f / m + (GB x d) . I^-1 (GA x f)`` (eq. 13): the mass line.
In the matrix form used here, ``A0 = T_ch M_G^-1 T_f^T`` with rows
``T = [d, GP x d]`` and ``M_G = blockdiag(m 1, I)``.

The method is two fits, one module each: the band and the per-FRF fit of the
constant ``A0`` (with the suspension's and the elastic modes' residual terms) in
:mod:`estimator.classical.massline_band`, and the rigid body fitted to all ``A0`` at once in
:mod:`estimator.classical.massline_rigid`. :func:`estimate_mass_line` here runs them in order;
callers import each name from the module that defines it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from estimator.classical.massline_band import (
    Band,
    FrfGeometry,
    MassLineError,
    MassLineFit,
    choose_band,
    find_resonances,
    fit_mass_line,
)
from estimator.classical.massline_rigid import (
    MassLineTolerances,
    RigidBodyFit,
    rigid_body_from_mass_line,
)


@dataclass(frozen=True)
class MassLineResult:
    """Everything :func:`estimate_mass_line` found."""

    band: Band
    fit: MassLineFit
    body: RigidBodyFit
    residual_stiffness: bool


def estimate_mass_line(
    frequency: npt.ArrayLike,
    h: npt.ArrayLike,
    geometry: FrfGeometry,
    band: tuple[float, float] | None = None,
    residual_stiffness: bool = True,
    tolerances: MassLineTolerances | None = None,
) -> MassLineResult:
    """Band (automatic unless given), mass-line fit, rigid body: the whole method.

    Parameters
    ----------
    frequency : (n_f,) Hz.
    h : (n_f, n_ch, n_e) complex accelerance m/s^2/N; channel and excitation order as
        in ``geometry``.
    geometry : the points and directions.
    band : (low, high) Hz; None chooses it (:func:`choose_band`).
    residual_stiffness : fit the suspension's residual terms (default); False shows their bias.
    tolerances : declared set-up uncertainties for the intervals.
    """
    f = np.asarray(frequency, dtype=float)
    hh = np.asarray(h, dtype=complex)
    n_ch, n_e = len(geometry.channel_positions), len(geometry.force_positions)
    if hh.shape != (len(f), n_ch, n_e):
        raise MassLineError(
            f"FRFs must have shape (n_f, n_ch, n_e) = ({len(f)}, {n_ch}, {n_e}), got {hh.shape}"
        )
    if band is None:
        chosen = choose_band(f, hh)
    else:
        chosen = Band(float(band[0]), float(band[1]), tuple(find_resonances(f, hh)), "user")
    fit = fit_mass_line(f, hh, (chosen.low_hz, chosen.high_hz), residual_stiffness)
    where = f"band {chosen.low_hz:.4g} to {chosen.high_hz:.4g} Hz"
    try:
        body = rigid_body_from_mass_line(fit.a0, fit.a0_std, geometry, tolerances)
    except MassLineError as err:
        raise MassLineError(f"{where}: {err}") from None
    return MassLineResult(chosen, fit, body, residual_stiffness)
