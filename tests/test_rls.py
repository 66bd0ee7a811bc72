"""Recursive least squares: equals batch WLS, pure twin equals the class, forgetting, rank."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.rls import RecursiveLeastSquares, batch_wls, rls_init, rls_solve, rls_update


def _problem(seed: int = 0, frames: int = 40, rows: int = 9, n: int = 12):
    rng = np.random.default_rng(seed)
    scale = 10.0 ** rng.uniform(-4, 1, n)  # parameters of very different units
    theta = rng.normal(size=n) * scale
    hs = [rng.normal(size=(rows, n)) / scale for _ in range(frames)]
    ws = [rng.uniform(0.5, 4.0, rows) for _ in range(frames)]
    ys = [
        h @ theta + rng.normal(size=rows) / np.sqrt(w) * 1e-3 for h, w in zip(hs, ws, strict=True)
    ]
    return theta, scale, hs, ys, ws


def test_rls_with_unit_forgetting_equals_batch_wls() -> None:
    _, scale, hs, ys, ws = _problem()
    rls = RecursiveLeastSquares(hs[0].shape[1], lam=1.0, scale=scale)
    for h, y, w in zip(hs, ys, ws, strict=True):
        rls.update(h, y, w)
    batch = batch_wls(np.vstack(hs), np.concatenate(ys), np.concatenate(ws))
    np.testing.assert_allclose(rls.solution.theta, batch, rtol=1e-9, atol=0)


def test_batch_covariance_is_inverse_normal_matrix() -> None:
    _, scale, hs, ys, ws = _problem(seed=1)
    rls = RecursiveLeastSquares(hs[0].shape[1], scale=scale)
    for h, y, w in zip(hs, ys, ws, strict=True):
        rls.update(h, y, w)
    H, W = np.vstack(hs), np.concatenate(ws)
    np.testing.assert_allclose(rls.solution.cov, np.linalg.inv(H.T @ (H * W[:, None])), rtol=1e-8)


def test_pure_function_twin_equals_class_to_1e12() -> None:
    _, scale, hs, ys, ws = _problem(seed=2)
    rls = RecursiveLeastSquares(hs[0].shape[1], lam=0.97, scale=scale)
    state = rls_init(hs[0].shape[1])
    for h, y, w in zip(hs, ys, ws, strict=True):
        rls.update(h, y, w)
        state = rls_update(state, h, y, w, lam=0.97)
        np.testing.assert_allclose(rls.state.info, state.info, rtol=1e-12, atol=0)
    np.testing.assert_allclose(
        rls.solution.theta, rls_solve(state, scale=scale).theta, rtol=1e-12, atol=0
    )


def test_forgetting_tracks_a_parameter_change() -> None:
    rng = np.random.default_rng(3)
    rls = RecursiveLeastSquares(2, lam=0.8)
    for k in range(200):
        truth = np.array([1.0, 2.0]) if k < 100 else np.array([3.0, -1.0])
        h = rng.normal(size=(3, 2))
        rls.update(h, h @ truth)
    np.testing.assert_allclose(rls.solution.theta, [3.0, -1.0], atol=1e-9)


def test_unexcited_parameter_is_reported_unobservable() -> None:
    rng = np.random.default_rng(4)
    rls = RecursiveLeastSquares(3)
    for _ in range(10):
        h = rng.normal(size=(4, 3))
        h[:, 2] = 0.0  # nothing ever excites parameter 2
        rls.update(h, h @ np.array([1.0, -2.0, 5.0]))
    sol = rls.solution
    assert list(sol.observable) == [True, True, False]
    np.testing.assert_allclose(sol.theta[:2], [1.0, -2.0], rtol=1e-10)
    assert np.isinf(sol.cov[2, 2])


def test_residual_sum_of_squares_matches_batch() -> None:
    _, scale, hs, ys, ws = _problem(seed=5)
    rls = RecursiveLeastSquares(hs[0].shape[1], scale=scale)
    for h, y, w in zip(hs, ys, ws, strict=True):
        rls.update(h, y, w)
    H, y, W = np.vstack(hs), np.concatenate(ys), np.concatenate(ws)
    r = y - H @ batch_wls(H, y, W)
    assert rls.solution.rss == pytest.approx(float(np.sum(W * r * r)), rel=1e-6)


def test_bad_forgetting_factor_refused() -> None:
    with pytest.raises(ValueError, match="forgetting factor"):
        RecursiveLeastSquares(2, lam=1.5)
