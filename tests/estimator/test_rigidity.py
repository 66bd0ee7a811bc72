"""The rigidity gate judged against the measured channel noise (estimator/rigidity.py).

References: Monte Carlo draws of Gaussian channel noise through the same rigid
fit (the chi-square quantile), the order statistics of exponential variables
(the median's bias), the noise put into a sweep (the measured level), and
end to end a rigid body with noise alone (no elastic mode may be confirmed).
"""

from __future__ import annotations

import numpy as np
import pytest
from support.estimator_runs import I3, run

from estimator import row_kernels
from estimator.channel_noise import RECENT, ChannelNoise, median_bias
from estimator.kinematics import RigidFit
from estimator.rigidity import (
    NOISE_QUANTILE,
    excess_many,
    excess_residual,
    noise_levels_many,
    noise_quantile,
)

ORDERS = (1.0, 1.5, 2.0, 3.0, 4.5)


def _geometry() -> tuple[np.ndarray, np.ndarray]:
    """Three triaxial sensors (9 channels)."""
    pos = np.repeat(np.array([[0.2, 0.1, 0.0], [-0.2, 0.15, 0.05], [0.0, -0.2, 0.2]]), 3, axis=0)
    dirs = np.tile(np.eye(3), (3, 1))
    return pos, dirs


@pytest.mark.parametrize("matched", [True, False])
def test_noise_alone_passes_the_quantile_as_often_as_the_chi_square_says(matched: bool) -> None:
    pos, dirs = _geometry()
    var = np.array([1.0, 4.0, 0.5, 2.0, 1.0, 9.0, 0.3, 1.0, 2.5]) * 1e-4
    # weights the inverse variances (exactly chi2 with 2 (9 - 6) dof) or equal ones
    fit = RigidFit.of(pos, dirs, 1.0 / var if matched else None).on_channels(np.arange(9))
    q, mean, dof = noise_quantile(fit, var)
    if matched:
        assert dof == pytest.approx(2 * (9 - 6))
    rng = np.random.default_rng(3)
    n = 40_000
    noise = (rng.normal(size=(n, 1, 9)) + 1j * rng.normal(size=(n, 1, 9))) * np.sqrt(var)
    # a rigid motion under the noise: it must not matter
    signal = fit.jw @ np.arange(1, 7) / fit.sw
    motions = fit.fit_many(noise + signal)
    rss = np.array([2 * 3 * m.noise_var[0] for m in motions])
    exceed = np.mean(rss > q)
    assert mean == pytest.approx(float(np.mean(rss)), rel=0.02)
    # 40 draws expected at 0.999; Satterthwaite's approximation errs a little in the tail
    assert 0.3 * (1 - NOISE_QUANTILE) < exceed < 2.5 * (1 - NOISE_QUANTILE)
    excess = np.array([excess_residual(m, fit, var)[1][0] for m in motions])
    assert np.mean(excess > 0) == pytest.approx(exceed)


def test_excess_is_the_whole_residual_without_noise_and_a_bent_body_keeps_its_residual() -> None:
    pos, dirs = _geometry()
    fit = RigidFit.of(pos, dirs).on_channels(np.arange(9))
    bent = fit.jw @ np.array([1, 2, 3, 0.5, 0.2, 0.1]) + 0.1 * np.sin(np.arange(9.0))
    motion = fit.fit(bent[None].astype(complex))
    assert excess_residual(motion, fit, None)[1][0] == motion.relative_residual[0]
    assert excess_residual(motion, fit, np.zeros(9))[1][0] == motion.relative_residual[0]
    # noise a thousand times below the bend takes almost nothing off it
    small = np.full(9, 1e-6 * float(motion.noise_var[0]))
    assert excess_residual(motion, fit, small)[1][0] == pytest.approx(
        motion.relative_residual[0], rel=1e-3
    )
    # noise that explains it all leaves no excess
    loud = excess_residual(motion, fit, np.full(9, 100 * float(motion.noise_var[0])))
    assert loud[0][0] == 0.0 and loud[1][0] == 0.0


@pytest.mark.parametrize("k", [1, 2, 3, 5, 6])
def test_median_bias_matches_the_exponential_order_statistics(k: int) -> None:
    rng = np.random.default_rng(k)
    draws = np.median(rng.exponential(size=(200_000, k)), axis=1)
    assert median_bias(k) == pytest.approx(float(np.mean(draws)), rel=0.01)


def test_measured_level_is_the_noise_put_in() -> None:
    std = np.array([0.01, 0.03, 0.1])
    noise = ChannelNoise(3)
    rng = np.random.default_rng(0)
    base = rng.normal(size=(len(ORDERS), 3)) + 1j * rng.normal(size=(len(ORDERS), 3))
    levels = []
    for k in range(400):
        x = base * (1 + k / 400) ** 2
        x = x + (rng.normal(size=x.shape) + 1j * rng.normal(size=x.shape)) * std
        noise.add(2 * k, ORDERS, x)
        if k < RECENT + 1:
            assert noise.variance() is None
        elif (v := noise.variance()) is not None:
            levels.append(v / std**2)
    # each level from RECENT frames scatters by ~25 %; their mean is unbiased
    np.testing.assert_allclose(np.mean(levels, axis=0), 1.0, rtol=0.05)


@pytest.mark.parametrize(("snr_db", "seed"), [(40.0, 1), (40.0, 2), (30.0, 3)])
def test_noise_alone_never_confirms_an_elastic_mode(snr_db: float, seed: int) -> None:
    # before the noise test each of these confirmed "H1.5 non-rigid from 99-106 Hz"
    doc = run(I3, {"noise_snr_db": snr_db, "seed": seed, "duration_s": 15.0})
    assert doc["elastic_mode"] is None


@pytest.mark.parametrize("each_its_own", [False, True])
def test_the_noise_levels_of_many_frames_are_those_of_each_frame_alone(
    each_its_own: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the block path (noise_levels_many, excess_many) against the one-frame reference,
    # bit for bit: unknown noise (None, a NaN channel), nil noise and measured noise;
    # or every frame its own measured noise (the rule along a sweep: a shorter path).
    # The numpy path (the compiled one is within rounding: test_compiled_runs.py)
    monkeypatch.setattr(row_kernels, "USE", False)
    pos, dirs = _geometry()
    rng = np.random.default_rng(8)
    fit = RigidFit.of(pos, dirs, rng.uniform(0.5, 2.0, 9)).on_channels(np.arange(9))
    amps = rng.normal(size=(7, 3, 9)) + 1j * rng.normal(size=(7, 3, 9))
    measured = rng.uniform(0.1, 2.0, 9)
    missing = measured.copy()
    missing[4] = np.nan
    variances = [None, measured, measured, np.zeros(9), missing, 0.01 * measured, None]
    if each_its_own:
        variances = [10.0 ** -(j / 2) * rng.uniform(0.1, 2.0, 9) for j in range(7)]
    _, _, relative, noise_var = fit.fit_arrays(amps)
    share, beyond = excess_many(relative, noise_var, fit, *noise_levels_many(fit, variances))
    for j, (motion, var) in enumerate(zip(fit.fit_many(amps), variances, strict=True)):
        one_share, one_beyond = excess_residual(motion, fit, var)
        assert np.array_equal(share[j], one_share)
        assert np.array_equal(beyond[j], one_beyond)
    assert np.any(beyond < relative) and np.any(beyond > 0)
    assert np.any(beyond == relative) != each_its_own  # (only unknown noise keeps it all)
