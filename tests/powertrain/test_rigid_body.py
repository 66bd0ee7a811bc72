"""Rigid-body algebra against direct integration over point clouds."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from powertrain.errors import PhysicsError
from powertrain.rigidbody import (
    RigidBody,
    consistency_problems,
    inertia_matrix,
    inertia_terms,
    parallel_axis,
    principal,
    rotate_inertia,
    rotation_matrix,
    skew,
)


@pytest.fixture
def cloud():
    rng = np.random.default_rng(7)
    masses = rng.uniform(0.5, 3.0, 40)
    points = rng.normal(size=(40, 3)) * [0.3, 0.2, 0.15] + [0.1, -0.05, 0.2]
    return masses, points


def direct_inertia(masses, points, about):
    """sum m (|r|^2 1 - r r^T) with r from ``about``: the definition."""
    r = points - about
    return np.einsum(
        "i,ijk->jk",
        masses,
        np.einsum("ij,ij->i", r, r)[:, None, None] * np.eye(3) - r[:, :, None] * r[:, None, :],
    )


def test_terms_follow_the_product_convention(cloud):
    masses, points = cloud
    cog = masses @ points / masses.sum()
    i_g = direct_inertia(masses, points, cog)
    terms = inertia_terms(i_g)
    r = points - cog
    assert terms["Ixy"] == pytest.approx(float(masses @ (r[:, 0] * r[:, 1])), rel=1e-12)
    assert terms["Ixz"] == pytest.approx(float(masses @ (r[:, 0] * r[:, 2])), rel=1e-12)
    assert terms["Iyz"] == pytest.approx(float(masses @ (r[:, 1] * r[:, 2])), rel=1e-12)
    assert terms["Ixx"] == pytest.approx(float(masses @ (r[:, 1] ** 2 + r[:, 2] ** 2)), rel=1e-12)
    np.testing.assert_allclose(inertia_matrix(**terms), i_g, rtol=1e-13, atol=1e-15)


def test_parallel_axis_matches_direct_integration(cloud):
    masses, points = cloud
    cog = masses @ points / masses.sum()
    i_g = direct_inertia(masses, points, cog)
    p = np.array([0.4, -0.3, 0.05])
    np.testing.assert_allclose(
        parallel_axis(i_g, masses.sum(), p - cog), direct_inertia(masses, points, p), rtol=1e-12
    )
    body = RigidBody(masses.sum(), cog, i_g)
    np.testing.assert_allclose(body.inertia_about(p), direct_inertia(masses, points, p), rtol=1e-12)


def test_rotate_inertia_matches_the_rotated_cloud(cloud):
    masses, points = cloud
    cog = masses @ points / masses.sum()
    rot = rotation_matrix([0.3, -1.0, 0.4], 0.7)
    rotated = (points - cog) @ rot.T
    np.testing.assert_allclose(
        rotate_inertia(direct_inertia(masses, points, cog), rot),
        direct_inertia(masses, rotated, np.zeros(3)),
        rtol=1e-12,
        atol=1e-14,
    )


def test_rotation_matrix_is_right_handed():
    axis, angle = np.array([1.0, 2.0, -0.5]), 0.9
    np.testing.assert_allclose(
        rotation_matrix(axis, angle),
        Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix(),
        atol=1e-15,
    )
    np.testing.assert_allclose(
        rotation_matrix([0, 0, 1], np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15
    )
    with pytest.raises(PhysicsError, match="non-zero"):
        rotation_matrix([0, 0, 0], 1.0)


def test_skew_is_the_cross_product():
    v, w = np.array([0.3, -1.2, 2.0]), np.array([1.1, 0.4, -0.7])
    np.testing.assert_allclose(skew(v) @ w, np.cross(v, w), atol=1e-15)
    np.testing.assert_allclose(skew(v).T, -skew(v))


def test_principal_axes(cloud):
    masses, points = cloud
    cog = masses @ points / masses.sum()
    i_g = direct_inertia(masses, points, cog)
    moments, axes = principal(i_g)
    assert np.all(np.diff(moments) >= 0)
    assert np.linalg.det(axes) == pytest.approx(1.0)
    np.testing.assert_allclose(axes @ np.diag(moments) @ axes.T, i_g, rtol=1e-12, atol=1e-14)
    # A box turned by a known rotation: the principal axes are the turned box axes.
    rot = rotation_matrix([1, 1, 0], 0.4)
    box = rotate_inertia(np.diag([1.0, 2.0, 2.5]), rot)
    m, a = principal(box)
    np.testing.assert_allclose(m, [1.0, 2.0, 2.5], rtol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(a * rot, axis=0)), 1.0, rtol=1e-12)


def test_consistency_problems():
    assert consistency_problems(inertia_matrix(4.6, 3.1, 4.2, 0.28, -0.42, 0.21)) == []
    assert "positive definite" in consistency_problems(np.diag([1.0, -1.0, 2.0]))[0]
    assert "triangle" in consistency_problems(np.diag([1.0, 1.0, 3.0]))[0]
    assert (
        "symmetric" in consistency_problems(np.array([[1.0, 0.2, 0], [0, 1.0, 0], [0, 0, 1.0]]))[0]
    )
    # Every real point cloud passes.
    rng = np.random.default_rng(1)
    for _ in range(20):
        pts = rng.normal(size=(5, 3))
        assert consistency_problems(direct_inertia(rng.uniform(0.1, 1, 5), pts, pts.mean(0))) == []


def test_rigid_body_refuses_impossible_values_in_one_line():
    with pytest.raises(PhysicsError, match=r"mass must be positive, got -1"):
        RigidBody(-1.0, np.zeros(3), np.eye(3))
    with pytest.raises(PhysicsError) as err:
        RigidBody(100.0, np.zeros(3), np.diag([1.0, 1.0, 3.0]))
    assert "\n" not in str(err.value) and "3.0" in str(err.value)
    with pytest.raises(PhysicsError, match="shape"):
        RigidBody(100.0, np.zeros(2), np.eye(3))
