"""Modal mass-line method (paper eqs. 9-13) on simulated hammer FRFs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from acquisition.classical.classic_sim import (
    ElasticModeSpec,
    Hit,
    default_hits,
    simulate_frfs,
    soft_suspension,
)
from estimator.classical.massline import estimate_mass_line
from estimator.classical.massline_band import (
    FrfGeometry,
    MassLineError,
    choose_band,
    mass_line_accelerance,
)
from estimator.classical.massline_rigid import MassLineTolerances, rigid_body_from_mass_line
from powertrain.mounted import MountedPowertrain
from powertrain.rigidbody import inertia_matrix
from ptinertia.cli import main
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_physics import build_model

BENCH = load_bench(EXAMPLES_DIR / "i3-bench.toml")
MODEL = build_model(BENCH)
BODY = MODEL.body
HITS = default_hits([s.position_m for s in BENCH.sensors])
GEOMETRY = FrfGeometry(
    MODEL.channel_positions,
    MODEL.channel_directions,
    np.array([h.position for h in HITS]),
    np.array([h.direction for h in HITS]),
    channel_sensor=np.repeat(np.arange(3), 3),
)
TERMS = ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
TRUTH = np.array([BODY.mass, *BODY.cog, *(BODY.terms[t] for t in TERMS)])
FREQ = np.arange(0.5, 400.0 + 1e-9, 0.25)
SUSPENSION = soft_suspension(BODY, top_hz=5.0)
ELASTIC = ElasticModeSpec(frequency_hz=250.0, axis=tuple(BENCH.engine.crank_axis))


def test_mass_line_is_the_free_body_response_to_a_unit_force():
    """Eq. 13 against Newton-Euler by hand and against the mounted model without mounts."""
    a0 = mass_line_accelerance(BODY.mass, BODY.cog, BODY.inertia, GEOMETRY)
    free = MountedPowertrain(BODY, ())
    w = 2 * np.pi * 37.0
    for e, hit in enumerate(HITS):
        gamma_g = hit.direction / BODY.mass
        omega_dot = np.linalg.solve(BODY.inertia, np.cross(hit.position - BODY.cog, hit.direction))
        load = np.hstack([hit.direction, np.cross(hit.position - BODY.cog, hit.direction)])
        q = free.response(w, [1.0], load[None, :])  # (1, 6) [u_G, theta]
        for c in range(9):
            r = MODEL.channel_positions[c] - BODY.cog
            d = MODEL.channel_directions[c]
            assert a0[c, e] == pytest.approx(d @ (gamma_g + np.cross(omega_dot, r)), abs=1e-15)
            acc = free.point_acceleration(q, w, [1.0], MODEL.channel_positions[c])[0]
            assert a0[c, e] == pytest.approx((d @ acc).real, abs=1e-15)


def test_exact_mass_line_gives_the_body_back():
    a0 = mass_line_accelerance(BODY.mass, BODY.cog, BODY.inertia, GEOMETRY)
    fit = rigid_body_from_mass_line(a0, np.full(a0.shape, 1e-6), GEOMETRY)
    np.testing.assert_allclose(fit.theta, TRUTH, rtol=1e-9, atol=1e-12)
    # Three hits are enough; two leave I + c n n^T undetermined (n normal to both Omega').
    for keep, ok in (([0, 2, 4], True), ([0, 3], False)):
        sub = FrfGeometry(
            GEOMETRY.channel_positions,
            GEOMETRY.channel_directions,
            GEOMETRY.force_positions[keep],
            GEOMETRY.force_directions[keep],
        )
        if ok:
            three = rigid_body_from_mass_line(a0[:, keep], np.full((9, len(keep)), 1e-6), sub)
            np.testing.assert_allclose(three.theta, TRUTH, rtol=1e-9, atol=1e-12)
        else:
            with pytest.raises(MassLineError, match="need at least 3 excitations"):
                rigid_body_from_mass_line(a0[:, keep], np.full((9, len(keep)), 1e-6), sub)


def test_simulated_suspension_is_soft():
    modes = MountedPowertrain(BODY, SUSPENSION).modes().frequency_hz
    assert 1.8 < modes.min() and modes.max() == pytest.approx(5.0, rel=1e-9)


@pytest.fixture(scope="module")
def noisy_frfs() -> np.ndarray:
    return simulate_frfs(
        BODY,
        MODEL.channel_positions,
        MODEL.channel_directions,
        HITS,
        FREQ,
        SUSPENSION,
        ELASTIC,
        snr_db=40.0,
        seed=0,
    )


def errors(theta: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Mass error (relative), cog error (m), inertia errors (relative per term)."""
    e = theta - TRUTH
    return e[0] / TRUTH[0], e[1:4], e[4:] / np.abs(TRUTH[4:])


def test_noisy_frfs_give_mass_cog_and_inertia_within_tolerance(noisy_frfs):
    result = estimate_mass_line(FREQ, noisy_frfs, GEOMETRY)
    mass, cog, inertia = errors(result.body.theta)
    assert abs(mass) < 0.005
    assert np.all(np.abs(cog) < 0.002)
    assert np.all(np.abs(inertia) < 0.02)
    # The band lies between the suspension (5 Hz) and the elastic mode (250 Hz).
    assert 3 * 4.9 <= result.band.low_hz and result.band.high_hz <= 250 / 2.5 + 0.5
    assert result.band.chosen == "auto"
    assert any(abs(r - 250) < 1 for r in result.band.resonances_hz)
    # The intervals are honest: every parameter within 3.5 of its standard deviations.
    assert np.all(np.abs(result.body.theta - TRUTH) < 3.5 * result.body.std)


def test_without_residual_stiffness_the_suspension_biases_the_result(noisy_frfs):
    """The 1/w^2 term removes a bias of the order (f_suspension / f_band)^2."""
    with_term = estimate_mass_line(FREQ, noisy_frfs, GEOMETRY)
    without = estimate_mass_line(FREQ, noisy_frfs, GEOMETRY, residual_stiffness=False)
    assert with_term.fit.powers[0] < 0 and all(k > 0 for k in without.fit.powers)
    _, _, inertia = errors(without.body.theta)
    # The suspension adds stiffness: the body looks lighter in rotation, by more than 2 %.
    assert np.max(np.abs(inertia[:3])) > 0.02 and np.all(inertia[:3] < 0)
    bias = np.abs(without.body.theta - TRUTH) / without.body.std
    assert bias.max() > 20  # far outside its own intervals
    _, _, fixed = errors(with_term.body.theta)
    assert np.max(np.abs(fixed[:3])) < 0.2 * np.max(np.abs(inertia[:3]))


def test_band_choice_on_exact_data_is_between_the_modes():
    h = simulate_frfs(
        BODY, MODEL.channel_positions, MODEL.channel_directions, HITS, FREQ, SUSPENSION, ELASTIC
    )
    band = choose_band(FREQ, h)
    assert band.low_hz == pytest.approx(3 * 5.0, abs=0.25 * 3)
    assert band.high_hz == pytest.approx(250 / 2.5, abs=0.25)
    # Exact data with a stiff-ish suspension: the fit's higher terms make the bias tiny.
    result = estimate_mass_line(FREQ, h, GEOMETRY)
    mass, cog, inertia = errors(result.body.theta)
    assert abs(mass) < 2e-4 and np.all(np.abs(cog) < 1e-4) and np.all(np.abs(inertia) < 2e-3)


@pytest.mark.parametrize(
    ("band", "reason"),
    [
        ((1.0, 6.0), "holds no mass line"),
        ((200.0, 300.0), "holds no mass line"),
        ((6.0, 12.0), "too close to the modes"),
        ((300.0, 395.0), "holds no mass line"),
    ],
    ids=["suspension", "elastic-mode", "near-suspension", "above-elastic"],
)
def test_a_band_without_mass_line_is_refused(noisy_frfs, band, reason):
    with pytest.raises(MassLineError, match=reason):
        estimate_mass_line(FREQ, noisy_frfs, GEOMETRY, band=band)


def test_force_gauge_tolerance_propagates_as_a_scale():
    """A gauge error g scales every accelerance by 1/(1+g): mass and inertia by (1+g), cog not."""
    a0 = mass_line_accelerance(BODY.mass, BODY.cog, BODY.inertia, GEOMETRY)
    fit = rigid_body_from_mass_line(
        a0, np.full(a0.shape, 1e-9), GEOMETRY, MassLineTolerances(force_gain_rel=0.01)
    )
    sys_std = np.sqrt(np.diag(fit.cov_systematic))
    np.testing.assert_allclose(sys_std[[0, 4, 5, 6]], 0.01 * TRUTH[[0, 4, 5, 6]], rtol=1e-6)
    np.testing.assert_allclose(sys_std[4:], 0.01 * np.abs(TRUTH[4:]), rtol=1e-6)
    assert np.all(sys_std[1:4] < 1e-9)


def test_hit_direction_tolerance_widens_what_it_should(noisy_frfs):
    base = estimate_mass_line(FREQ, noisy_frfs, GEOMETRY)
    tilted = estimate_mass_line(
        FREQ,
        noisy_frfs,
        GEOMETRY,
        tolerances=MassLineTolerances(hit_direction_rad=np.radians(2.0), hit_position_m=0.002),
    )
    assert np.all(tilted.body.std >= base.body.std - 1e-15)
    assert tilted.body.std[0] > 1.5 * base.body.std[0]


def test_a_skewed_hit_and_a_negative_direction_are_just_other_geometry():
    hits = (*HITS[:4], Hit("skew", np.array([0.0, 0.1, 0.3]), np.array([0.3, -0.5, 0.81])))
    h = simulate_frfs(
        BODY, MODEL.channel_positions, MODEL.channel_directions, hits, FREQ, SUSPENSION, ELASTIC
    )
    geometry = FrfGeometry(
        MODEL.channel_positions,
        -MODEL.channel_directions,
        np.array([x.position for x in hits]),
        np.array([x.direction for x in hits]),
    )
    result = estimate_mass_line(FREQ, -h, geometry)
    mass, cog, inertia = errors(result.body.theta)
    assert abs(mass) < 1e-3 and np.all(np.abs(cog) < 2e-4) and np.all(np.abs(inertia) < 5e-3)


def test_a_wrong_hit_direction_in_the_setup_is_refused():
    """A hit declared along X that went along Y: the constants fit no rigid body."""
    a0 = mass_line_accelerance(BODY.mass, BODY.cog, BODY.inertia, GEOMETRY)
    wrong = GEOMETRY.force_directions.copy()
    wrong[0] = [0.0, 1.0, 0.0]
    geometry = FrfGeometry(
        GEOMETRY.channel_positions, GEOMETRY.channel_directions, GEOMETRY.force_positions, wrong
    )
    with pytest.raises(MassLineError, match="not those of one rigid body"):
        rigid_body_from_mass_line(a0, np.full(a0.shape, 1e-3 * np.abs(a0).max()), geometry)


def test_wrong_sign_of_the_force_is_refused():
    a0 = mass_line_accelerance(BODY.mass, BODY.cog, inertia_matrix(4.6, 3.1, 4.2), GEOMETRY)
    with pytest.raises(MassLineError, match="not positive"):
        rigid_body_from_mass_line(-a0, np.full(a0.shape, 1e-6), GEOMETRY)


def test_massline_command_on_simulated_uff(tmp_path, capsys):
    frf = tmp_path / "frf.uff"
    bench = str(EXAMPLES_DIR / "i3-bench.toml")
    assert (
        main(
            [
                "simulate-frf",
                "--bench",
                bench,
                "--out",
                str(frf),
                "--df-hz",
                "0.5",
                "--fmax-hz",
                "300",
            ]
        )
        == 0
    )
    out = tmp_path / "ml.json"
    assert main(["massline", str(frf), "--bench", bench, "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["method"] == "massline"
    assert abs(doc["mass_kg"]["value"] - 110.0) < 0.005 * 110.0
    assert np.allclose(doc["cog_m"]["value"], BENCH.powertrain.cog_m, atol=0.002)
    for t in TERMS:
        true = getattr(BENCH.powertrain.inertia_kgm2, t)
        assert abs(doc["inertia_kgm2"]["value"][t] - true) < 0.02 * abs(true), t
    assert doc["band_hz"]["chosen"] == "auto"
    report = capsys.readouterr().out
    assert re.search(r"band 15 to 100(\.\d)? Hz \(auto; resonances at \[.*250.*\] Hz\)", report)
    # Bad input: a band with no mass line, one line and exit code 2.
    assert main(["massline", str(frf), "--bench", bench, "--band", "200", "280"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "holds no mass line" in err
    # Bad input: the bench names sensors where the file has no nodes.
    other = str(EXAMPLES_DIR / "i4-bench.toml")
    assert main(["massline", str(frf), "--bench", other]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "has no node within 5 mm" in err
