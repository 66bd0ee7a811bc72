"""Channel weights from the measured noise (estimator/channel_noise.py).

The reference is the noise put in: complex Gaussian noise of a known std per
channel on amplitudes that vary smoothly along a sweep, and, through the whole
chain, the simulator's own per-channel noise std.
"""

from __future__ import annotations

import numpy as np
import pytest
from support.estimator_runs import I3, run

from estimator.channel_noise import CAPACITY, ChannelNoise, median_of_orders
from ptinertia.config import load_bench
from ptinertia.runner import make_estimator
from ptinertia.sources import REALISTIC_SIMULATION, open_source

ORDERS = (1.0, 1.5, 2.0, 3.0, 4.5, 6.0)


def _sweep(noise_std: np.ndarray, n_frames: int, seed: int = 0, bend_order: int | None = None):
    """(revolution, amplitudes) of frames 720 deg apart: amplitudes growing like rpm^2,
    plus complex noise of std ``noise_std`` per real part; ``bend_order`` resonates."""
    rng = np.random.default_rng(seed)
    n_ch = len(noise_std)
    base = rng.normal(size=(len(ORDERS), n_ch)) + 1j * rng.normal(size=(len(ORDERS), n_ch))
    for k in range(n_frames):
        rpm = 1500.0 + 3000.0 * k / n_frames
        x = base * (rpm / 1500.0) ** 2
        if bend_order is not None:  # a mode passing: a sharp, large swing
            x[bend_order] *= 1 + 5.0 / (1 + 1j * (rpm - 3000.0) / 20.0)
        noise = rng.normal(size=x.shape) + 1j * rng.normal(size=x.shape)
        yield 2 * k, x + noise * noise_std[None, :]


def test_weights_are_inverse_noise_variances():
    std = np.array([0.01, 0.03, 0.1, 0.02, 0.05])
    noise = ChannelNoise(len(std))
    for rev, x in _sweep(std, 600):
        noise.add(rev, ORDERS, x)
    w = noise.weights()
    assert w is not None
    truth = (1 / std**2) / np.median(1 / std**2)
    # the weights span 100x; the median-of-medians scatters by ~10 % with these counts
    np.testing.assert_allclose(w, truth, rtol=0.2)


def test_a_resonant_order_does_not_move_the_weights():
    std = np.array([0.01, 0.03, 0.1])
    plain, bent = ChannelNoise(3), ChannelNoise(3)
    for (rev, x), (_, xb) in zip(_sweep(std, 600), _sweep(std, 600, bend_order=2), strict=True):
        plain.add(rev, ORDERS, x)
        bent.add(rev, ORDERS, xb)
    np.testing.assert_allclose(bent.weights(), plain.weights(), rtol=0.1)


def test_overlapping_frames_and_a_dead_channel():
    # frames at every revolution (odd ones overlap their neighbours): each parity is
    # chained with itself; a channel NaN throughout keeps weight 1, the others are measured
    std = np.array([0.01, 0.04, 0.02])
    noise = ChannelNoise(3)
    for rev, x in _sweep(std, 800):
        x[:, 1] = np.nan
        noise.add(rev // 2, ORDERS, x)
    w = noise.weights()
    assert w is not None and w[1] == 1.0
    np.testing.assert_allclose(w[2] / w[0], (0.01 / 0.02) ** 2, rtol=0.2)


def test_memory_is_bounded_over_a_long_sweep():
    noise = ChannelNoise(2)
    for rev, x in _sweep(np.array([0.01, 0.02]), 5000):
        noise.add(rev, ORDERS, x)
    assert len(noise._kept.items) < CAPACITY
    assert noise.weights() is not None


def test_no_estimate_before_enough_frames():
    noise = ChannelNoise(2)
    for rev, x in _sweep(np.array([0.01, 0.02]), 5):
        noise.add(rev, ORDERS, x)
    assert noise.weights() is None


def test_simulated_bench_weights_match_the_simulator_noise():
    # 40 dB below each channel's own level: noise variances spanning ~20x
    overrides = {**REALISTIC_SIMULATION, "seed": 4, "duration_s": 30.0}
    doc = run(I3, overrides, estimator={"self_calibration": True})
    weights = doc["channel_weights"]
    meta = open_source("sim", load_bench(I3), **overrides).layout.metadata
    std = meta["noise_std"]
    names = list(weights)
    w = np.array([weights[c] for c in names])
    truth = np.array([1 / std[c] ** 2 for c in names])
    truth /= np.median(truth)
    assert truth.max() / truth.min() > 10
    np.testing.assert_allclose(w, truth, rtol=0.25)


def test_equal_weights_without_self_calibration():
    doc = run(I3, {"duration_s": 10.0, "noise_snr_db": 40.0})
    assert "channel_weights" not in doc


def test_auto_weights_follow_the_self_calibration_actually_run():
    bench = load_bench(I3)
    est = bench.estimator.model_copy(update={"self_calibration": True})
    bench = bench.model_copy(update={"estimator": est})
    assert make_estimator(bench).setup.corrections.channel_weights
    # --no self_calibration: equal weights, as without self-calibration
    assert not make_estimator(bench, ("self_calibration",)).setup.corrections.channel_weights


@pytest.mark.parametrize("k", [1, 2, 3, 4, 9, 12])
def test_the_median_over_orders_is_numpys_bit_for_bit(k: int) -> None:
    """median_of_orders replaces np.median(axis=1) in the per-frame noise estimate."""
    rng = np.random.default_rng(k)
    a = rng.lognormal(size=(40, k, 9)) * 10.0 ** rng.integers(-300, 300, size=(40, 1, 1))
    a[rng.random(a.shape) < 0.05] = np.nan  # a channel missing in an order
    a[rng.random(a.shape) < 0.05] = 0.0
    a[rng.random(a.shape) < 0.02] = np.inf
    a[:5] *= 1e-310  # subnormal: the mean of the middle pair rounds there
    got = median_of_orders(a)
    assert got.shape == (40, 9)
    assert np.array_equal(got.view(np.int64), np.median(a, axis=1).view(np.int64))
