"""The residual unbalance with its location: a static part and a couple, both linear.

Checked against results derived apart from ``estimator.equations``: the harness's
forward model puts each point unbalance's force at its own point
(``np.cross``, not the ``s x (c - i t) = i (c - i t)`` identity the rows use);
``powertrain.balancing`` (the simulator's unbalance model, crank angle by crank
angle) gives the force and moment whose order-1 Fourier coefficients the rows'
columns must reproduce; the delta-method intervals are checked against sampling.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.estimator_harness import AXIS_C, AXIS_S, UNB_POINT, Body, frames, make_setup
from support.estimator_runs import I3, cog_error_m, rel_errors, run

from estimator.equations import Linearisation, ParameterLayout, frame_rows
from estimator.setup import Corrections
from estimator.streaming import InertiaEstimator
from estimator.unbalance import unbalance_report
from powertrain.balancing import Unbalance, add_balancing_loads

RPMS = np.linspace(1500, 4500, 60)
BETA = np.radians(120.0)
Z = 1e-3 * np.exp(-1j * BETA)  # 1 g m at 120 deg


def _estimate(body: Body, **kw: object) -> InertiaEstimator:
    located = Corrections(unbalance_location=True)
    est = InertiaEstimator(make_setup(body, corrections=located, **kw))
    for f in frames(body, RPMS):
        est.update(f)
    return est


@pytest.mark.parametrize("mass_known", [True, False])
def test_an_off_centre_point_unbalance_is_located_and_the_body_comes_back(
    mass_known: bool,
) -> None:
    body = Body(point_unbalances=((Z, 0.08),))
    e = _estimate(body, mass_known=mass_known).estimate()
    np.testing.assert_allclose(e.inertia, body.inertia, rtol=0, atol=1e-9)
    np.testing.assert_allclose(e.cog, body.cog, rtol=0, atol=1e-10)
    unb = e.unbalance()
    assert unb is not None
    assert unb["mr_kgm"]["value"] == pytest.approx(1e-3, rel=1e-8)
    assert unb["angle_deg"]["value"] == pytest.approx(120.0, abs=1e-6)
    assert unb["axial_m"]["value"] == pytest.approx(0.08, abs=1e-9)
    np.testing.assert_allclose(unb["point_m"], UNB_POINT + 0.08 * AXIS_S, atol=1e-9)
    assert unb["couple_kgm2"]["value"] < 1e-12  # a point unbalance leaves no couple


def test_a_two_plane_unbalance_leaves_its_couple() -> None:
    # the static 1 g m at 120 deg, 30 mm off, and a pair of 0.5 g m 200 mm apart at 90 deg
    # to it: +s side at 210 deg, -s side opposite; the pair is a couple of 0.1 g m^2
    pair = 0.5e-3 * np.exp(-1j * np.radians(210.0))
    body = Body(point_unbalances=((Z, 0.03), (pair, 0.1), (-pair, -0.1)))
    unb = _estimate(body).estimate().unbalance()
    assert unb is not None
    assert unb["mr_kgm"]["value"] == pytest.approx(1e-3, rel=1e-8)
    assert unb["axial_m"]["value"] == pytest.approx(0.03, abs=1e-9)
    assert unb["couple_kgm2"]["value"] == pytest.approx(1e-4, rel=1e-7)
    assert unb["couple_angle_deg"]["value"] == pytest.approx(-150.0, abs=1e-5)  # 210 deg


@pytest.mark.parametrize("mass_known", [True, False])
def test_the_columns_are_the_simulators_point_unbalance(mass_known: bool) -> None:
    """A point unbalance (powertrain.balancing, sampled over a revolution) moves the rows'
    residual by the static and couple columns times z and a z."""
    rng = np.random.default_rng(3)
    mass, cog = 110.0, np.array([0.035, -0.085, 0.105])
    mr, axial, rpm = 1e-3, 0.08, 3000.0
    w2 = (rpm * 2 * np.pi / 60) ** 2
    n = 64
    phi = 2 * np.pi * np.arange(n) / n
    force, moment = np.zeros((n, 3)), np.zeros((n, 3))
    s, c = AXIS_S, AXIS_C
    add_balancing_loads(
        force, moment, [Unbalance(mr, BETA, axial)], [], phi, (s, c, np.cross(s, c)), UNB_POINT, cog
    )
    # order-1 amplitudes, x(phi) = Re(X exp(i phi)), at the crank speed
    basis = 2.0 / n * np.exp(-1j * phi)
    f1, m1 = w2 * basis @ force, w2 * basis @ moment

    body = Body()
    setup = make_setup(body, mass_known=mass_known)
    layout = ParameterLayout(unbalance=True, mass=not mass_known, offset=False, couple=True)
    lin = Linearisation(cog=cog, inertia=body.inertia, mass=mass)
    motion = rng.normal(size=(1, 6)) + 1j * rng.normal(size=(1, 6))
    rows = frame_rows(
        setup, layout, lin, motion[:, :3], motion[:, 3:], np.zeros(3), np.eye(6),
        np.array([1.0]), rpm, np.zeros((1, 3), complex), np.zeros((1, 3), complex), np.ones(1),
    )  # fmt: skip
    raw = np.linalg.solve(rows.whiten[0], rows.H[0])  # (12, n) before whitening
    cols = [layout.index(k) for k in ("unb_re", "unb_im", "unb_couple_re", "unb_couple_im")]
    z = mr * np.exp(-1j * BETA) / (1.0 if mass_known else mass)
    q = axial * mr * np.exp(-1j * BETA)
    shift = raw[:, cols] @ np.array([z.real, z.imag, q.real, q.imag])
    shift = shift[:6] + 1j * shift[6:]
    # residual rows: translation m gamma - F_unb (or gamma - F_unb / m), rotation ... - M_G
    scale = 1.0 if mass_known else mass
    np.testing.assert_allclose(shift[:3] * scale, -f1, rtol=0, atol=1e-12 * np.abs(f1).max())
    np.testing.assert_allclose(shift[3:], -m1, rtol=0, atol=1e-12 * np.abs(m1).max())


@pytest.mark.parametrize("per_mass", [False, True])
def test_the_delta_method_intervals_match_sampling(per_mass: bool) -> None:
    rng = np.random.default_rng(11)
    mass = 145.0
    q = 0.06 * Z + 2e-5j * Z / abs(Z)  # 60 mm off, and a small couple at 90 deg
    values = [Z.real, Z.imag, q.real, q.imag]
    if per_mass:
        values = [Z.real / mass, Z.imag / mass, q.real, q.imag, 1 / mass]
    values_a = np.array(values)
    a = rng.normal(size=(len(values), len(values)))
    cov = a @ a.T * (1e-4 * np.abs(values_a)[:, None] * np.abs(values_a)[None, :]) / len(values)
    rep = unbalance_report(values_a, cov, True, per_mass, UNB_POINT, AXIS_S)
    assert rep["axial_m"]["value"] == pytest.approx(0.06, rel=1e-12)
    assert rep["couple_kgm2"]["value"] == pytest.approx(2e-5, rel=1e-12)
    draws = rng.multivariate_normal(values_a, cov, size=20000)
    zs = (draws[:, 0] + 1j * draws[:, 1]) / (draws[:, -1] if per_mass else 1.0)
    qs = draws[:, 2] + 1j * draws[:, 3]
    sampled = {
        "mr_kgm": np.abs(zs),
        "angle_deg": np.degrees(-np.angle(zs)),
        "axial_m": (qs * np.conj(zs)).real / np.abs(zs) ** 2,
        "couple_kgm2": (qs * np.conj(zs)).imag / np.abs(zs),
    }
    for key, x in sampled.items():
        assert rep[key]["std"] == pytest.approx(np.std(x), rel=0.05), key


def test_an_undetected_static_part_reports_the_couple_about_the_reference_point() -> None:
    q = 2e-4 * np.exp(-1j * np.radians(30.0))
    cov = np.diag([1e-8, 1e-8, 1e-12, 1e-12])  # m r std 1e-4: 1e-5 is not detected
    rep = unbalance_report(
        np.array([1e-5, 0.0, q.real, q.imag]), cov, True, False, UNB_POINT, AXIS_S
    )
    assert rep["axial_m"] is None
    assert rep["point_m"] == UNB_POINT.tolist()
    assert rep["couple_kgm2"]["value"] == pytest.approx(2e-4, rel=1e-12)
    assert rep["couple_angle_deg"]["value"] == pytest.approx(30.0, abs=1e-9)


def test_noise_free_i3_with_an_off_centre_unbalance_through_the_dsp() -> None:
    """The issue's scenario, a short sweep: simulator -> dsp -> estimator, no noise."""
    doc = run(
        I3,
        {
            "duration_s": 20.0,
            "residual_unbalance_kgm": 1e-3,
            "residual_unbalance_deg": 120.0,
            "residual_unbalance_axial_m": 0.08,
        },
        estimator={"unbalance_location": True},
    )
    errs = rel_errors(doc)
    assert max(abs(e) for e in errs.values()) < 5e-4, errs  # every term within 0.05 %
    assert np.all(cog_error_m(doc) < 1e-4)
    unb = doc["unbalance"]
    assert unb["mr_kgm"]["value"] == pytest.approx(1e-3, rel=0.005)
    assert unb["angle_deg"]["value"] == pytest.approx(120.0, abs=0.5)
    assert unb["axial_m"]["value"] == pytest.approx(0.08, abs=0.002)
    assert unb["point_m"] == pytest.approx([0.0, unb["axial_m"]["value"], 0.0])
