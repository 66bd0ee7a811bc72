"""An order with no known load, driven by the estimated unbalance alone, is used.

A balanced inline 4 has no known order-1 load; its residual unbalance drives an
order-1 response all the same. With the unbalance located (its couple free), that order is used
where the rigid motion (not noise) explains its readings and it is well above the
rigid-body modes; otherwise it stays out as ``no_excitation``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.estimator_harness import Body, channel_geometry, excitation, frames, make_setup

from estimator.kinematics import RigidFit
from estimator.order_evidence import UNLOADED_MODE_RATIO, responds
from estimator.outcome import FrameOutcome
from estimator.setup import Corrections
from estimator.streaming import InertiaEstimator

RPMS = np.linspace(1500, 4500, 60)
LOCATED = Corrections(unbalance_location=True)
Z = 5e-4 * np.exp(-1j * np.radians(40.0))


def balanced(rpm: float, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The harness's loads with nothing known at order 1."""
    force, moment = excitation(rpm, orders)
    first = np.asarray(orders) == 1.0
    force[first], moment[first] = 0.0, 0.0
    return force, moment


def _run(body: Body, **kw: object) -> tuple[InertiaEstimator, list[FrameOutcome]]:
    est = InertiaEstimator(make_setup(body, excitation_fn=balanced, **kw))
    outcomes = [est.update(f) for f in frames(body, RPMS, excitation_fn=balanced)]
    return est, outcomes


def test_the_unbalance_alone_drives_a_used_order_one() -> None:
    body = Body(unbalance=Z)
    est, outcomes = _run(body, corrections=LOCATED)
    assert all(1.0 in o.used_orders for o in outcomes)
    e = est.estimate()
    unb = e.unbalance()
    assert unb is not None  # observable: order 1 is in
    assert unb["mr_kgm"]["value"] == pytest.approx(abs(Z), rel=1e-8)
    assert unb["angle_deg"]["value"] == pytest.approx(40.0, abs=1e-6)
    np.testing.assert_allclose(e.inertia, body.inertia, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    "corrections", [Corrections(unbalance=False), Corrections(unbalance_location=False)]
)
def test_without_the_located_unbalance_order_one_stays_out(corrections: Corrections) -> None:
    est, outcomes = _run(Body(unbalance=Z), corrections=corrections)
    assert not any(1.0 in o.used_orders for o in outcomes)
    assert est.stats.orders_rejected["no_excitation"] == len(RPMS)


def test_order_one_with_no_known_load_is_used_only_well_above_the_modes() -> None:
    mode_hz = 20.0  # order 1 of 1500-4500 rpm is 25-75 Hz
    setup = dataclasses.replace(
        make_setup(Body(unbalance=Z), excitation_fn=balanced, corrections=LOCATED),
        mode_max_hz=mode_hz,
    )
    est = InertiaEstimator(setup)
    body = Body(unbalance=Z)
    for f in frames(body, RPMS, excitation_fn=balanced):
        o = est.update(f)
        above = f.rpm / 60.0 >= UNLOADED_MODE_RATIO * mode_hz
        if o.reason is None:
            assert (1.0 in o.used_orders) == above, f.rpm
    assert est.stats.orders_rejected["no_excitation"] > 0


def test_noise_alone_does_not_pass_for_a_response() -> None:
    rng = np.random.default_rng(5)
    pos, dirs, _ = channel_geometry()
    fit = RigidFit.of(pos, dirs)
    n = 2000
    noise = rng.normal(size=(n, 1, 9)) + 1j * rng.normal(size=(n, 1, 9))
    passed = [
        bool(responds(m.relative_residual, np.mean(np.abs(r) ** 2, axis=1), fit)[0])
        for m, r in zip(fit.fit_many(noise), noise, strict=True)
    ]
    assert sum(passed) <= 0.004 * n  # the test's level is 1e-3
    # a rigid motion 20 dB above that noise passes in every frame
    motion = rng.normal(size=(n, 1, 6)) + 1j * rng.normal(size=(n, 1, 6))
    jac = np.hstack([dirs, np.cross(pos - fit.origin, dirs)])
    readings = motion @ jac.T
    scale = np.sqrt(np.mean(np.abs(readings) ** 2, axis=2, keepdims=True))
    readings = readings / scale * 10 * np.sqrt(2) + noise
    assert all(
        responds(m.relative_residual, np.mean(np.abs(r) ** 2, axis=1), fit)[0]
        for m, r in zip(fit.fit_many(readings), readings, strict=True)
    )
