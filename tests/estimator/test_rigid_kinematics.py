"""Rigid-body fit of one frame: exact motion recovered, residual flags non-rigid motion."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.kinematics import KinematicsError, check_geometry, fit_rigid_motion

POSITIONS = np.array([[0.05, 0.30, 0.29], [0.02, -0.42, 0.25], [-0.26, -0.02, -0.12]])


def _channels(rotations: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    pos = np.repeat(POSITIONS, 3, axis=0)
    dirs = np.vstack(rotations)
    return pos, dirs


def _motion(rng: np.random.Generator, n_orders: int = 3) -> tuple[np.ndarray, np.ndarray]:
    g = rng.normal(size=(n_orders, 3)) + 1j * rng.normal(size=(n_orders, 3))
    w = rng.normal(size=(n_orders, 3)) + 1j * rng.normal(size=(n_orders, 3))
    return g, w


def test_exact_rigid_motion_is_recovered_with_zero_residual() -> None:
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    pos, dirs = _channels([np.eye(3), q * np.sign(np.linalg.det(q)), np.eye(3)])
    gamma_p, omega_dot = _motion(rng)
    point = np.array([0.1, -0.2, 0.05])
    # Each channel reads n . (gamma_P + Omega' x (r - P)): an independent construction.
    acc = gamma_p[:, None, :] + np.cross(omega_dot[:, None, :], (pos - point)[None, :, :])
    amplitudes = np.einsum("ocj,cj->oc", acc, dirs)
    fit = fit_rigid_motion(amplitudes, pos, dirs)
    np.testing.assert_allclose(fit.omega_dot, omega_dot, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(fit.point_acceleration(point), gamma_p, rtol=1e-12, atol=1e-12)
    assert np.all(fit.relative_residual < 1e-12)


def test_non_rigid_motion_shows_in_the_residual() -> None:
    rng = np.random.default_rng(1)
    pos, dirs = _channels([np.eye(3)] * 3)
    gamma_p, omega_dot = _motion(rng, 1)
    acc = gamma_p[:, None, :] + np.cross(omega_dot[:, None, :], pos[None, :, :])
    amplitudes = np.einsum("ocj,cj->oc", acc, dirs)
    bent = amplitudes.copy()
    bent[0, 2] += 0.2 * np.abs(amplitudes).mean()  # one axis moves off the rigid body
    assert fit_rigid_motion(bent, pos, dirs).relative_residual[0] > 0.02


def test_collinear_sensors_refused() -> None:
    pos = np.repeat(np.array([[0, 0, 0], [0, 1, 0], [0, 2, 0]], dtype=float), 3, axis=0)
    dirs = np.vstack([np.eye(3)] * 3)
    with pytest.raises(KinematicsError, match="determine only 5 of 6"):
        check_geometry(pos, dirs)
