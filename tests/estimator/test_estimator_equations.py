"""The streaming estimator inverts an independently solved forward model.

``estimator_harness`` solves the 6-DOF harmonic response directly (rigid body,
complex mount stiffness, gyroscopic spin, residual unbalance); the estimator
must give the body back. Exact data leave only round-off (or, with an
unbalance, the documented linearisation of the G x F_unb term).
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np
import pytest
from support.estimator_harness import Body, Frame, frames, make_setup

from estimator.elastic_tail import with_tail
from estimator.hypotheses import add_frame
from estimator.setup import Corrections
from estimator.streaming import InertiaEstimator

RPMS = np.linspace(1500, 4500, 60)


def _run(body: Body, rpms=RPMS, frame_map=lambda f: f, **setup_kw) -> InertiaEstimator:
    with_mounts = setup_kw.pop("with_mounts", True)
    est = InertiaEstimator(make_setup(body, **setup_kw))
    for f in frames(body, rpms, with_mounts=with_mounts):
        est.update(frame_map(f))
    return est


def _rel_inertia_error(est: InertiaEstimator, body: Body) -> float:
    e = est.estimate()
    return float(np.max(np.abs(e.inertia - body.inertia)) / np.max(np.abs(body.inertia)))


@pytest.mark.parametrize("mass_known", [True, False])
def test_exact_data_give_the_body_back_to_round_off(mass_known: bool) -> None:
    body = Body()
    est = _run(body, mass_known=mass_known)
    e = est.estimate()
    assert e.frames_used == len(RPMS)
    np.testing.assert_allclose(e.inertia, body.inertia, rtol=0, atol=1e-9)
    np.testing.assert_allclose(e.cog, body.cog, rtol=0, atol=1e-10)
    if mass_known:
        assert e.mass() is None
    else:
        m = e.mass()
        assert m is not None and m[0] == pytest.approx(body.mass, rel=1e-9)


def test_residual_unbalance_estimated_jointly() -> None:
    z = 5e-4 * np.exp(-1j * np.radians(40.0))  # m r = 5e-4 kg m at beta = 40 deg
    body = Body(unbalance=z)
    est = _run(body)
    unb = est.estimate().unbalance()
    assert unb is not None
    assert unb["mr_kgm"]["value"] == pytest.approx(5e-4, rel=1e-3)
    assert unb["angle_deg"]["value"] == pytest.approx(40.0, abs=0.1)
    # G x F_unb is linearised about the running cog estimate: a tiny, bounded error
    assert _rel_inertia_error(est, body) < 1e-4


def test_unmodelled_unbalance_biases_the_paper_method() -> None:
    body = Body(unbalance=5e-4 * np.exp(-1j * np.radians(40.0)))
    off = _run(body, corrections=Corrections(unbalance=False))
    on = _run(body)
    assert _rel_inertia_error(off, body) > 10 * _rel_inertia_error(on, body)


def test_suspension_correction_removes_the_mount_bias() -> None:
    body = Body()
    plain = _run(body, corrections=Corrections(suspension=False))
    corrected = _run(body)
    assert _rel_inertia_error(plain, body) > 0.01  # the paper's bias, falling as 1/rpm^2
    assert _rel_inertia_error(corrected, body) < 1e-9


def test_gyroscopic_correction_matters_and_is_exact() -> None:
    body = Body(spin=0.3)
    plain = _run(body, corrections=Corrections(gyroscopic=False))
    assert _rel_inertia_error(plain, body) > 1e-3
    assert _rel_inertia_error(_run(body), body) < 1e-9


def test_free_body_needs_no_suspension_term() -> None:
    body = Body()
    est = _run(body, with_mounts=False, corrections=Corrections(suspension=False))
    assert _rel_inertia_error(est, body) < 1e-9


def test_half_order_sign_ambiguity_is_resolved_by_the_residual() -> None:
    body = Body()

    def lose_cycle(f: Frame) -> Frame:
        amps = f.amplitudes.copy()
        amps[1] *= -1  # H1.5 seen through phi + 360 deg
        return dataclasses.replace(f, amplitudes=amps, flags=frozenset({"cycle_ambiguous"}))

    est = _run(body, frame_map=lose_cycle)
    e = est.estimate()
    assert e.half_order is not None
    assert e.half_order["half_order_sign"] == -1
    assert e.half_order["residual_ratio"] > 1e6
    np.testing.assert_allclose(e.inertia, body.inertia, atol=1e-9)


def test_crank_reference_offset_is_detected() -> None:
    body = Body()
    d = np.radians(0.5)

    def late_reference(f: Frame) -> Frame:
        h = np.asarray(f.orders)[:, None]
        return dataclasses.replace(f, amplitudes=f.amplitudes * np.exp(1j * h * d))

    e = _run(body, frame_map=late_reference).estimate()
    assert np.degrees(e.value("crank_offset")) == pytest.approx(0.5, abs=0.01)


def test_unsteady_and_non_rigid_frames_are_rejected_with_reasons() -> None:
    body = Body()

    def spoil(f: Frame) -> Frame:
        if f.time_s % 3 == 0:
            return dataclasses.replace(f, rpm_change=0.2)
        if f.time_s % 3 == 1:
            amps = f.amplitudes.copy()
            amps[:, 4] *= 1.5  # one axis off the rigid body in every order
            return dataclasses.replace(f, amplitudes=amps)
        return f

    est = _run(body, frame_map=spoil)
    e = est.estimate()
    assert e.frames_rejected == {"rpm_unsteady": 20, "non_rigid": 20}
    assert e.frames_used == 20
    np.testing.assert_allclose(e.inertia, body.inertia, atol=1e-9)


def test_dead_channel_is_dropped_and_the_rest_still_estimate() -> None:
    body = Body()

    def dead(f: Frame) -> Frame:
        ok = f.channel_ok.copy()
        ok[2] = False
        amps = f.amplitudes.copy()
        amps[:, 2] = np.nan
        return dataclasses.replace(f, channel_ok=ok, amplitudes=amps)

    est = _run(body, frame_map=dead)
    np.testing.assert_allclose(est.estimate().inertia, body.inertia, atol=1e-9)


def test_intervals_cover_the_truth_under_sensor_gain_errors() -> None:
    body = Body()
    covered = 0
    for seed in range(20):
        rng = np.random.default_rng(seed)
        gains = 1 + 0.01 * rng.normal(size=9)

        def miscalibrated(f: Frame, gains=gains) -> Frame:
            return dataclasses.replace(f, amplitudes=f.amplitudes * gains)

        e = _run(body, rpms=np.linspace(1500, 4500, 30), frame_map=miscalibrated).estimate()
        inside = [
            abs(e.value(n) - t) <= 1.96 * e.std(n)
            for n, t in zip(
                ("Ixx", "Iyy", "Izz", "Ixy", "Ixz", "Iyz"),
                (4.6, 3.1, 4.2, 0.28, -0.42, 0.21),
                strict=True,
            )
        ]
        covered += int(all(inside))
    assert covered >= 16  # simultaneous coverage of six 95 % intervals: expect ~ 0.95^6 or better


def test_publishing_estimates_midway_changes_no_bit_of_the_result() -> None:
    # Live runs publish after every frame, replays every 0.5 s: the frames' rows are
    # assembled in batches, and flushing a batch early must not change any sum.
    body = Body(unbalance=5e-4 * np.exp(-1j * np.radians(40.0)))
    fr = [
        dataclasses.replace(f, flags=frozenset({"cycle_ambiguous"}))
        for f in frames(body, np.linspace(1500, 4500, 70))
    ]
    quiet = InertiaEstimator(make_setup(body))
    chatty = InertiaEstimator(make_setup(body))
    rng = np.random.default_rng(5)
    for f in fr:
        quiet.update(f)
        chatty.update(f)
        if rng.random() < 0.4:
            chatty.estimate()
    a, b = quiet.estimate(), chatty.estimate()
    assert np.array_equal(a.theta, b.theta)
    assert np.array_equal(a.cov, b.cov)


def test_a_block_of_frames_gives_the_same_bits_as_one_frame_at_a_time() -> None:
    # The pipeline hands the estimator a block's frames together: the shared
    # arithmetic must not change any decision or any bit of the result.
    body = Body(unbalance=5e-4 * np.exp(-1j * np.radians(40.0)))
    fr = list(frames(body, np.linspace(1500, 4500, 70)))
    single = InertiaEstimator(make_setup(body))
    outcomes = [single.update(f) for f in fr]
    block = InertiaEstimator(make_setup(body))
    together = [o for i in range(0, len(fr), 9) for o in block.update_many(fr[i : i + 9])]
    assert [o.used_orders for o in together] == [o.used_orders for o in outcomes]
    a, b = single.estimate(), block.estimate()
    assert np.array_equal(a.theta, b.theta)
    assert np.array_equal(a.cov, b.cov)


@pytest.mark.parametrize("self_calibration", [False, True])
def test_the_per_frame_update_agrees_with_its_pure_function_twin(self_calibration: bool) -> None:
    """The estimator adds each queued frame's rows to its state as ``add_frame`` does."""
    body = Body()
    corrections = Corrections(self_calibration=self_calibration)
    est = InertiaEstimator(make_setup(body, corrections=corrections))
    for f in frames(body, RPMS[:6]):
        est.update(f)
    # the first used frame was flushed for the first relinearisation; the others wait
    pending = list(est.queue.frames)
    assert len(pending) == 5
    sign = np.ones(sum(len(p.orders) for p in pending))
    dm = est.rows.sensitivity(pending)
    H, y, dr = est.rows.rows(pending, sign, sign.astype(bool), dm, est.lin)
    H = with_tail(H, np.concatenate([p.orders * p.rpm / 60.0 for p in pending]))
    kin = est.rows.redundancy(pending) if self_calibration else None
    expected = est.acc[1]
    bounds = np.cumsum([0] + [len(p.orders) for p in pending])
    for f, (a, b) in enumerate(itertools.pairwise(bounds)):
        own = None if kin is None else (kin[0][f], kin[1][f], kin[2][f])
        expected = add_frame(expected, H[a:b], y[a:b], dr[a:b], est.forgetting, own)
    est.best_state()  # assembles the queued frames' rows and adds them
    got = est.acc[1]
    # Each sum against its natural scale (the compiled rows, PTINERTIA_NUMBA=1, sum in
    # another order; the numpy path is exact): an information entry against
    # sqrt(info_ii info_jj) and a vector entry against sqrt(info_ii yty), their
    # Cauchy-Schwarz bounds, a sensitivity against its row's and column's largest
    # (entries of 1e-17 of the scale, cancellations, differ by 60 % of themselves).
    diag, yty = np.diag(expected.state.info), expected.state.yty
    scale = {"info": np.sqrt(np.outer(diag, diag)), "vec": np.sqrt(diag * yty)}
    for name in ("info", "vec"):
        diff = np.abs(getattr(got.state, name) - getattr(expected.state, name))
        assert np.all(diff <= 1e-12 * scale[name]), name
    size = np.abs(expected.sens)
    sens_scale = np.sqrt(np.outer(size.max(axis=1), size.max(axis=0)))
    assert np.all(np.abs(got.sens - expected.sens) <= 1e-12 * sens_scale)
    assert got.state.yty == pytest.approx(expected.state.yty, rel=1e-12)
    assert got.state.rows == expected.state.rows
