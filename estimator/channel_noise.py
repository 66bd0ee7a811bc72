"""Each channel's noise level, from the scatter of its order amplitudes along the sweep.

The rigid fit weighs the channels by their inverse noise variance. Channels do
not share one noise level (a sensor near the bank carries more combustion noise,
ranges and cables differ), and with equal weights the fitted motion and the fit
residual share noise: the redundancy rows of self-calibration
(:mod:`estimator.redundancy`) are then no longer free of errors-in-variables
bias. Measured on the simulated i3 (channel noise 40 dB below each channel's own
level, so its variance spans 20x across channels), self-calibrated, 7 seeds:
Ixy 1.8 % -> 1.0 % and Iyz 4.6 % -> 3.2 % mean error with the true variances as
weights.

Estimate: along the mass line an order's amplitude changes slowly with rpm, so
the second difference of three frames 720 deg apart (no overlap, independent
noise) is noise: ``Var(X_k - 2 X_k-1 + X_k-2) = 6 Var(X)`` for each real part.
White noise gives every order of a window the same variance, so per frame we
take the median over the orders (a resonant order bends, the median ignores it),
and over the sweep the median of those. Only the ratios across channels are used:
the rigid fit's residual sets the level.

Memory is bounded: at most ``CAPACITY`` frame estimates are kept; when full,
every other one is dropped and only every other later frame is added, so the
kept ones stay spread over the whole sweep.
"""

from __future__ import annotations

from typing import Any

import numpy as np

CAPACITY = 256
# Weights are kept within this ratio of the median channel's: a channel with no
# measurable noise (noise-free simulation, a stuck sensor) must not take the fit over.
MAX_WEIGHT_RATIO = 100.0
MIN_ESTIMATES = 8


class ChannelNoise:
    """Running per-channel noise variance of the order amplitudes (relative levels).

    Parameters
    ----------
    n_channels : the number of channels (the estimator's channel order).
    """

    def __init__(self, n_channels: int) -> None:
        self.n_channels = n_channels
        # per (orders, revolution parity): the last two frames, (rev, amplitudes) each
        self._history: dict[tuple[Any, ...], tuple[int, np.ndarray, int, np.ndarray]] = {}
        self._kept: list[np.ndarray] = []
        self._stride = 1
        self._seen = 0

    def add(self, revolution: int, orders: tuple[float, ...], amplitudes: np.ndarray) -> None:
        """One frame: its revolution number (frames 720 deg apart differ by 2) and its
        (k, n_channels) complex amplitudes, NaN for channels it lacks."""
        key = (orders, revolution % 2)
        last = self._history.get(key)
        x = np.asarray(amplitudes, complex)
        if last is not None:
            r0, x0, r1, x1 = last
            if r1 == revolution - 2 and r0 == revolution - 4:
                d = x - 2 * x1 + x0
                per_order = (d.real**2 + d.imag**2) / 12.0  # 6 Var per part, two parts
                self._keep(np.median(per_order, axis=0))
            self._history[key] = (r1, x1, revolution, x)
        else:
            self._history[key] = (revolution - 10**6, x, revolution, x)

    def _keep(self, variance: np.ndarray) -> None:
        self._seen += 1
        if self._seen % self._stride:
            return
        self._kept.append(variance)
        if len(self._kept) >= CAPACITY:
            self._kept = self._kept[::2]
            self._stride *= 2

    def weights(self) -> np.ndarray | None:
        """(n_channels,) inverse noise variances, the median channel's 1, within
        ``MAX_WEIGHT_RATIO`` of it; 1 for a channel with fewer than ``MIN_ESTIMATES``
        estimates (None while no channel has that many)."""
        stack = np.array(self._kept).reshape(-1, self.n_channels)
        known = np.sum(np.isfinite(stack), axis=0) >= MIN_ESTIMATES
        if not np.any(known):
            return None
        var = np.nanmedian(stack[:, known], axis=0)
        ref = float(np.median(var))
        if not ref > 0:
            return None
        w = np.ones(self.n_channels)
        w[known] = np.clip(ref / np.maximum(var, 1e-300), 1.0 / MAX_WEIGHT_RATIO, MAX_WEIGHT_RATIO)
        return w
