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
and over the sweep the median of those. Only the ratios across channels are used
for the weights: the rigid fit's residual sets the level.

The level itself, where it is now along the sweep (:meth:`ChannelNoise.variance`),
is what the rigidity gate judges a frame's residual against
(:mod:`estimator.rigidity`): the mean of the last ``RECENT`` per-frame medians,
divided by the mean of the median of k exponential variables (each |d|^2 / 12 is
one: two real parts of Gaussian noise) so that it estimates the variance itself.
A second difference also holds what the amplitudes bend along the sweep: that
errs on the high side, towards calling a frame rigid.

Memory is bounded: at most ``CAPACITY`` frame estimates are kept; when full,
every other one is dropped and only every other later frame is added, so the
kept ones stay spread over the whole sweep.
"""

from __future__ import annotations

import collections
import functools
from collections.abc import Callable
from typing import Any

import numpy as np

from estimator import row_kernels
from estimator.compiled_noise import noise_medians, window_means

CAPACITY = 256
# Weights are kept within this ratio of the median channel's: a channel with no
# measurable noise (noise-free simulation, a stuck sensor) must not take the fit over.
MAX_WEIGHT_RATIO = 100.0
MIN_ESTIMATES = 8
# per-frame estimates in the current noise level: the order noise grows with rpm
# (shorter cycles), 8 frames 720 deg apart span 16 revolutions
RECENT = 8


@functools.cache  # k is the channel count, fixed for a run: one sum per run
def median_bias(k: int) -> float:
    """E[median of k independent unit-mean exponential variables] (numpy's median:
    the mean of the two middle ones for even k): E[X_(j)] = sum_{i=k-j+1}^{k} 1/i."""

    def order_stat(j: int) -> float:
        return float(sum(1.0 / i for i in range(k - j + 1, k + 1)))

    if k % 2:
        return order_stat((k + 1) // 2)
    return 0.5 * (order_stat(k // 2) + order_stat(k // 2 + 1))


class ThinnedSample:
    """A sample of a stream that stays below ``capacity`` items however long the stream:
    when full, every other kept item is dropped and only every other later item is kept
    from then on, so the sample stays spread evenly over the whole stream."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.items: list[Any] = []
        self._stride = 1
        self._seen = 0

    def add(self, item: Any) -> None:
        self._seen += 1
        if not self._seen % self._stride:
            self._keep(item)

    def extend(self, items: Any) -> None:
        """:meth:`add` of each of ``items`` in turn (one call for a block's)."""
        keep = self._keep
        for item in items:
            self._seen += 1
            if not self._seen % self._stride:
                keep(item)

    def add_made(self, make: Callable[[], Any]) -> None:
        """:meth:`add` of ``make()``, called only when the item is kept."""
        self._seen += 1
        if not self._seen % self._stride:
            self._keep(make())

    def add_made_many(self, n: int, make: Callable[[int], Any]) -> None:
        """:meth:`add_made` of ``n`` items in turn, ``make(i)`` called only for the kept
        ones (no callable made per item: a flush's frames, most of them not kept)."""
        keep = self._keep
        for i in range(n):
            self._seen += 1
            if not self._seen % self._stride:  # (read each time: a keep may double it)
                keep(make(i))

    def _keep(self, item: Any) -> None:
        self.items.append(item)
        if len(self.items) >= self.capacity:
            self.items = self.items[::2]
            self._stride *= 2

    def copy(self) -> ThinnedSample:
        out = ThinnedSample(self.capacity)
        out.items, out._stride, out._seen = list(self.items), self._stride, self._seen
        return out


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
        self._kept = ThinnedSample(CAPACITY)  # per-frame variance estimates along the sweep
        self._recent: list[np.ndarray] = []  # the last RECENT bias-corrected estimates
        # estimates of a block not in _kept yet: a block's later frames must not weigh
        # the channels of a relinearisation at one of its earlier frames (release)
        self._held: collections.deque[np.ndarray] = collections.deque()
        self.estimates = 0  # per-frame estimates made so far
        self._released = 0  # of which in _kept
        self._variance: np.ndarray | None = None  # variance(), kept as _recent changes

    def add(self, revolution: int, orders: tuple[float, ...], amplitudes: np.ndarray) -> None:
        """One frame: its revolution number (frames 720 deg apart differ by 2) and its
        (k, n_channels) complex amplitudes, NaN for channels it lacks."""
        self.add_many([(revolution, orders, np.asarray(amplitudes, complex))])
        self.release(self.estimates)

    def release(self, upto: int) -> None:
        """Let the first ``upto`` per-frame estimates count in :meth:`weights`."""
        if self._released >= upto:
            return
        held = self._held
        self._kept.extend([held.popleft() for _ in range(upto - self._released)])
        self._released = upto

    def add_many(
        self, frames: list[tuple[int, tuple[float, ...], np.ndarray]]
    ) -> list[tuple[np.ndarray | None, int]]:
        """:meth:`add` for consecutive frames, (revolution, orders, amplitudes) each, the
        medians of all frames taken in one call; returns :meth:`variance` as it stands
        after each frame (the same arrays, bit for bit, as adding one at a time), and
        ``estimates`` then. The frames' estimates count in :meth:`weights` once
        released (:meth:`release`)."""
        prior = self.variance()
        made = self.estimates
        chained: list[int] = []  # frames with a second difference, in order
        triples: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # their x, x1, x0
        history = self._history
        for j, (revolution, orders, x) in enumerate(frames):
            key = (orders, revolution % 2)
            last = history.get(key)
            if last is None:
                history[key] = (revolution - 10**6, x, revolution, x)
                continue
            r0, x0, r1, x1 = last
            if r1 == revolution - 2 and r0 == revolution - 4:
                triples.append((x, x1, x0))
                chained.append(j)
            history[key] = (r1, x1, revolution, x)
        out: list[tuple[np.ndarray | None, int]] = []
        if not chained:
            return [(prior, made)] * len(frames)
        # frames of one block track the same orders: one array call per order count
        # (each operation elementwise or per frame: the bits of one frame at a time)
        medians: list[np.ndarray] = [np.empty(0)] * len(triples)
        recent: list[np.ndarray] = [np.empty(0)] * len(triples)
        by_k: dict[int, list[int]] = {}
        if len({len(t[0]) for t in triples}) == 1:  # (most blocks: one order count)
            by_k[len(triples[0][0])] = list(range(len(triples)))
        else:
            for i, (x, _, _) in enumerate(triples):
                by_k.setdefault(len(x), []).append(i)
        for k, at in by_k.items():
            # (one stack of the triples: copies, the same values as three; from a flat
            # list of their arrays, which numpy reads in half the time of the tuples)
            picked = triples if len(at) == len(triples) else [triples[i] for i in at]
            flat = np.array([a for t in picked for a in t])
            stack = flat.reshape(len(picked), 3, *flat.shape[1:])
            if row_kernels.USE:  # PTINERTIA_NUMBA=1: in one loop, the same bits
                m = noise_medians(stack)
            else:
                x, x1, x0 = stack[:, 0], stack[:, 1], stack[:, 2]
                d = x - 2 * x1 + x0
                per_order = (d.real**2 + d.imag**2) / 12.0  # 6 Var per part, two parts
                m = median_of_orders(per_order)
            if len(at) == len(triples):  # (every frame's: the rows as they come)
                medians, recent = list(m), list(m / median_bias(k))
                continue
            for i, row, unbiased in zip(at, m, m / median_bias(k), strict=True):
                medians[i], recent[i] = row, unbiased
        before = len(self._recent)
        self.estimates += len(chained)
        self._held.extend(medians)
        self._recent.extend(recent)
        windows = _window_variances(self._recent[max(before - RECENT + 1, 0) :])
        self._recent = self._recent[-RECENT:]
        if windows:
            self._variance = windows[-1]
        # the variance after each frame: the window ending at its latest estimate
        now = prior
        first = RECENT - 1 - min(before, RECENT - 1)  # first new estimate with a full window
        step = 0
        for j in range(len(frames)):
            if step < len(chained) and chained[step] == j:
                now = windows[step - first] if step >= first else None
                step += 1
            out.append((now, made + step))
        return out

    def variance(self) -> np.ndarray | None:
        """(n_channels,) the current noise variance of the real (and of the imaginary)
        part of an order amplitude, (m/s^2)^2, NaN for a channel not measured lately
        (None until ``RECENT`` frames have been measured)."""
        return self._variance

    def weights(self) -> np.ndarray | None:
        """(n_channels,) inverse noise variances, the median channel's 1, within
        ``MAX_WEIGHT_RATIO`` of it; 1 for a channel with fewer than ``MIN_ESTIMATES``
        estimates (None while no channel has that many)."""
        stack = np.array(self._kept.items).reshape(-1, self.n_channels)
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


def median_of_orders(a: np.ndarray) -> np.ndarray:
    """``np.median(a, axis=1)`` of a float (m, k, n) array, without its wrapper (most of
    its time at these sizes): the same partition, the same mean of the middle pair, the
    same NaN where a slice has one; so the same bits."""
    k = a.shape[1]
    half = k // 2
    kth = [half, -1] if k % 2 else [half - 1, half, -1]
    part = np.partition(a, kth, axis=1)
    if k % 2:
        out = part[:, half].copy()
    else:
        out = (part[:, half - 1] + part[:, half]) / 2  # np.mean of the pair
    last = part[:, -1]
    nan = np.isnan(last)  # (NaN partitions last, as np.median checks)
    out[nan] = last[nan]
    return out


def _window_variances(recent: list[np.ndarray]) -> list[np.ndarray]:
    """The mean of each run of ``RECENT`` consecutive estimates of ``recent``, NaN for a
    channel missing in one of them: summed in stream order, as ``np.mean(axis=0)`` of
    each run sums it (so one frame at a time and a block give the same bits)."""
    if len(recent) < RECENT:
        return []
    stack = np.array(recent)  # (m, n_channels)
    if row_kernels.USE:  # PTINERTIA_NUMBA=1: in one loop, the same bits
        return list(window_means(stack, RECENT))
    n = len(recent) - RECENT + 1
    total = stack[:n] + stack[1 : n + 1]
    for j in range(2, RECENT):
        total = total + stack[j : n + j]
    # no channel missing in a run: no non-finite estimate between its ends (counts)
    missing = np.concatenate(
        [np.zeros((1, stack.shape[1]), int), np.cumsum(~np.isfinite(stack), 0)]
    )
    finite = missing[RECENT:] == missing[:n]
    return list(np.where(finite, total / RECENT, np.nan))
