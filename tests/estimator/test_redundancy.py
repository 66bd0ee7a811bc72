"""The self-calibration rows of the rigid fit's redundancy (estimator.redundancy).

Checked against sensors built wrong on purpose: the readings of a rigid motion at
sensors that are turned, moved and mis-scaled by exact rotations and displacements,
not through the linearised sensitivities the rows are made of.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from estimator.kinematics import RigidFit
from estimator.redundancy import redundancy_rows
from estimator.setup import EstimatorSetup
from estimator.systematic import systematic_names

POSITIONS = np.array([[0.05, 0.30, 0.29], [0.02, -0.42, 0.25], [-0.26, -0.02, -0.12]])
AXES = np.eye(3)


def _setup(sensor_positions: np.ndarray = POSITIONS) -> EstimatorSetup:
    n_s = len(sensor_positions)
    return EstimatorSetup(
        channels=tuple(f"{s}_{a}" for s in "ABCD"[:n_s] for a in "xyz"),
        sensor_of_channel=np.repeat(np.arange(n_s), 3),
        positions=np.repeat(sensor_positions, 3, axis=0),
        directions=np.tile(AXES, (n_s, 1)),
        reference_point=np.zeros(3),
        unbalance_point=np.zeros(3),
        crank_axis=np.array([0.0, 1.0, 0.0]),
        cylinder_axis=np.array([0.0, 0.0, 1.0]),
        spin_inertia=0.1,
        excitation=lambda rpm, orders: (np.zeros((len(orders), 3)), np.zeros((len(orders), 3))),
        mounts=(),
        mass_nominal=100.0,
        mass_known=True,
        cog_nominal=np.zeros(3),
        inertia_nominal=np.eye(3),
    )


def _readings(motion: np.ndarray, positions: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Exact readings (P, n_ch) of rigid motions (P, 6) [gamma_O at the origin, Omega']."""
    gamma = motion[:, None, :3] + np.cross(motion[:, None, 3:], positions[None])
    return np.einsum("pcj,cj->pc", gamma, directions)


def _fitted_rows(setup: EstimatorSetup, y_meas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fit the rigid motion of each reading set (P, n_ch) with the nominal geometry and
    return its redundancy rows H, y (unit noise)."""
    n_ch = len(setup.channels)
    fit = RigidFit.of(setup.positions, setup.directions).on_channels(np.arange(n_ch))
    m = fit.fit_many(y_meas[:, None, :])
    g = np.concatenate([x.gamma_o for x in m])
    o = np.concatenate([x.omega_dot for x in m])
    return redundancy_rows(setup, fit, y_meas, g, o, np.ones(len(y_meas)))


def test_a_rigid_motion_seen_by_exact_sensors_leaves_nothing():
    setup = _setup()
    fit = RigidFit.of(setup.positions, setup.directions).on_channels(np.arange(9))
    q = fit.redundancy
    assert q is not None
    assert q.shape == (9, 3)
    np.testing.assert_allclose(q.T @ fit.jw, 0.0, atol=1e-12)
    np.testing.assert_allclose(q.T @ q, np.eye(3), atol=1e-12)
    rng = np.random.default_rng(0)
    motion = rng.standard_normal((5, 6)) + 1j * rng.standard_normal((5, 6))
    y_meas = _readings(motion, setup.positions, setup.directions)
    _, y = _fitted_rows(setup, y_meas)
    np.testing.assert_allclose(y, 0.0, atol=1e-12)


def test_rows_explain_the_residual_of_sensors_built_wrong():
    setup = _setup()
    rng = np.random.default_rng(1)
    eps = 1e-4  # small: the rows are first order, the check is to second order
    gains = eps * rng.standard_normal(9)
    turns = eps * rng.standard_normal((3, 3))  # rotation vectors, rad
    moves = eps * rng.standard_normal((3, 3))  # m
    directions = np.concatenate([Rotation.from_rotvec(turns[s]).apply(AXES) for s in range(3)])
    positions = np.repeat(POSITIONS + moves, 3, axis=0)
    motion = rng.standard_normal((40, 6)) + 1j * rng.standard_normal((40, 6))
    y_meas = (1.0 + gains) * _readings(motion, positions, directions)
    H, y = _fitted_rows(setup, y_meas)
    # the calibration columns hold the correction: minus the error, in systematic_names order
    error = np.concatenate([gains, *[np.concatenate([turns[s], moves[s]]) for s in range(3)]])
    assert len(error) == len(systematic_names(setup))
    explained = H @ -error
    assert np.linalg.norm(y) > 1e-5 * np.linalg.norm(y_meas)
    np.testing.assert_allclose(explained, y, atol=1e-3 * np.linalg.norm(y) / np.sqrt(y.size))


def _unexplained_by_gains_and_turns(sensor_positions: np.ndarray, seed: int) -> float:
    """Share of the redundancy residual of moved sensors that no gain and alignment
    errors explain, over many motions of every direction (exact readings, 0.1 mm moves)."""
    setup = _setup(sensor_positions)
    n_s = len(sensor_positions)
    rng = np.random.default_rng(seed)
    moves = 1e-4 * rng.standard_normal((n_s, 3))
    positions = np.repeat(sensor_positions + moves, 3, axis=0)
    motion = rng.standard_normal((60, 6)) + 1j * rng.standard_normal((60, 6))
    y_meas = _readings(motion, positions, setup.directions)
    H, y = _fitted_rows(setup, y_meas)
    names = systematic_names(setup)
    keep = [i for i, name in enumerate(names) if not name.startswith("pos:")]
    a = H[:, :, keep].reshape(-1, len(keep))
    b = y.reshape(-1)
    c, *_ = np.linalg.lstsq(a, b, rcond=None)
    return float(np.linalg.norm(b - a @ c) / np.linalg.norm(b))


def test_with_three_sensors_a_moved_sensor_looks_like_regained_and_turned_ones():
    # Why self-calibration leaves the positions alone (estimator.redundancy.CALIBRATED):
    # three triaxial sensors give 3 redundant readings per motion, and whatever a
    # move leaves there, some fixed gain and alignment errors leave too, for every
    # motion (the sizes they need do not matter here: the rows are linear in them).
    # A fourth sensor gives 6 and makes part of the positions visible on their own.
    for seed in range(3):
        assert _unexplained_by_gains_and_turns(POSITIONS, seed) < 1e-3
    fourth = np.vstack([POSITIONS, [[0.25, 0.05, -0.05]]])
    assert _unexplained_by_gains_and_turns(fourth, 0) > 0.1
