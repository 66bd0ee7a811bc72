"""Self-calibration rows from the rigid-body redundancy of the accelerometers.

Nine channels measure six rigid-body motions: three combinations of the
readings per (frame, order) are zero for any rigid motion. What the fit leaves
there is noise plus the sensor errors: a gain error, a turned or a moved
sensor each add ``J c`` to the readings (:func:`estimator.systematic.reading_sensitivity`),
and the part of ``J c`` no rigid motion can produce shows in the residual.
What a rigid motion absorbs these rows never see: a common gain (the motion's
scale), a common turn (its direction), a common move (the reference point), a
common stretch of the positions (the angular acceleration's scale). And along
a mass-line sweep each order keeps nearly one motion shape, so they see only
a few combinations of the rest. The equations of motion and the priors hold
what they leave; what they add is that the noise cannot pull the calibration
where the readings say it is not.

Unlike the equations of motion, these rows do not depend on the inertia
estimate, so they cannot follow it when it drifts. The sensitivities are
taken at the fitted readings, which for weighted least squares are
independent of the residual's noise: no errors-in-variables bias.
"""

from __future__ import annotations

import numpy as np

from estimator.kinematics import RigidFit
from estimator.setup import EstimatorSetup
from estimator.systematic import reading_sensitivity, systematic_names, systematic_stds

# What self-calibration estimates: each channel's gain and each sensor's alignment.
# Not the positions. With three triaxial sensors these rows see five combinations of
# the nine position errors (a common move and a common stretch are rigid motions),
# and fixed gain and alignment errors leave the same residual for every motion: four
# of the five exactly, with errors of a few times their tolerances, the fifth nearly
# (tests/estimator/test_redundancy.py; a fourth sensor changes that). So these rows cannot tell
# a moved sensor from a turned or re-gained one; only the priors and the equations of
# motion, through their weak rpm dependence, could. Measured on the simulated i3 at
# 40 dB with no sensor error at all, calibrating the positions as well moved Iyz by
# 10 % and the cog by 12 mm. They stay in the type-B covariance.
CALIBRATED = ("gain:", "align:")


def calibrated_names(setup: EstimatorSetup) -> tuple[str, ...]:
    """The systematic parameters self-calibration estimates: the gains and alignments
    whose declared tolerance is not zero (zero: the user knows them exactly)."""
    stds = systematic_stds(setup)
    return tuple(
        name
        for name, std in zip(systematic_names(setup), stds, strict=True)
        if name.startswith(CALIBRATED) and std > 0
    )


def redundancy_rows(
    setup: EstimatorSetup,
    fit: RigidFit,
    amplitudes: np.ndarray,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    noise_var: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Whitened rows ``H c = y`` on the systematic parameters, for P (frame, order) pairs.

    Parameters
    ----------
    fit : the channels' geometry (``channels``: setup indices, u of them).
    amplitudes : (P, u) complex measured readings, m/s^2.
    gamma_o, omega_dot : (P, 3) complex fitted motion.
    noise_var : (P,) variance of the real (and imaginary) part of a unit-weight reading.

    Returns
    -------
    H : (P, 2 (u - 6), n_sys); y : (P, 2 (u - 6)). Real and imaginary parts stacked.
    ``c`` is what the estimator's calibration columns hold: the correction, minus
    the sensor error (the measured readings are the true ones plus ``J (-c)``).
    """
    assert fit.redundancy is not None
    q = fit.redundancy.T * fit.sw  # (k, u): weighted residual combinations
    fitted = (np.concatenate([gamma_o, omega_dot], axis=1) @ fit.jw.T) / fit.sw
    dy = reading_sensitivity(setup, fit, fitted, gamma_o, omega_dot)  # (P, u, n_sys)
    hc = -np.einsum("ku,pus->pks", q, dy)
    z = amplitudes @ q.T  # (P, k)
    s = 1.0 / np.sqrt(np.asarray(noise_var, float))
    H = np.concatenate([hc.real, hc.imag], axis=1) * s[:, None, None]
    y = np.concatenate([z.real, z.imag], axis=1) * s[:, None]
    return H, y
