"""Rpm profiles: exact crank angle, its inverse, and the rpm it integrates."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from acquisition.sim.sweep import RpmProfile, hold, parse_sweep, ramp
from acquisition.stream import SourceError
from ptinertia.config import Simulation
from ptinertia.to_acquisition import sweep_profile

W = 2 * math.pi / 60  # rpm -> rad/s


def mixed_profile() -> RpmProfile:
    # hold, fast ramp up, a step down, slow ramp down, hold, a tiny slope (cancellation-prone)
    return RpmProfile(
        [
            hold(1500, 2.0),
            ramp(1500, 4500, 6.0),
            ramp(3000, 800, 3.0),
            hold(800, 1.0),
            ramp(800, 800.000001, 5.0),
        ],
        phi0_rad=0.3,
    )


def test_rpm_is_the_piecewise_linear_interpolation_of_the_points() -> None:
    times = [0.0, 2.0, 8.0, 8.0, 11.0, 12.0]
    rpms = [1500.0, 1500.0, 4500.0, 3000.0, 800.0, 800.0]
    p = RpmProfile.from_points(times, rpms)
    t = np.random.default_rng(0).uniform(0, 12, 2000)
    t = t[np.abs(t - 8.0) > 1e-9]
    expected = np.where(
        t < 8.0, np.interp(t, times[:3], rpms[:3]), np.interp(t, times[3:], rpms[3:])
    )
    np.testing.assert_allclose(p.rpm(t), expected, rtol=1e-13)
    assert len(p.segments) == 4  # the repeated time is a step, not a segment


def test_phi_is_the_integral_of_the_rpm() -> None:
    p = mixed_profile()
    breaks = np.cumsum([0.0] + [s.duration_s for s in p.segments])
    for t_end in (1.3, 2.0, 5.7, 9.9, 11.5, 17.0):
        pts = [b for b in breaks if 0 < b < t_end]
        integral, _ = quad(
            lambda t: float(p.omega(np.array([t]))[0]),
            0.0,
            t_end,
            points=pts or None,
            limit=200,
            epsabs=1e-12,
            epsrel=1e-13,
        )
        assert p.phi(np.array([t_end]))[0] - 0.3 == pytest.approx(integral, rel=1e-11)


def test_ramp_angle_closed_form() -> None:
    p = RpmProfile([ramp(1000, 3000, 4.0)])
    # linear speed: the angle is the mean speed times the duration
    assert p.phi(np.array([4.0]))[0] == pytest.approx(0.5 * (1000 + 3000) * W * 4.0, rel=1e-15)
    assert p.phi_end == pytest.approx(2000 * W * 4.0, rel=1e-15)


def test_phi_is_continuous_across_segments_and_steps() -> None:
    p = mixed_profile()
    eps = 1e-9
    for b in np.cumsum([s.duration_s for s in p.segments])[:-1]:
        before, after = p.phi(np.array([b - eps, b + eps]))
        assert 0 < after - before < 2 * eps * 4500 * W * (1 + 1e-6)


def test_t_of_phi_inverts_phi_to_a_picosecond() -> None:
    p = mixed_profile()
    t = np.concatenate(
        [
            np.random.default_rng(1).uniform(-1.0, p.duration_s + 1.0, 200_000),
            np.cumsum([0.0] + [s.duration_s for s in p.segments]),
        ]
    )
    assert np.max(np.abs(p.t_of_phi(p.phi(t)) - t)) < 1e-12
    phi = np.random.default_rng(2).uniform(p.phi_start[0] - 10, p.phi_end + 10, 10_000)
    assert np.max(np.abs(p.phi(p.t_of_phi(phi)) - phi)) < 1e-9 * max(1.0, p.phi_end)


def test_phi_strictly_increasing_also_beyond_the_ends() -> None:
    p = mixed_profile()
    t = np.linspace(-2.0, p.duration_s + 2.0, 100_001)
    assert np.all(np.diff(p.phi(t)) > 0)
    # ends held: the speed before 0 is the first rpm, after the end the last one
    assert p.rpm(np.array([-1.0]))[0] == pytest.approx(1500)
    assert p.rpm(np.array([p.duration_s + 1.0]))[0] == pytest.approx(800.000001)


def test_default_profile_from_simulation() -> None:
    p = sweep_profile(Simulation(rpm_start=1200, rpm_end=5000, duration_s=30, hold_s=4))
    assert [(s.rpm_from, s.rpm_to, s.duration_s) for s in p.segments] == [
        (1200, 1200, 4),
        (1200, 5000, 30),
    ]
    assert p.duration_s == 34
    assert p.phi(np.array([0.0]))[0] == 0.0
    p = sweep_profile(Simulation(rpm_start=1200, rpm_end=5000, duration_s=30))
    assert len(p.segments) == 1


@pytest.mark.parametrize(
    ("segments", "match"),
    [
        ([], "at least one segment"),
        ([ramp(1000, 2000, 0.0)], "duration must be > 0"),
        ([ramp(1000, 0.0, 1.0)], "rpm must stay > 0"),
        ([hold(-5, 1.0)], "rpm must stay > 0"),
    ],
)
def test_bad_profiles_are_refused(segments: list, match: str) -> None:
    with pytest.raises(SourceError, match=match):
        RpmProfile(segments)


def test_parse_sweep() -> None:
    assert parse_sweep("1500:4500") == (1500.0, 4500.0)
    assert parse_sweep("3000") == (3000.0, 3000.0)
    for bad in ("", "a:b", "1:2:3", "-5:100", "0", "nan"):
        with pytest.raises(SourceError, match="expected RPM"):
            parse_sweep(bad)
