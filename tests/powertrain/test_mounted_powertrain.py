"""The mounted rigid body: Newton-Euler balances, closed-form modes, gyroscopic coupling."""

from __future__ import annotations

import numpy as np
import pytest

from powertrain.errors import PhysicsError
from powertrain.mounted import Mount, MountedPowertrain, gyroscopic_matrix
from powertrain.rigidbody import RigidBody, inertia_matrix, rotation_matrix
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_physics import build_model

BODY = RigidBody(
    110.0, np.array([0.035, -0.085, 0.105]), inertia_matrix(4.6, 3.1, 4.2, 0.28, -0.42, 0.21)
)
S = np.array([0.0, 1.0, 0.0])
MOUNTS = (
    Mount("rh", [0.06, 0.34, 0.31], np.eye(3), [110e3, 70e3, 190e3], 0.12),
    Mount("lh", [0.02, -0.46, 0.27], rotation_matrix([0, 0, 1], 0.3), [90e3, 60e3, 170e3], 0.12),
    Mount("rod", [-0.30, -0.02, -0.16], np.eye(3), [300e3, 15e3, 15e3], 0.15),
)


def test_free_body_under_a_pure_couple_rotates_about_its_cog():
    orders = np.array([1.0, 1.5, 2.0, 3.0])
    omega = 300.0
    couple = np.array([120.0 + 30j, -45.0, 80.0j])
    load = np.hstack([np.zeros(3), couple])[None, :].repeat(4, 0)
    free = MountedPowertrain(BODY, (), spin_inertia=0.0, spin_axis=S)
    q = free.response(omega, orders, load)
    w = orders * omega
    gamma_g = -(w**2)[:, None] * q[:, :3]
    omega_dot = -(w**2)[:, None] * q[:, 3:]
    assert np.abs(gamma_g).max() < 1e-12 * np.abs(omega_dot).max()
    np.testing.assert_allclose(
        omega_dot @ BODY.inertia.T, load[:, 3:], atol=1e-12 * np.abs(couple).max()
    )
    # With the crank spinning: I Omega' + Omega x H = M, Omega = Omega' / (i W).
    spinning = MountedPowertrain(BODY, (), spin_inertia=0.13, spin_axis=S)
    q = spinning.response(omega, orders, load)
    omega_dot = -(w**2)[:, None] * q[:, 3:]
    rate = omega_dot / (1j * w[:, None])
    lhs = omega_dot @ BODY.inertia.T + np.cross(rate, 0.13 * omega * S)
    np.testing.assert_allclose(lhs, load[:, 3:], atol=1e-12 * np.abs(couple).max())
    assert np.abs(q[:, :3]).max() < 1e-15


def test_free_body_under_a_force_through_the_cog_translates():
    free = MountedPowertrain(BODY, (), spin_inertia=0.13, spin_axis=S)
    force = np.array([10.0, -20.0j, 5.0])
    q = free.response(250.0, np.array([2.0]), np.hstack([force, np.zeros(3)])[None])
    np.testing.assert_allclose(-((2 * 250.0) ** 2) * q[0, :3], force / BODY.mass, rtol=1e-12)
    assert np.abs(q[0, 3:]).max() < 1e-18


def test_mounted_model_balances_momentum_and_angular_momentum():
    j, omega = 0.13, 2.0 * np.pi * 2500 / 60
    model = MountedPowertrain(BODY, MOUNTS, spin_inertia=j, spin_axis=S)
    orders = np.array([0.5, 1.0, 1.5, 3.0])
    rng = np.random.default_rng(3)
    load = rng.normal(size=(4, 6)) + 1j * rng.normal(size=(4, 6))
    q = model.response(omega, orders, load)
    for i, h in enumerate(orders):
        w = h * omega
        u_g, theta = q[i, :3], q[i, 3:]
        mount_force = np.zeros(3, complex)
        mount_moment = np.zeros(3, complex)
        for m in MOUNTS:
            arm = m.position - BODY.cog
            u = u_g + np.cross(theta, arm)
            f = -m.axes.T @ (m.stiffness * (1 + 1j * m.loss_factor) * (m.axes @ u))
            mount_force += f
            mount_moment += np.cross(arm, f)
        gamma_g = -(w**2) * u_g
        omega_dot, rate = -(w**2) * theta, 1j * w * theta
        np.testing.assert_allclose(mount_force + load[i, :3], BODY.mass * gamma_g, atol=1e-10)
        lhs = BODY.inertia @ omega_dot + np.cross(rate, j * omega * S)
        np.testing.assert_allclose(mount_moment + load[i, 3:], lhs, atol=1e-10)


def test_point_acceleration_is_rigid_kinematics():
    model = MountedPowertrain(BODY, MOUNTS, 0.13, S)
    q = np.array([[1e-4, -2e-4j, 3e-5, 1e-3, 2e-4j, -5e-4]])
    p = np.array([0.2, 0.3, -0.1])
    acc = model.point_acceleration(q, 300.0, np.array([2.0]), p)
    expected = -(600.0**2) * (q[0, :3] + np.cross(q[0, 3:], p - BODY.cog))
    np.testing.assert_allclose(acc[0], expected, rtol=1e-14)


def test_bounce_and_roll_frequencies_match_closed_forms():
    # Diagonal inertia, cog at the origin, four identical mounts at (+-a, +-b, 0),
    # vertical stiffness only: bounce sqrt(4k/m), rotation about X sqrt(4 k b^2 / Ixx).
    body = RigidBody(100.0, np.zeros(3), np.diag([4.0, 3.0, 5.0]))
    k, a, b = 2e5, 0.3, 0.4
    mounts = tuple(
        Mount(f"m{i}", [sx * a, sy * b, 0.0], np.eye(3), [1e3, 1e3, k])
        for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)])
    )
    modes = MountedPowertrain(body, mounts).modes()
    freqs = modes.frequency_hz
    expected = {
        "bounce": np.sqrt(4 * k / 100.0),
        "pitch": np.sqrt(4 * k * b**2 / 4.0),  # about X
        "roll": np.sqrt(4 * k * a**2 / 3.0),  # about Y, the crank axis
    }
    for label, w in expected.items():
        j = modes.dominant().index(label)
        assert freqs[j] == pytest.approx(w / (2 * np.pi), rel=1e-6)
        assert modes.energy[modes.labels.index(label), j] == pytest.approx(1.0, abs=1e-4)


def test_example_i3_modes_lie_in_the_rigid_body_band():
    model = build_model(load_bench(EXAMPLES_DIR / "i3-bench.toml"))
    f = model.modes().frequency_hz
    assert np.all((f >= 5.0) & (f <= 20.0)), f
    np.testing.assert_allclose(model.modes().energy.sum(axis=0), 1.0, rtol=1e-12)


def test_undamped_mounts_give_real_modes():
    undamped = tuple(Mount(m.name, m.position, m.axes, m.stiffness, 0.0) for m in MOUNTS)
    model = MountedPowertrain(BODY, undamped, 0.13, S)
    real, complex_ = model.modes(), model.modes(omega=0.0)
    np.testing.assert_allclose(complex_.frequency_hz, real.frequency_hz, rtol=1e-9)
    np.testing.assert_allclose(complex_.damping_ratio, 0.0, atol=1e-9)
    assert np.abs(complex_.shapes.imag).max() < 1e-8 * np.abs(complex_.shapes).max()
    # Mass-normalised shapes diagonalise M and K.
    v = real.shapes.real
    np.testing.assert_allclose(v.T @ model.M @ v, np.eye(6), atol=1e-10)
    np.testing.assert_allclose(
        v.T @ model.K.real @ v, np.diag((2 * np.pi * real.frequency_hz) ** 2), rtol=1e-9, atol=1e-6
    )
    # With loss, the same mounts damp every mode.
    damped = MountedPowertrain(BODY, MOUNTS, 0.13, S).modes(omega=0.0)
    assert np.all(damped.damping_ratio > 0.05)


def test_gyroscopic_matrix_is_skew_and_vanishes_at_rest():
    assert not np.any(gyroscopic_matrix(0.13, 0.0, S))
    g = gyroscopic_matrix(0.13, 400.0, S)
    np.testing.assert_allclose(g, -g.T)
    assert not np.any(g[:3]) and not np.any(g[:, :3])
    # Spin splits the modes only a little at idle, and not at all at rest.
    model = MountedPowertrain(BODY, MOUNTS, 0.13, S)
    np.testing.assert_allclose(
        model.modes(omega=0.0).frequency_hz,
        MountedPowertrain(BODY, MOUNTS, 0.0, S).modes(omega=0.0).frequency_hz,
        rtol=1e-10,
    )


def test_sweep_equals_direct_solves():
    model = MountedPowertrain(BODY, MOUNTS, 0.13, S)
    omega = np.linspace(50.0, 500.0, 7)
    orders = np.array([0.5, 1.0, 1.5, 2.0, 6.0])
    rng = np.random.default_rng(5)
    l1 = rng.normal(size=(5, 6)) + 1j * rng.normal(size=(5, 6))
    l0 = rng.normal(size=(5, 6)) * 100
    fast = model.response_sweep(omega, orders, l1, l0)
    direct = model.response(omega, orders, omega[:, None, None] ** 2 * l1 + l0)
    np.testing.assert_allclose(fast, direct, rtol=1e-10, atol=1e-10 * np.abs(direct).max())


def test_stiffness_matrix_is_symmetric_and_translation_invariant_in_force():
    k = MountedPowertrain(BODY, MOUNTS).K
    np.testing.assert_allclose(k, k.T, atol=1e-6)
    # A pure translation stretches every mount the same: force = -sum R^T k R u.
    u = np.array([1e-3, 0, 0])
    f = -(k[:3, :3] @ u)
    expected = -sum(
        m.axes.T @ (m.stiffness * (1 + 1j * m.loss_factor) * (m.axes @ u)) for m in MOUNTS
    )
    np.testing.assert_allclose(f, expected, rtol=1e-12)


def test_bad_mounts_raise_physics_error():
    with pytest.raises(PhysicsError, match="orthonormal"):
        Mount("x", [0, 0, 0], [[1, 0, 0], [0, 2, 0], [0, 0, 1]], [1, 1, 1])
    with pytest.raises(PhysicsError, match=r"\[1.0, -1.0, 1.0\]"):
        Mount("x", [0, 0, 0], np.eye(3), [1, -1, 1])
