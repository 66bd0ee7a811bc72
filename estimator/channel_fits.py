"""Which channels of a frame the streaming estimator fits, and with what weights.

A frame's channels are matched to the setup's by name (cached per channel
tuple); a channel is used when present, flagged good and finite. The rigid-fit
geometry (:class:`estimator.kinematics.RigidFit`) of each set of used channels
is decomposed once and cached. The channels' weights in that fit are declared,
measured from their noise along the sweep (:mod:`estimator.channel_noise`,
taken up at each relinearisation), or equal.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimator.channel_noise import ChannelNoise
from estimator.frame_gates import FrameLike, revolutions
from estimator.kinematics import KinematicsError, RigidFit
from estimator.setup import EstimatorSetup

# Measured channel weights are taken up when one moved by more than this (log ratio):
# each change re-decomposes the fit geometry.
WEIGHT_CHANGE = 0.1

# Frames that see only two sensors are used once that has lasted this many gated frames
# in a row (a sensor dead or unplugged: see estimator/partial.py). Sporadic losses (a
# window that lost more of a sensor than dsp.gap_fit fills or fits) are rejected as
# "sensor_geometry": their neighbours carry the same information, and on the simulated
# CAN bus with 1 % lost frames and the realistic sensor errors, using them (when every
# lost frame took its sensor out of the window) biased Izz by 6 %.
UNSEEN_AFTER_FRAMES = 8

# A frame's channels that lost samples (dsp.gap_fit) are weighed by their variance factor,
# rounded to steps of this (log) so that their fit geometries can be cached; at most
# MAX_FITTERS geometries are kept.
VARIANCE_STEP = 0.05
MAX_FITTERS = 512


class ChannelFits:
    """The used channels of frames and the cached geometry of their rigid fits."""

    def __init__(self, setup: EstimatorSetup) -> None:
        self.setup = setup
        # frame channels -> per setup channel its column (-1: absent), whether present, and
        # the columns to gather (0 where absent; None where they are the frame's own order)
        self._columns: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, np.ndarray | None]] = {}
        self._fitters: dict[bytes, RigidFit | None] = {}  # channel mask -> geometry
        # the channels' weights in the rigid fit: declared, measured along the sweep
        # (refreshed at each relinearisation), or equal
        self.channel_noise = ChannelNoise(len(setup.channels))
        self.weights = setup.channel_weights
        self._measure_weights = setup.corrections.channel_weights and setup.channel_weights is None
        self._unseen_run = 0  # consecutive gated frames fitted with a rotation unseen
        self.generation = 0  # counts the weight changes (each makes new fit geometries)

    def screen(
        self, frames: list[FrameLike], revs: list[int | None] | None = None
    ) -> list[tuple[np.ndarray, np.ndarray, Any, int, np.ndarray | None]]:
        """The usable channels of gated frames, their noise tracked: per frame the
        usable setup channels (bool), their columns in the frame, the channel noise
        variance and estimate count as they stand after the frame
        (:meth:`ChannelNoise.add_many`; release that count before the channel
        weights may be refreshed, and everything at the end of the block), and the
        used channels' variance steps (:meth:`variance_steps`). ``revs``: the frames'
        :func:`estimator.frame_gates.revolutions`, when at hand.

        Frames sharing their channels and orders are masked with one array call."""
        if not frames:  # (a block of overlapping or rejected frames)
            return []
        masks: list[tuple[np.ndarray, np.ndarray]] = []
        used_amps: list[np.ndarray] = []  # per frame (k, n_setup), NaN where not used
        start, n = 0, len(frames)
        while start < n:  # (groups of frames with the same channels and orders count)
            first = frames[start]
            channels, shape = first.channels, first.amplitudes.shape
            end = start + 1
            # (a block's frames share their channel tuple: identity first, then its names)
            while end < n and (
                ((c := frames[end].channels) is channels or c == channels)
                and frames[end].amplitudes.shape == shape
            ):
                end += 1
            group, amps = self._masks(frames[start:end])
            masks.extend(group)
            used_amps.extend(amps)
            start = end
        if revs is None:
            revs = revolutions(frames)
        tracked = [
            (rev, tuple(f.orders), x)
            for f, x, rev in zip(frames, used_amps, revs, strict=True)
            if rev is not None
        ]
        noise = self.channel_noise
        now = (noise.variance(), noise.estimates)  # until the block's first tracked frame
        variances = iter(noise.add_many(tracked))
        # channels that lost samples (dsp.gap_fit) weigh less: their variance steps (None
        # without variance factors: no call per frame)
        steps = self.variance_steps
        out: list[tuple[np.ndarray, np.ndarray, Any, int, np.ndarray | None]] = []
        for f, (u, cols), rev in zip(frames, masks, revs, strict=True):
            if rev is not None:
                now = next(variances)
            v, n_est = now
            factor = getattr(f, "variance_factor", None)
            out.append((u, cols, v, n_est, None if factor is None else steps(f, u, cols)))
        return out

    def choose(
        self, used: np.ndarray, steps: np.ndarray | None = None
    ) -> tuple[str | None, RigidFit | None]:
        """Why a screened frame's channels cannot be fitted (None when they can) and,
        when they can, the geometry of its used channels weighed with their variance
        ``steps`` (:meth:`variance_steps`; frame by frame: it counts how long a sensor
        has been missing, and the geometry follows the weights)."""
        if used.tobytes() not in self._fitters and used.sum() < 6:  # (cached: six or more)
            return "too_few_channels", None
        if (fitter := self.fitter(used, steps)) is None:
            return "sensor_geometry", None
        if fitter.null is None:
            self._unseen_run = 0
        else:
            self._unseen_run += 1
            if self._unseen_run < UNSEEN_AFTER_FRAMES:
                return "sensor_geometry", None
        return None, fitter

    def again(self, fit: RigidFit, frames: int = 1) -> None:
        """:meth:`choose` for ``frames`` later frames of a run whose first frame it chose
        ``fit`` for (the same channels and variance steps,
        :func:`estimator.fitted_runs.run_end`): only the count of how long a sensor has
        been missing moves (nothing reads it before the next :meth:`choose`: once a run)."""
        self._unseen_run = 0 if fit.null is None else self._unseen_run + frames

    def _masks(
        self, frames: list[FrameLike]
    ) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
        """Usable setup channels (bool: present, flagged good, finite) and, per setup
        channel, its column in the frame, of frames with the same channels and orders;
        and their amplitudes (n, k, n_setup) in setup channel order, NaN where not used."""
        cols, present, at = self._columns_of(frames[0].channels)
        amps = np.array([f.amplitudes for f in frames])  # (n, k, n_setup)
        ok = np.array([f.channel_ok for f in frames], dtype=bool)
        if at is not None:  # (a copy either way: the same values)
            amps, ok = amps[:, :, at], ok[:, at]
        finite = np.logical_and.reduce(np.isfinite(amps), axis=1)  # (.all without its wrapper)
        used = present & ok & finite
        used.flags.writeable = False  # (rows shared between frames below)
        first = used[0]
        if used.tobytes() == first.tobytes() * len(used):
            # every frame the same channels (most blocks): one row, shared (read only, as
            # every row is), which run_end then compares by identity
            masks = [(first, cols)] * len(used)
        else:
            masks = [(row, cols) for row in used]
        return masks, np.where(used[:, None, :], amps, np.nan)

    def variance_steps(
        self, frame: FrameLike, used: np.ndarray, cols: np.ndarray
    ) -> np.ndarray | None:
        """The used channels' variance factors (a window that lost samples, see
        ``dsp.gap_fit``) in steps of ``VARIANCE_STEP`` (log), None when all round to one."""
        factor = getattr(frame, "variance_factor", None)
        if factor is None:
            return None
        steps = np.zeros(len(used), dtype=np.int64)
        at = cols[used]
        with np.errstate(divide="ignore", invalid="ignore"):
            steps[used] = np.round(np.log(np.asarray(factor, float)[at]) / VARIANCE_STEP)
        return steps if steps.any() else None

    def fitter(self, used: np.ndarray, steps: np.ndarray | None = None) -> RigidFit | None:
        """The geometry decomposition of these channels (None: degenerate), cached per mask
        (and per variance steps: a channel whose window lost samples weighs less)."""
        key = used.tobytes() if steps is None else used.tobytes() + steps.tobytes()
        if key not in self._fitters:
            if steps is not None and len(self._fitters) >= MAX_FITTERS:
                # a long lossy run meets many combinations: keep the plain ones
                self._fitters = {k: v for k, v in self._fitters.items() if len(k) == used.size}
            setup = self.setup
            weights = None if self.weights is None else self.weights[used]
            if steps is not None:
                base = np.ones(int(used.sum())) if weights is None else weights
                weights = base * np.exp(-VARIANCE_STEP * steps[used])
            try:
                self._fitters[key] = RigidFit.of(
                    setup.positions[used], setup.directions[used], weights, allow_null=True
                ).on_channels(np.flatnonzero(used))
            except KinematicsError:
                self._fitters[key] = None
        return self._fitters[key]

    def _columns_of(
        self, channels: tuple[str, ...]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Per setup channel, its column among ``channels`` (-1: absent) and whether it
        is present; and the columns to gather (0 where absent), None when that is all
        of ``channels`` in their order; cached."""
        known = self._columns.get(channels)
        if known is None:
            index = {c: i for i, c in enumerate(channels)}
            cols = np.array([index.get(name, -1) for name in self.setup.channels])
            present = cols >= 0
            at = np.where(present, cols, 0)
            same = len(at) == len(channels) and bool(np.all(at == np.arange(len(at))))
            known = self._columns[channels] = (cols, present, None if same else at)
        return known

    def refresh_weights(self) -> None:
        """Weigh the channels by their measured noise from now on (new frames' fits)."""
        if not self._measure_weights:
            return
        w = self.channel_noise.weights()
        if w is None:
            return
        if self.weights is None or np.max(np.abs(np.log(w / self.weights))) > WEIGHT_CHANGE:
            self.weights = w
            self._fitters.clear()
            self.generation += 1

    def measured_weights(self) -> dict[str, float] | None:
        """The channels' weights in the rigid fit when measured from their noise, by name."""
        if not self._measure_weights or self.weights is None:
            return None
        return dict(zip(self.setup.channels, self.weights.tolist(), strict=True))
