"""The geometry the Rerun view draws: the equivalent box of the principal moments, the cog
ellipsoid, the displacement from the fitted accelerations, the exaggerated pose."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2
from support.viewer_checks import uniform_box_moments

from estimator.kinematics import fit_rigid_motion
from estimator.result import principal_axes
from ptinertia.config import load_bench
from ptinertia.viewer.scene import (
    covariance_ellipsoid,
    displacement_amplitudes,
    displacement_at,
    equivalent_box,
    exaggerated_pose,
    nice_exaggeration,
    peak_excursion,
)

ROOT = Path(__file__).resolve().parents[3]
I3 = ROOT / "examples" / "i3-bench.toml"


# -- geometry ---------------------------------------------------------------------------------


def test_equivalent_box_has_the_principal_moments():
    bench = load_bench(I3)
    moments, _ = principal_axes(bench.powertrain.inertia_kgm2.matrix())
    half = equivalent_box(moments, 110.0)
    np.testing.assert_allclose(uniform_box_moments(half, 110.0), moments, rtol=1e-12)


def test_cog_ellipsoid_holds_the_right_share_of_samples():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(3, 3)) * 1e-3
    cov = a @ a.T + np.diag([1e-7, 4e-7, 2e-7])
    half, axes = covariance_ellipsoid(cov, 2.0)
    assert np.isclose(np.linalg.det(axes), 1.0)
    # points on the drawn surface have Mahalanobis distance k
    u = rng.normal(size=(50, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    surface = (axes @ (half * u).T).T
    np.testing.assert_allclose(np.einsum("ij,jk,ik->i", surface, np.linalg.inv(cov), surface), 4.0)
    # and it holds P(chi2_3 <= 4) = 0.739 of Gaussian samples
    n = 40000
    x = rng.multivariate_normal(np.zeros(3), cov, size=n)
    local = x @ axes / half
    share = np.mean(np.sum(local**2, axis=1) <= 1.0)
    p = chi2.cdf(4.0, 3)
    assert abs(share - p) < 4 * np.sqrt(p * (1 - p) / n)


def test_displacement_matches_the_harmonic_solve(i3_simulated):
    """u_G and theta from the fitted accelerations equal the model's own 6x6 solve."""
    bench, model, _ = i3_simulated
    orders = (1.0, 1.5, 2.0)
    rpm = 3100.0
    amps = model.channel_amplitudes(rpm, orders)[0]
    motion = fit_rigid_motion(amps, model.channel_positions, model.channel_directions)
    u_o, theta = displacement_amplitudes(motion, orders, rpm)
    cog = np.asarray(bench.powertrain.cog_m)
    u_g = u_o + np.cross(theta, cog - motion.origin)
    q = model.response(rpm, orders)
    np.testing.assert_allclose(u_g, q[:, :3], rtol=1e-7, atol=1e-9 * np.abs(q[:, :3]).max())
    np.testing.assert_allclose(theta, q[:, 3:], rtol=1e-7, atol=1e-9 * np.abs(q[:, 3:]).max())


def test_displacement_twice_differentiated_is_the_acceleration(i3_simulated):
    _, model, _ = i3_simulated
    orders = np.array([1.0, 1.5, 2.0])
    rpm = 2400.0
    omega = rpm * 2 * np.pi / 60
    motion = fit_rigid_motion(
        model.channel_amplitudes(rpm, orders)[0], model.channel_positions, model.channel_directions
    )
    u_o, theta = displacement_amplitudes(motion, orders, rpm)
    t, dt = 0.0123, 2e-5
    u = [displacement_at(u_o, theta, orders, omega * s)[0] for s in (t - dt, t, t + dt)]
    accel = (u[0] - 2 * u[1] + u[2]) / dt**2
    expected = (motion.gamma_o * np.exp(1j * orders * omega * t)[:, None]).sum(axis=0).real
    np.testing.assert_allclose(accel, expected, rtol=1e-4, atol=1e-4 * np.abs(expected).max())


def test_exaggerated_pose_is_the_rigid_displacement_to_first_order():
    rng = np.random.default_rng(5)
    origin, u, theta = rng.normal(size=3), rng.normal(size=3) * 1e-5, rng.normal(size=3) * 1e-5
    points = rng.normal(size=(5, 3))
    for e in (1.0, 10.0):
        t, r = exaggerated_pose(origin, u, theta, e)
        moved = points @ r.T + t
        linear = points + e * (u + np.cross(theta, points - origin))
        np.testing.assert_allclose(moved, linear, atol=10 * (e * 1e-5 * 3) ** 2)
    t, r = exaggerated_pose(origin, u, theta, 1e4)  # large: still a proper rotation
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(r), 1.0)
    t, r = exaggerated_pose(origin, u, np.zeros(3), 300.0)
    np.testing.assert_allclose(points @ r.T + t, points + 300.0 * u, atol=1e-15)


@pytest.mark.parametrize("excursion", [3.7e-6, 1e-5, 2.4e-4, 0.02])
def test_exaggeration_is_the_largest_1_2_5_step_within_target(excursion):
    target = 0.05
    e = nice_exaggeration(excursion, target)
    mantissa = e / 10 ** np.floor(np.log10(e))
    assert np.isclose(mantissa, 1) or np.isclose(mantissa, 2) or np.isclose(mantissa, 5)
    assert e * excursion <= target * (1 + 1e-12)
    steps = [1, 2, 5, 10, 20, 50]
    above = next(
        s * 10 ** np.floor(np.log10(e))
        for s in steps
        if s * 10 ** np.floor(np.log10(e)) > e * 1.001
    )
    assert above * excursion > target or e == 1.0


def test_peak_excursion_bounds_the_motion_of_points_within_radius():
    rng = np.random.default_rng(8)
    orders = np.array([1.0, 1.5, 2.0])
    u_o = (rng.normal(size=(3, 3)) + 1j * rng.normal(size=(3, 3))) * 1e-5
    theta = (rng.normal(size=(3, 3)) + 1j * rng.normal(size=(3, 3))) * 1e-5
    radius = 0.4
    bound = peak_excursion(u_o, theta, radius)
    worst = 0.0
    for phi in np.linspace(0, 4 * np.pi, 97):
        u, th = displacement_at(u_o, theta, orders, phi)
        p = rng.normal(size=(20, 3))
        p *= radius / np.linalg.norm(p, axis=1, keepdims=True)
        worst = max(worst, float(np.abs(u + np.cross(th, p)).max()))
    assert worst <= bound and worst > 0.2 * bound
