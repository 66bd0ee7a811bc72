"""Slider-crank kinematics and its exact Fourier series, checked against independent results."""

from __future__ import annotations

import numpy as np
import pytest

from powertrain.errors import PhysicsError
from powertrain.slider_crank import (
    SliderCrank,
    kinematics,
    piston_acceleration_coefficients,
    piston_motion,
    piston_position_coefficients,
)

R, L, A = 0.042, 0.133, 0.040
N = 2048
THETA = np.arange(N) * 2 * np.pi / N


def spectral_derivative(y: np.ndarray) -> np.ndarray:
    """d/dtheta of a smooth 2 pi-periodic sampled function (exact to rounding for band-limited data)."""
    k = np.fft.rfftfreq(y.size, 1.0 / y.size)
    return np.fft.irfft(1j * k * np.fft.rfft(y), y.size)


def test_positions_satisfy_the_rod_length_constraint():
    k = kinematics(THETA, R, L, A)
    pin = np.stack([k.pc, k.pt], axis=1)
    small_end = np.stack([k.x, np.zeros(N)], axis=1)
    rod = small_end - pin
    np.testing.assert_allclose(np.linalg.norm(rod, axis=1), L, rtol=1e-14)
    # psi is the angle of big end -> small end from c, right hand about s.
    np.testing.assert_allclose(
        rod / L, np.stack([np.cos(k.psi), np.sin(k.psi)], axis=1), atol=1e-14
    )
    # The rod cog lies on the rod at a from the big end.
    np.testing.assert_allclose(np.stack([k.gc, k.gt], axis=1), pin + A / L * rod, atol=1e-15)


@pytest.mark.parametrize("name", ["x", "psi", "gc", "gt"])
def test_derivatives_match_spectral_differentiation(name):
    k = kinematics(THETA, R, L, A)
    y = getattr(k, name)
    d1 = spectral_derivative(y)
    d2 = spectral_derivative(d1)
    scale = np.abs(y - y.mean()).max()
    np.testing.assert_allclose(getattr(k, name + "_t"), d1, atol=1e-10 * scale)
    np.testing.assert_allclose(getattr(k, name + "_tt"), d2, atol=1e-9 * scale)


def test_piston_motion_alone_is_the_kinematics_piston_and_its_derivative():
    # the volume and the gas torque take x and dx/dtheta alone: the kinematics' bits
    # (the derivative itself is checked against spectral differentiation above)
    k = kinematics(THETA, R, L, A)
    x, x_t = piston_motion(THETA, R, L)
    assert (x.tobytes(), x_t.tobytes()) == (k.x.tobytes(), k.x_t.tobytes())
    np.testing.assert_allclose(x_t, spectral_derivative(x), atol=1e-10 * np.ptp(x))


@pytest.mark.parametrize("lam", [0.1, 0.316, 0.45])
def test_exact_series_matches_time_domain_fft(lam):
    max_order = 24
    k = kinematics(THETA, 1.0, 1.0 / lam)
    fft_x = np.fft.rfft(k.x)[: max_order + 1] * 2 / N
    fft_x[0] /= 2
    fft_a = np.fft.rfft(k.x_tt)[: max_order + 1] * 2 / N
    c = piston_position_coefficients(lam, max_order)
    a = piston_acceleration_coefficients(lam, max_order)
    np.testing.assert_allclose(fft_x.real, c, atol=1e-9)
    np.testing.assert_allclose(fft_a.real, a, atol=1e-9)
    assert np.abs(fft_a.imag).max() < 1e-12  # x is even in theta: cosines only


def test_series_matches_textbook_expansion():
    # Textbook (e.g. Taylor, The ICE in theory and practice, vol. 2):
    # x_tt / r = -(cos t + A2 cos 2t - A4 cos 4t + A6 cos 6t ...), errors O(lambda^7).
    lam = 0.15
    a = piston_acceleration_coefficients(lam, 6)
    expected = {
        1: -1.0,
        2: -(lam + lam**3 / 4 + 15 * lam**5 / 128),
        4: lam**3 / 4 + 3 * lam**5 / 16,
        6: -9 * lam**5 / 128,
    }
    for order, value in expected.items():
        assert a[order] == pytest.approx(value, abs=2 * lam**7)
    assert np.all(a[[0, 3, 5]] == 0)


def test_reciprocating_force_first_terms():
    # m_rec r w^2 (cos t + lambda cos 2t): the exact order-2 term differs by lambda^3/4 only.
    sc = SliderCrank(R, L, A, 0.31, 0.42)
    a = piston_acceleration_coefficients(sc.lam, 2)
    assert -a[2] == pytest.approx(sc.lam, rel=sc.lam**2 / 4 * 1.05)
    assert -a[2] - sc.lam == pytest.approx(sc.lam**3 / 4, rel=0.1)


def test_two_mass_rod_is_a_rod_with_inertia_m_a_l_minus_a():
    # Two point masses (m a / l at the small end, the rest at the big end) have the
    # rod's mass and cog; their inertia about the cog is m a (l - a).
    m_rod = 0.42
    sc = SliderCrank(R, L, A, 0.31, m_rod)
    k = sc.kinematics(THETA)
    m_small, m_big = m_rod * A / L, m_rod * (1 - A / L)
    assert m_small * (L - A) ** 2 + m_big * A**2 == pytest.approx(sc.two_mass_inertia, rel=1e-14)
    # Kinetic energy of the point masses vs the rigid-rod formula with J = J_2m.
    ke_points = 0.5 * (0.31 + m_small) * k.x_t**2 + 0.5 * m_big * R**2
    ke_rod = sc.kinetic_energy(THETA)
    # The big-end mass has constant KE, which the rod formula leaves out of the moving parts.
    np.testing.assert_allclose(ke_rod - ke_rod.mean(), ke_points - ke_points.mean(), atol=1e-15)


def test_inertia_torque_is_minus_rate_of_kinetic_energy():
    omega = 400.0
    for inertia in (None, 0.0011, 0.0025):
        sc = SliderCrank(R, L, A, 0.31, 0.42, inertia)
        ke = sc.kinetic_energy(THETA, omega)
        # T omega = -dKE/dt = -omega dKE/dtheta
        expected = -spectral_derivative(ke)
        np.testing.assert_allclose(
            sc.inertia_torque(THETA, omega), expected, atol=1e-9 * np.abs(expected).max()
        )
        assert abs(sc.inertia_torque(THETA, omega).mean()) < 1e-9 * np.abs(expected).max()


def test_bad_geometry_raises_physics_error():
    with pytest.raises(PhysicsError, match="lambda"):
        SliderCrank(0.1, 0.09, 0.03, 0.3, 0.4)
    with pytest.raises(PhysicsError, match="outside the rod"):
        SliderCrank(0.04, 0.13, 0.2, 0.3, 0.4)
    with pytest.raises(PhysicsError, match="lambda"):
        piston_position_coefficients(1.2, 4)
