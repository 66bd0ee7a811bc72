"""The declared systematic sensor errors: their names, their standard deviations,
and how each moves the rigid-body motion fitted from a frame.

Per channel a relative gain error; per sensor a small rotation (alignment, rad)
and a displacement (position, m) about/along the bench axes. The model inputs'
declared tolerances follow them (:mod:`estimator.model_inputs`): they do not
touch the readings, only the equations of motion. The streaming
estimator accumulates the sensitivity of its normal equations to them, which
turns the declared tolerances into the type-B part of the covariance.
"""

from __future__ import annotations

import numpy as np

from estimator.kinematics import RigidFit
from estimator.setup import EstimatorSetup
from estimator.vec import cross


def systematic_names(setup: EstimatorSetup) -> list[str]:
    """The sensor errors, then the model inputs (``model:<name>``, :mod:`estimator.model_inputs`)."""
    names = [f"gain:{c}" for c in setup.channels]
    for s in range(setup.n_sensors):
        names += [f"align:{s}:{ax}" for ax in "xyz"]
        names += [f"pos:{s}:{ax}" for ax in "xyz"]
    return names + [f"model:{m.name}" for m in setup.model_inputs]


def systematic_stds(setup: EstimatorSetup) -> np.ndarray:
    tol = setup.tolerances
    n_ch = len(setup.channels)
    per_sensor = [tol.alignment_rad] * 3 + [tol.position_m] * 3
    model = [m.std for m in setup.model_inputs]
    return np.array([tol.gain_rel] * n_ch + per_sensor * setup.n_sensors + model)


def _pose_sensitivity(
    setup: EstimatorSetup, fit: RigidFit, gamma_o: np.ndarray, omega_dot: np.ndarray
) -> tuple[np.ndarray, int, np.ndarray, np.ndarray]:
    """What the two sensitivities below share: the used channels (u,), n_sys, where each
    used channel's sensor block starts among the systematic parameters (u,), and
    d reading / d(alignment, position) of its sensor, (P, u, 6) complex."""
    n_ch = len(setup.channels)
    assert fit.channels is not None
    used = np.asarray(fit.channels)
    # (the model inputs' columns stay zero: they do not touch the readings)
    n_sys = n_ch + 6 * setup.n_sensors + len(setup.model_inputs)
    n = setup.directions[used]  # (u, 3)
    r = setup.positions[used] - fit.origin  # (u, 3)
    gamma_p = gamma_o[:, None, :] + cross(omega_dot[:, None, :], r[None])  # (P, u, 3)
    d_pose = np.concatenate(
        [cross(n[None], gamma_p), cross(n[None], omega_dot[:, None, :])], axis=2
    )
    return used, n_sys, n_ch + 6 * setup.sensor_of_channel[used], d_pose


def reading_sensitivity(
    setup: EstimatorSetup,
    fit: RigidFit,
    amplitudes: np.ndarray,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
) -> np.ndarray:
    """d readings / d(systematic parameters), (P, u, n_sys) complex.

    For P (frame, order) pairs of the u channels of ``fit`` (its ``channels``:
    setup indices); ``amplitudes`` (P, u) complex, the motion (P, 3).

    A reading is ``n . gamma_P``. A relative gain error g scales it by (1 + g);
    turning the sensor by a small angle about bench axis e changes ``n`` by
    ``e x n``, so the reading by ``e . (n x gamma_P)``; moving it along e
    changes ``gamma_P`` by ``Omega' x e``, so the reading by ``e . (n x Omega')``.
    """
    used, n_sys, bases, d_pose = _pose_sensitivity(setup, fit, gamma_o, omega_dot)
    out = np.zeros((len(gamma_o), len(used), n_sys), complex)
    # every channel at once (the same elementwise products as one channel at a time);
    # row j's alignment columns start at its sensor's block, its position ones 3 later
    rows = np.arange(len(used))[:, None]
    out[:, rows[:, 0], used] = amplitudes
    out[:, rows, bases[:, None] + np.arange(6)] = d_pose
    return out


def motion_sensitivity(
    setup: EstimatorSetup,
    fit: RigidFit,
    amplitudes: np.ndarray,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
) -> np.ndarray:
    """d[gamma_O, Omega'] / d(systematic parameters), (P, 12, n_sys) real (Re rows, Im rows).

    The arguments are those of :func:`reading_sensitivity`. The fit is linear
    (``motion = gain @ readings``), so each reading's change reaches the motion
    through its column of the gain: ``gain @ reading_sensitivity(...)``, formed
    without the zeros of that product (a channel's gain error moves its own reading
    only, a sensor's alignment and position the readings of its channels).
    """
    used, n_sys, base_of, d_pose = _pose_sensitivity(setup, fit, gamma_o, omega_dot)
    out = np.zeros((len(gamma_o), 6, n_sys), complex)
    out[:, :, used] = fit.gain[None] * amplitudes[:, None, :]
    # The channels of a sensor summed in channel order (elementwise products, a fixed
    # order): the result of a pair does not depend on how many pairs are assembled
    # together, and it is the dense product's sum without its zero terms. Each pass adds
    # every sensor's channel at one place at once (their column blocks are disjoint).
    bases = base_of.tolist()
    seen: dict[int, int] = {}
    rank = []  # each used channel's place among its sensor's channels
    for base in bases:
        rank.append(seen.get(base, 0))
        seen[base] = rank[-1] + 1
    for place in range(max(rank, default=-1) + 1):
        js = [j for j, q in enumerate(rank) if q == place]
        cols = np.array([bases[j] for j in js])[:, None] + np.arange(6)  # (k, 6)
        out[:, :, cols] += fit.gain[None, :, js, None] * d_pose[:, js][:, None]
    return np.concatenate([out.real, out.imag], axis=1)
