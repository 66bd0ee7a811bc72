"""The compiled arithmetic of a fitted run (estimator/compiled_runs.py) against the numpy
reference (RigidFit.fit_arrays and fit_run's power): the readings are copies (equal), the
fits agree within rounding (1e-13 relative to each array's largest entry: the loop sums
in another order than BLAS), and so do whole runs of the estimator (1e-12 relative),
one frame at a time and in blocks bit for bit. The loop is checked run by the
interpreter (no numba needed) and compiled."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from support.estimator_harness import Body, frames, make_setup

from estimator import row_kernels
from estimator.compiled_runs import fitted_arrays
from estimator.kinematics import RigidFit
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
