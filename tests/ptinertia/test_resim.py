"""The re-simulation check: the estimate put back in the 6-DOF model against the measured orders.

Independent references: Euler's equations of a free body with a spinning rotor
(the mass-line limit far above the mounts), a Monte Carlo over perturbed sensors
for the tolerance model, the estimator's own unbalance equation, and the
realistic i3 recording (the check passes with the estimate and fails with a
wrong one).
"""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
from support.report_logs import realistic_log

from estimator.setup import Tolerances
from powertrain.rigidbody import rotation_matrix, skew
from ptinertia.config import load_bench
from ptinertia.paths import DEFAULT_BENCH
from ptinertia.report.data import load
from ptinertia.resim import (
    estimated_properties,
    predict,
    resim_check,
    resim_model,
    resolve_half_orders,
    rigid_motion,
    tolerance_sigma,
)
from ptinertia.resim_compare import compare

ORDERS = (1.0, 1.5, 2.0)


def _doc_of_bench(bench, **extra) -> dict:
    """A result document holding the bench file's own powertrain (as if estimated exactly)."""
    p = bench.powertrain
    doc = {
        "inertia_kgm2": {
            "value": {
                k: getattr(p.inertia_kgm2, k) for k in ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz")
            }
        },
        "cog_m": {"value": list(p.cog_m)},
        "mass_kg": None,
        "unbalance": None,
        "crank_offset_deg": None,
        "half_order": None,
    }
    doc.update(extra)
    return doc


def test_far_above_the_mounts_the_model_is_eulers_free_body() -> None:
    """At 60 000 rpm (orders at 1-2 kHz, modes below 20 Hz) mounts add (f_mode / f)^2 ~ 4e-4:
    gamma_G = F / m and I Omega' + (J / (i h)) Omega' x s = M_G (Euler with a spinning rotor:
    d(J w s)/dt = J w Omega x s and Omega = Omega' / (i h w))."""
    bench = load_bench(DEFAULT_BENCH)
    model = resim_model(bench, estimated_properties(_doc_of_bench(bench), bench))
    rpm = 60000.0
    gamma, omega_dot = rigid_motion(model, [rpm], ORDERS)
    force, moment = model.engine.excitation(rpm, ORDERS, about=model.body.cog)
    s = model.engine.crank_axis
    j = model.engine.crank_spin_inertia
    assert j > 0  # the gyroscopic term is really exercised
    for k, h in enumerate(ORDERS):
        a = model.body.inertia - (j / (1j * h)) * skew(s)  # Omega' x s = -skew(s) Omega'
        expected = np.linalg.solve(a, moment[k])
        scale = np.abs(expected).max()  # rad/s^2; the gyroscopic part is ~3 % of it
        np.testing.assert_allclose(omega_dot[0, k], expected, rtol=0, atol=1e-3 * scale)
        # the i3 has no free force: gamma_G is what the mounts leave, against a 0.3 m lever
        np.testing.assert_allclose(
            gamma[0, k], force[k] / model.body.mass, rtol=0, atol=1e-3 * 0.3 * scale
        )


def test_tolerance_model_matches_perturbed_sensors() -> None:
    """sigma from the formula against the scatter of readings of randomly perturbed sensors."""
    bench = load_bench(DEFAULT_BENCH)
    model = resim_model(bench, estimated_properties(_doc_of_bench(bench), bench))
    tol = Tolerances(gain_rel=0.01, alignment_rad=math.radians(1.0), position_m=0.002)
    rpm = 2500.0
    sigma = tolerance_sigma(model, [rpm], ORDERS, tol)[0]  # (n_o, n_ch)
    gamma, omega_dot = rigid_motion(model, [rpm], ORDERS)
    pos, n = model.channel_positions, model.channel_directions
    exact = np.einsum(
        "oci,ci->oc",
        gamma[0][:, None, :] + np.cross(omega_dot[0][:, None, :], pos - model.body.cog),
        n,
    )
    rng = np.random.default_rng(5)
    draws = 4000
    err = np.zeros((draws, *exact.shape), complex)
    for d in range(draws):
        gain = 1 + tol.gain_rel * rng.standard_normal(n.shape[0])
        turn = tol.alignment_rad * rng.standard_normal((n.shape[0], 3))
        shift = tol.position_m * rng.standard_normal((n.shape[0], 3))
        n_d = np.array(
            [rotation_matrix(t, np.linalg.norm(t)) @ v for t, v in zip(turn, n, strict=True)]
        )
        p_d = pos + shift
        a = gamma[0][:, None, :] + np.cross(omega_dot[0][:, None, :], p_d - model.body.cog)
        err[d] = gain * np.einsum("oci,ci->oc", a, n_d) - exact
    empirical = np.sqrt(np.mean(np.abs(err) ** 2, axis=0)) / np.abs(exact)
    np.testing.assert_allclose(sigma, empirical, rtol=0.06)


def test_compare_signs_mass_line_and_judgement() -> None:
    rng = np.random.default_rng(0)
    n, n_o, n_ch = 40, 2, 3
    pred = rng.standard_normal((n, n_o, n_ch)) + 1j * rng.standard_normal((n, n_o, n_ch))
    # the model is 0.3 dB above and leads by 2 deg: meas = pred / (gain * exp(i phase))
    meas = pred / (10 ** (0.3 / 20) * np.exp(1j * np.radians(2.0)))
    mass_line = np.ones((n, n_o), bool)
    mass_line[:10, 0] = False
    meas[:10, 0] *= 10.0  # far off, but outside the mass line: must not count
    sigma = np.full((n, n_o, n_ch), 0.01)
    sigma[:, 1, 2] = 0.2  # one tolerance-limited channel
    c = compare(
        np.linspace(1500, 4500, n), (1.0, 2.0), ("a", "b", "c"), meas, pred, mass_line, sigma
    )
    np.testing.assert_allclose(c.diff_db[10:], 0.3, atol=1e-12)
    np.testing.assert_allclose(c.diff_deg[10:], 2.0, atol=1e-12)
    np.testing.assert_allclose(c.median_db, 0.3, atol=1e-12)
    np.testing.assert_allclose(c.p95_deg, 2.0, atol=1e-12)
    assert c.assessable.tolist() == [[True, True, True], [True, True, False]]
    assert c.passed is True and c.worst_db == pytest.approx(0.3)
    assert c.mass_line_rpm(0)[0] > 1500.0
    worse = compare(c.rpm, c.orders, c.channels, meas / 1.1, pred, mass_line, sigma)  # +0.83 dB
    assert worse.passed is False and worse.worst_db == pytest.approx(0.3 + 20 * math.log10(1.1))


def test_half_orders_turn_only_in_ambiguous_frames() -> None:
    amps = np.ones((3, 3, 2), complex)
    amb = np.array([True, False, True])
    out = resolve_half_orders(amps, ORDERS, amb, -1)
    assert out[:, 1, :].real.tolist() == [[-1, -1], [1, 1], [-1, -1]]
    assert np.all(out[:, [0, 2], :] == 1)
    assert np.all(resolve_half_orders(amps, ORDERS, amb, 1) == 1)


def test_estimated_unbalance_and_offset_enter_as_the_estimator_defines_them() -> None:
    """F_unb = w^2 z (c - i t), z = m r exp(-i beta) (estimator.equations); order h turned by exp(i h d)."""
    bench = load_bench(DEFAULT_BENCH)
    base = _doc_of_bench(bench)
    unb = {
        "mr_kgm": {"value": 5e-4},
        "angle_deg": {"value": 40.0},
        "point_m": bench.engine.reference_point_m,
    }
    with_unb = _doc_of_bench(bench, unbalance=unb, crank_offset_deg={"value": 0.7})
    m0 = resim_model(bench, estimated_properties(base, bench))
    props = estimated_properties(with_unb, bench)
    m1 = resim_model(bench, props)
    rpm = 3000.0
    w = rpm * math.pi / 30
    f0, _ = m0.engine.excitation(rpm, [1.0], about=m0.body.cog)
    f1, _ = m1.engine.excitation(rpm, [1.0], about=m1.body.cog)
    _, c, t = m1.engine.frame
    z = 5e-4 * np.exp(-1j * math.radians(40.0))
    np.testing.assert_allclose(f1[0] - f0[0], w**2 * z * (c - 1j * t), atol=1e-9)
    assert props.mass == bench.powertrain.mass_kg and props.mass_source.startswith("bench")
    d = math.radians(0.7)
    ratio = predict(m1, [rpm], ORDERS, props.crank_offset_rad) / m1.channel_amplitudes(
        [rpm], ORDERS
    )
    np.testing.assert_allclose(
        ratio[0], np.exp(1j * np.array(ORDERS) * d)[:, None] * np.ones((1, 9))
    )


def test_realistic_sweep_passes_and_a_wrong_estimate_fails(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    log, doc_path = realistic_log(tmp_path_factory)
    data = load(log)
    assert data.frames is not None and data.gating is not None and data.bench is not None
    f = data.frames

    def check(doc):
        return resim_check(
            data.bench,
            doc,
            f.rpm,
            f.orders,
            f.channels,
            f.amplitudes,
            f.ambiguous,
            data.gating.used,
        )

    doc = json.loads(doc_path.read_text(encoding="utf-8"))
    good = check(doc)
    assert good.passed is True, good.summary()
    assert good.worst_db < 0.5 and good.worst_deg < 5.0
    # the verdict rests on the strong axes of every order, not on a handful of channels
    assert np.all(good.assessable.sum(axis=1) >= 4)
    assert np.all(good.assessable[good.level_db > -3.0])
    # a 10 % error in one term is seen
    wrong = copy.deepcopy(doc)
    wrong["inertia_kgm2"]["value"]["Ixx"] *= 1.10
    assert check(wrong).passed is False
    # and so is a 1 cm error of the cog
    shifted = copy.deepcopy(doc)
    shifted["cog_m"]["value"][2] += 0.01
    assert check(shifted).worst_db > good.worst_db
