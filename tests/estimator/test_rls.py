"""Recursive least squares: equals batch WLS, pure twin equals the class, forgetting, rank."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.rls import (
    RecursiveLeastSquares,
    RlsState,
    batch_wls,
    rls_init,
    rls_solve,
    rls_update,
)


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


def _clean_data_and_a_weak_prior() -> tuple[RlsState, np.ndarray, np.ndarray]:
    """Three parameters measured to 1e-5 and a fourth known only from a prior of
    std 0.1 that the rows couple to the others: the sensor-calibration situation of
    a clean (60 dB) sweep. Returns the state, the rows and the prior as one stacked
    whitened system (for an independent solve), and the truth."""
    rng = np.random.default_rng(7)
    H = rng.normal(size=(200, 4))
    H[:, 3] = H[:, 0] + H[:, 1]  # the rows see the fourth only together with the first two
    w = np.full(200, 1e10)
    theta = np.array([1.0, -2.0, 0.5, 0.03])
    y = H @ theta + rng.normal(size=200) / np.sqrt(w)
    state = rls_update(rls_init(4), H, y, w)
    prior = np.zeros((4, 4))
    prior[3, 3] = 1.0 / 0.1**2
    stacked = np.vstack(
        [np.column_stack([H * np.sqrt(w)[:, None], y * np.sqrt(w)]), [0, 0, 0, 10.0, 0]]
    )
    return (
        RlsState(info=state.info + prior, vec=state.vec, yty=state.yty, rows=state.rows),
        stacked,
        theta,
    )


def test_a_prior_held_parameter_is_never_thrown_away_with_its_partners() -> None:
    state, stacked, theta = _clean_data_and_a_weak_prior()
    # The joint matrix spans 1e11: a relative rank threshold drops the prior's
    # direction and with it the parameters it couples to (what a clean sensor with
    # self-calibration used to give: a cog 85 mm off, marked unobservable).
    assert not np.all(rls_solve(state).observable)
    sol = rls_solve(state, anchored=(3,))
    assert np.all(sol.observable)
    # Second method: QR least squares on the stacked rows and prior (condition
    # number the square root of the information matrix's 1e11, which leaves the
    # information form about five digits in the prior-held direction).
    a, b = stacked[:, :4], stacked[:, 4]
    exact, *_ = np.linalg.lstsq(a, b, rcond=None)
    r_inv = np.linalg.inv(np.linalg.qr(a, mode="r"))
    cov = r_inv @ r_inv.T
    std = np.sqrt(np.diag(cov))
    assert np.all(np.abs(sol.theta - exact) < 1e-3 * std), (sol.theta - exact) / std
    np.testing.assert_allclose(np.sqrt(np.diag(sol.cov)), std, rtol=1e-3)
    # and the answer is the truth within its interval
    assert np.all(np.abs(sol.theta - theta) < 4 * np.sqrt(np.diag(sol.cov)))


def test_a_free_parameter_no_row_excites_stays_unobservable_beside_an_anchor() -> None:
    state, _, _ = _clean_data_and_a_weak_prior()
    n = 5  # a fifth parameter that no row touches
    info = np.zeros((n, n))
    info[:4, :4] = state.info
    vec = np.concatenate([state.vec, [0.0]])
    padded = RlsState(info=info, vec=vec, yty=state.yty, rows=state.rows)
    sol = rls_solve(padded, anchored=(3,))
    assert sol.observable.tolist() == [True, True, True, True, False]
    assert np.isinf(sol.cov[4, 4])
    np.testing.assert_allclose(sol.theta[:4], rls_solve(state, anchored=(3,)).theta, rtol=1e-12)
