"""How the declared tolerances of the model inputs move the equations of motion (type B).

The estimator takes some inputs of its model as known: the gas model, the crank
train's spin inertia, the moving masses, the crankcase pressure, the mount
stiffnesses. Each has a declared 1-sigma uncertainty
(:class:`estimator.setup.ModelInput`); like the sensor tolerances
(:mod:`estimator.systematic`) it enters the type-B covariance through the
derivative of each row's residual ``r = H theta - y`` with respect to the input,
accumulated as ``S = sum H^T dr/dp``. The rows (:mod:`estimator.equations`) are

translation   m (gamma_O + Omega' x (G - O)) - F_exc - sum_i f_i = 0   (or, mass
              unknown, gamma_O + Omega' x (G - O) - (F_exc + sum_i f_i) / m)
rotation      I Omega' + Omega x H_spin - M_R - (R - G) x F_exc - sum_i (p_i - G) x f_i = 0

so, analytically:

* an input of the known excitation moving it by ``(dF, dM_R)``:
  translation ``-dF`` (``-dF / m``), rotation ``(G - R) x dF - dM_R``; the
  excitation's own derivative ``(dF, dM_R)`` comes with the input
  (``ModelInput.d_excitation``: the gas scale's is its gas part, the masses' and the
  crankcase pressure's a central difference of the engine's excitation,
  ``ptinertia/model_tolerances.py``);
* the spin inertia J: rotation ``d(Omega x H)/dJ = (Omega' x s) / (i h)``;
* the stiffness scale of mount i (``K_i -> (1 + k) K_i``): its reaction
  ``f_i = K_i gamma_i / W^2``: translation ``-f_i`` (``-f_i / m``), rotation
  ``(G - p_i) x f_i``, the columns the estimated mount scales would have.

Evaluated at the linearisation point (cog G, mass m) and the pair's fitted motion;
the weighting of the rows is not differentiated (a second-order effect).
"""

from __future__ import annotations

import numpy as np

from estimator.equations import Linearisation
from estimator.setup import EstimatorSetup
from estimator.vec import cross


def model_input_rows(
    setup: EstimatorSetup,
    lin: Linearisation,
    mass_known: bool,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    origin: np.ndarray,
    orders: np.ndarray,
    rpm: np.ndarray,
) -> np.ndarray:
    """d raw residual / d model inputs, (P, 12, n_model) real (Re rows, then Im rows).

    For P (frame, order) pairs: motion ``gamma_o``, ``omega_dot`` (P, 3) complex
    about ``origin`` (P, 3) m, ``orders`` and ``rpm`` (P,); ``mass_known``: the
    translation rows are in newtons (else divided by the mass).
    """
    inputs = setup.model_inputs
    n_p = len(orders)
    out = np.zeros((n_p, 6, len(inputs)), complex)
    if not inputs:
        return np.zeros((n_p, 12, 0))
    h = np.asarray(orders, float)
    rpm = np.asarray(rpm, float)
    w = rpm * 2 * np.pi / 60.0
    g = np.asarray(lin.cog, float)
    per_force = 1.0 if mass_known else 1.0 / lin.mass  # translation rows per newton
    s = setup.crank_axis
    mounts = []  # (column, mount) of the mount stiffness inputs
    excitation = []  # (column, d force, d moment) of the excitation inputs
    for j, inp in enumerate(inputs):
        if inp.kind == "excitation":
            assert inp.d_excitation is not None
            excitation.append((j, *inp.d_excitation(rpm, h)))
        elif inp.kind == "spin_inertia":
            out[:, 3:, j] = cross(omega_dot, s) / (1j * h)[:, None]
        else:
            mounts.append((j, setup.mounts[inp.mount]))
    if excitation:
        # every excitation input at once (axis 0: the same elementwise products)
        cols = [j for j, _, _ in excitation]
        df = np.stack([d for _, d, _ in excitation])  # (E, P, 3)
        dm = np.stack([d for _, _, d in excitation])
        out[:, :3, cols] = (-per_force * df).transpose(1, 2, 0)
        out[:, 3:, cols] = (cross(g - setup.reference_point, df) - dm).transpose(1, 2, 0)
    if mounts:
        # every mount at once (axis 0: the same elementwise products and the same
        # three-term sums per mount as one mount at a time)
        cols = [j for j, _ in mounts]
        p = np.array([m.position for _, m in mounts])  # (M, 3)
        stiff = np.array([m.stiffness for _, m in mounts])  # (M, 3, 3)
        big_w2 = (h * w) ** 2
        gamma_i = gamma_o[None] + cross(omega_dot[None], p[:, None] - origin[None])
        f_i = np.einsum("mij,moj->moi", stiff, gamma_i) / big_w2[None, :, None]
        out[:, :3, cols] = (-per_force * f_i).transpose(1, 2, 0)
        out[:, 3:, cols] = cross(g - p[:, None], f_i).transpose(1, 2, 0)
    return np.concatenate([out.real, out.imag], axis=1)
