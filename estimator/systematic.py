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

from dataclasses import dataclass

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


def _sensor_columns(setup: EstimatorSetup, fit: RigidFit) -> tuple[np.ndarray, int, np.ndarray]:
    """The fit's used channels (u,), the number of systematic parameters, and where each
    used channel's sensor block (alignment, then position) starts among them (u,)."""
    assert fit.channels is not None
    used = np.asarray(fit.channels)
    n_ch = len(setup.channels)
    # (the model inputs' columns, last, stay zero: they do not touch the readings)
    n_sys = n_ch + 6 * setup.n_sensors + len(setup.model_inputs)
    return used, n_sys, n_ch + 6 * setup.sensor_of_channel[used]


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
    used, n_sys, bases = _sensor_columns(setup, fit)
    n = setup.directions[used]  # (u, 3)
    r = setup.positions[used] - fit.origin  # (u, 3)
    gamma_p = gamma_o[:, None, :] + cross(omega_dot[:, None, :], r[None])  # (P, u, 3)
    d_pose = np.concatenate(
        [cross(n[None], gamma_p), cross(n[None], omega_dot[:, None, :])], axis=2
    )  # (P, u, 6)
    out = np.zeros((len(gamma_o), len(used), n_sys), complex)
    # every channel at once (the same elementwise products as one channel at a time);
    # row j's alignment columns start at its sensor's block, its position ones 3 later
    rows = np.arange(len(used))[:, None]
    out[:, rows[:, 0], used] = amplitudes
    out[:, rows, bases[:, None] + np.arange(6)] = d_pose
    return out


def sensor_blocks(setup: EstimatorSetup, fit: RigidFit) -> SensorBlocks:
    """What :func:`motion_sensitivity` takes from the fit's channel geometry (the same for
    every frame fitted with ``fit``: callers keep it per fit)."""
    used, n_sys, base_array = _sensor_columns(setup, fit)
    bases = base_array.tolist()
    sensors = list(dict.fromkeys(bases))  # in order of their first channel
    members: list[list[int]] = [[j for j, b in enumerate(bases) if b == s] for s in sensors]
    width = max(len(m) for m in members)
    # a sensor with fewer channels than the widest is padded with a zero-gain channel:
    # its terms (+0) come after the real ones and leave their sum as it is
    pad = len(used)
    idx = np.array([m + [pad] * (width - len(m)) for m in members])  # (S, width)
    gain = np.concatenate([fit.gain, np.zeros((6, 1))], axis=1)
    cols = (np.array(sensors)[:, None] + np.arange(6)).ravel()
    return SensorBlocks(
        used=used,
        n_sys=n_sys,
        arm=setup.positions[used] - fit.origin,
        # (a unit axis for the padding channel, whose motion is zero)
        directions=np.concatenate([setup.directions[used], np.ones((1, 3))])[:, None, :],
        gain=fit.gain,
        idx=idx,
        gain_by_place=[gain[:, idx[:, q]][:, :, None] for q in range(width)],  # (6, S, 1)
        cols=cols,
        bases=base_array,
    )


@dataclass(frozen=True)
class SensorBlocks:
    """The used channels of a fit grouped by sensor (:func:`sensor_blocks`)."""

    used: np.ndarray  # (u,) setup channel indices
    n_sys: int
    arm: np.ndarray  # (u, 3) m, channel point - fit origin
    directions: np.ndarray  # (u + 1, 1, 3) the channels' axes, then the padding's
    gain: np.ndarray  # (6, u) the fit's gain
    idx: np.ndarray  # (S, width) each sensor's used channels in channel order (u: padding)
    gain_by_place: list[np.ndarray]  # per place in a sensor: the gain columns (6, S, 1)
    cols: np.ndarray  # (6 S,) the sensors' alignment and position columns
    bases: np.ndarray  # (u,) each used channel's sensor's first column


def motion_sensitivity(
    setup: EstimatorSetup,
    fit: RigidFit,
    amplitudes: np.ndarray,
    gamma_o: np.ndarray,
    omega_dot: np.ndarray,
    blocks: SensorBlocks | None = None,
) -> np.ndarray:
    """d[gamma_O, Omega'] / d(systematic parameters), (P, 12, n_sys) real (Re rows, Im rows).

    The arguments are those of :func:`reading_sensitivity` (``blocks``: the fit's
    :func:`sensor_blocks`, made here when not given). The fit is linear
    (``motion = gain @ readings``), so each reading's change reaches the motion
    through its column of the gain: ``gain @ reading_sensitivity(...)``, formed
    without the zeros of that product (a channel's gain error moves its own reading
    only, a sensor's alignment and position the readings of its channels).

    Every product here has a real factor (gain, sensor axis, lever arm), so the real and
    imaginary parts are carried side by side as reals (axis 1): the values of the complex
    arithmetic (whose product with a real adds only ``0 * x`` terms), without its
    complex temporaries.
    """
    b = sensor_blocks(setup, fit) if blocks is None else blocks
    n_p, u = amplitudes.shape
    parts = np.empty((2, n_p, 2, 3))  # gamma_O, Omega' (P, Re/Im, 3)
    parts[0, :, 0], parts[0, :, 1] = gamma_o.real, gamma_o.imag
    parts[1, :, 0], parts[1, :, 1] = omega_dot.real, omega_dot.imag
    w = parts[1][:, :, None, :]  # (P, 2, 1, 3)
    # gamma_P = gamma_O + Omega' x r, and d reading / d(alignment, position) of each
    # channel: n x gamma_P, n x Omega' (one cross product over both)
    motion = np.empty((n_p, 2, u + 1, 2, 3))
    motion[:, :, :u, 0] = parts[0][:, :, None, :] + cross(w, b.arm)
    motion[:, :, :u, 1] = w
    motion[:, :, u] = 0.0  # the padding channel
    d_pose = cross(b.directions, motion)
    d_pose = d_pose.reshape(n_p, 2, u + 1, 6)
    out = np.zeros((n_p, 2, 6, b.n_sys))
    amp = np.empty((n_p, 2, 1, u))
    amp[:, 0, 0], amp[:, 1, 0] = amplitudes.real, amplitudes.imag
    out[:, :, :, b.used] = b.gain * amp
    # The channels of a sensor summed in channel order (elementwise products, a fixed
    # order): the result of a pair does not depend on how many pairs are assembled
    # together, and it is the dense product's sum without its zero terms. Each pass adds
    # every sensor's channel at one place at once (their column blocks are disjoint).
    total = None
    for q, g in enumerate(b.gain_by_place):
        term = g * d_pose[:, :, None, b.idx[:, q]]  # (P, 2, 6, S, 6)
        total = term if total is None else total + term
    assert total is not None
    out[:, :, :, b.cols] = total.reshape(n_p, 2, 6, -1)
    return out.reshape(n_p, 12, b.n_sys)
