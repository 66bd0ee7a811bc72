"""The compiled arithmetic of a fitted run (estimator/compiled_runs.py) against the numpy
reference (RigidFit.fit_arrays and fit_run's power, the curvature gate's arithmetic, the
noise levels, the excess residuals, the order screen, the channel noise's medians and
windows). The readings are copies and the channel noise the same operations: equal. The
fits agree within rounding (1e-13 relative to each array's largest entry: the loop sums
in another order than BLAS), the rest within 1e-13 relative (the same decisions), and
whole runs of the estimator within 1e-12 relative, one frame at a time and in blocks bit
for bit. The loops are checked run by the interpreter (no numba needed) and compiled."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from support.estimator_harness import Body, frames, make_setup

from estimator import compiled_noise, compiled_runs, row_kernels
from estimator.channel_noise import ChannelNoise
from estimator.compiled_runs import bend_excess, fitted_arrays
from estimator.gating import BEND_NOISE, OrderGates
from estimator.kinematics import RigidFit
from estimator.rigidity import excess_many, noise_levels_many
from estimator.setup import Corrections
from estimator.streaming import InertiaEstimator

NUMBA = pytest.mark.skipif(not row_kernels.AVAILABLE, reason="numba not installed")
POSITIONS = np.array([[0.2, 0.1, 0.0], [-0.2, 0.15, 0.05], [0.0, -0.2, 0.2], [0.1, 0.3, -0.1]])


def _fit(sensors: int, weighted: bool) -> tuple[RigidFit, np.ndarray]:
    """A fit of ``sensors`` triaxial sensors (two: one rotation unseen) on some of a
    frame's 14 columns (in scrambled order), and those columns."""
    pos = np.repeat(POSITIONS[:sensors], 3, axis=0)
    dirs = np.tile(np.eye(3), (sensors, 1))
    rng = np.random.default_rng(sensors)
    weights = rng.uniform(0.3, 3.0, len(pos)) if weighted else None
    fit = RigidFit.of(pos, dirs, weights, allow_null=True)
    return fit, rng.permutation(14)[: len(pos)]


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
@pytest.mark.parametrize(("sensors", "weighted"), [(3, False), (3, True), (4, True), (2, True)])
def test_the_compiled_fit_of_a_run_is_the_numpy_fit(
    compiled: bool, sensors: int, weighted: bool
) -> None:
    fit, columns = _fit(sensors, weighted)
    assert (fit.null is None) == (sensors > 2)
    rng = np.random.default_rng(7)
    amplitudes = rng.normal(size=(5, 3, 14)) + 1j * rng.normal(size=(5, 3, 14))
    amplitudes[2, 1] = 0.0  # no signal at all: relative residual 0
    readings, x, rms, relative, noise_var, power = fitted_arrays(
        fit, amplitudes, columns, compiled=compiled
    )
    reference = amplitudes[:, :, columns]
    assert np.array_equal(readings, reference)
    want = fit.fit_arrays(reference)
    want_power = np.add.reduce(abs(reference) ** 2, axis=2) / len(columns)
    for got, ref in zip((x, rms, relative, noise_var, power), (*want, want_power), strict=True):
        assert got.shape == ref.shape
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13 * np.max(np.abs(ref)))
    assert relative[2, 1] == 0.0 and np.all(relative[:2] > 0)


def _estimate(monkeypatch: pytest.MonkeyPatch, compiled: bool, block: int) -> Any:
    monkeypatch.setattr(row_kernels, "USE", compiled)
    body = Body()
    est = InertiaEstimator(make_setup(body))
    rng = np.random.default_rng(2)
    data = [
        dataclasses.replace(f, amplitudes=f.amplitudes * (1 + 0.01 * rng.normal(size=(3, 9))))
        for f in frames(body, np.linspace(1200.0, 5200.0, 80))
    ]
    outcomes = [o for at in range(0, 80, block) for o in est.update_many(data[at : at + block])]
    return est.estimate(), outcomes


@NUMBA
def test_the_compiled_runs_give_the_numpy_estimate(monkeypatch: pytest.MonkeyPatch) -> None:
    ref, ref_outcomes = _estimate(monkeypatch, False, 20)
    got, outcomes = _estimate(monkeypatch, True, 20)
    assert got.frames_used == ref.frames_used > 40
    assert [o.reason for o in outcomes] == [o.reason for o in ref_outcomes]
    sd, sd_ref = np.sqrt(np.diag(got.cov)), np.sqrt(np.diag(ref.cov))
    assert np.all(np.abs(got.theta - ref.theta) <= 1e-12 * np.maximum(np.abs(ref.theta), sd_ref))
    assert np.all(np.abs(sd - sd_ref) <= 1e-12 * sd_ref)
    # one frame at a time (live) and in blocks (replay) give the same bits
    single, _ = _estimate(monkeypatch, True, 1)
    assert np.array_equal(single.theta, got.theta) and np.array_equal(single.cov, got.cov)


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
def test_the_compiled_curvature_is_the_numpy_one(compiled: bool) -> None:
    fit, _ = _fit(3, True)
    rng = np.random.default_rng(3)
    seq_w = rng.normal(size=(8, 3, 3)) + 1j * rng.normal(size=(8, 3, 3))
    seq_w[:2, 1] = np.nan  # no motion before: not finite
    seq_w[4:, 2] = seq_w[3, 2] * np.arange(1, 5)[:, None]  # straight: within the noise
    seq_w[5, 0] = 0.0  # no motion at all
    chained = np.array([True, True, True, False, True, True])
    noise = rng.uniform(0.0, 0.02, (6, 3))
    noise[2, 0] = 0.0  # a noise-free fit: all its bend is excess
    want = OrderGates._bend_excess(seq_w, chained, noise, [], fit)
    got = bend_excess(seq_w, chained, noise, fit.omega_trace, BEND_NOISE, compiled=compiled)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=0)
    # not chained, no motion before, straight: nothing; a motion gone: a bend
    assert np.all(got[3] == 0) and np.all(got[:2, 1] == 0) and np.all(got[4:, 2] == 0)
    w = seq_w[4, 0]
    bend = np.linalg.norm(w - 2 * seq_w[3, 0] + seq_w[2, 0]) / np.linalg.norm(w)
    assert got[2, 0] == pytest.approx(bend, rel=1e-14) and np.count_nonzero(got) > 6


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
def test_the_compiled_noise_levels_are_the_numpy_ones(
    monkeypatch: pytest.MonkeyPatch, compiled: bool
) -> None:
    # unknown noise (None, a NaN channel), nil noise, measured noise, shared by frames
    fit, _ = _fit(3, True)
    fit = fit.on_channels(np.arange(9))
    rng = np.random.default_rng(8)
    amps = rng.normal(size=(7, 3, 9)) + 1j * rng.normal(size=(7, 3, 9))
    measured = rng.uniform(0.1, 2.0, 9)
    missing = measured.copy()
    missing[4] = np.nan
    variances: list[np.ndarray | None] = [None, measured, measured, np.zeros(9), missing]
    variances += [0.01 * measured, None]
    _, _, relative, noise_var = fit.fit_arrays(amps)
    unknown = [True, False, False, False, True, False, True]
    own: list[np.ndarray | None] = [rng.uniform(0.1, 2.0, 9) for _ in range(7)]
    for each in (variances, own):
        monkeypatch.setattr(row_kernels, "USE", False)
        want = noise_levels_many(fit, each)
        want_excess = excess_many(relative, noise_var, fit, *want)
        monkeypatch.setattr(row_kernels, "USE", True)
        if not compiled:
            monkeypatch.setattr(compiled_noise, "jit", lambda fn: fn)
        got = noise_levels_many(fit, each)
        got_excess = excess_many(relative, noise_var, fit, *got)
        for a, b in zip((*got, *got_excess), (*want, *want_excess), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-13, atol=0)
        assert np.isnan(got[0]).tolist() == unknown
        assert np.all(got_excess[1] <= got_excess[0]) and np.any(got_excess[1] < relative)
        if each is variances:
            assert got[0][3] == got[1][3] == 0  # (nil noise)
        unknown = [False] * 7


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
@pytest.mark.parametrize(("mode_hz", "unbalance_location"), [(None, False), (30.0, True)])
def test_the_compiled_order_screen_is_the_numpy_one(
    monkeypatch: pytest.MonkeyPatch, compiled: bool, mode_hz: float | None, unbalance_location: bool
) -> None:
    # every reason: not excited (a nil order, a NaN level's frame), near the modes, off
    # the mass line, leakage from a bending neighbour; order 1 unloaded but responding
    corrections = Corrections(unbalance_location=unbalance_location)
    setup = dataclasses.replace(make_setup(Body(), corrections=corrections), mode_max_hz=mode_hz)
    gates = OrderGates(setup)
    fit, _ = _fit(3, True)
    rng = np.random.default_rng(11)
    n, orders = 40, np.array([0.5, 1.0, 1.5, 2.0])
    rpm = rng.uniform(800.0, 6000.0, n)
    force = rng.normal(size=(n, 4, 3)) + 1j * rng.normal(size=(n, 4, 3))
    moment = rng.normal(size=(n, 4, 3)) + 1j * rng.normal(size=(n, 4, 3))
    force[:, 1], moment[:, 1] = 0.0, 0.0  # order 1: no known load
    force[5, 2, 0] = np.nan
    curvature = rng.uniform(0.0, 0.01, (n, 4))
    power = rng.uniform(0.1, 2.0, (n, 4))
    relative = rng.uniform(0.0, 0.5, (n, 4))
    rpm[7], curvature[7] = 3000.0, [0.002, 0.002, 0.2, 0.002]  # H1.5 bends: H2 leaks
    args = (rpm, orders, force, moment, curvature, power, relative, fit)
    monkeypatch.setattr(row_kernels, "USE", False)
    why, floor = gates.screen_orders(*args)
    monkeypatch.setattr(row_kernels, "USE", True)
    if not compiled:
        monkeypatch.setattr(compiled_runs, "jit", lambda fn: fn)
    got_why, got_floor = gates.screen_orders(*args)
    assert np.array_equal(got_why, why)
    np.testing.assert_allclose(got_floor, floor, rtol=1e-13, atol=0)
    assert set(why.ravel().tolist()) == ({0, 1, 2, 3, 4} if mode_hz else {0, 1, 3, 4})
    assert np.all(why[5, [0, 2, 3]] == 1) and np.any(why[:, 1] != 1) == unbalance_location
    assert why[7, 2] == 3 and why[7, 3] == 4


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
@pytest.mark.parametrize("k", [3, 4])
def test_the_compiled_channel_noise_is_the_numpy_one_bit_for_bit(
    monkeypatch: pytest.MonkeyPatch, compiled: bool, k: int
) -> None:
    # a sweep of frames 720 deg apart (revolutions 0, 2, 4, ...), a channel lost for a
    # while (NaN) and another with no noise at all; in blocks of 5, numpy against loops
    rng = np.random.default_rng(k)
    n = 30
    amps = rng.normal(size=(n, k, 9)) + 1j * rng.normal(size=(n, k, 9))
    amps *= rng.uniform(0.1, 3.0, 9)
    amps[12:15, :, 2] = np.nan
    amps[:, :, 5] = 1.0 + 2.0j
    amps[7, 1, 4] = np.nan  # one order of one frame
    orders = tuple(np.arange(1, k + 1) / 2.0)
    frames = [(2 * j, orders, amps[j]) for j in range(n)]

    def variances(use: bool) -> list[Any]:
        monkeypatch.setattr(row_kernels, "USE", use)
        noise = ChannelNoise(9)
        after = [v for at in range(0, n, 5) for v, _ in noise.add_many(frames[at : at + 5])]
        noise.release(noise.estimates)
        return [*after, noise.weights()]

    want = variances(False)
    if not compiled:
        monkeypatch.setattr(compiled_noise, "jit", lambda fn: fn)
    got = variances(True)
    assert len(got) == len(want) and sum(v is not None for v in want) > 15
    for a, b in zip(got, want, strict=True):
        assert (a is None and b is None) or np.array_equal(a, b, equal_nan=True)
    last = want[-2]
    assert not np.isnan(last[2]) and last[5] == 0.0
    assert any(v is not None and np.isnan(v[2]) for v in want)
