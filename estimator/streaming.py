"""The streaming inertia estimator: one order frame in, an updated estimate out.

Per frame: gate it (rpm steadiness, rpm range, mass-line distance to the
rigid-body modes, rigidity residual per order), fit the rigid motion per order,
build the whitened rows of every usable order (:mod:`estimator.equations`) and
add them to a recursive least-squares state (:mod:`estimator.rls`).

Beside the information state we accumulate ``S = sum H^T dr/dp``: the
sensitivity of the normal equations to the declared systematic sensor errors
p (gains, orientation, position). ``dtheta/dp = -Lambda^-1 S`` then turns the
declared tolerances into a type-B covariance that does not shrink with the
number of frames, which is what makes the 95 % intervals honest when the
real errors are systematic (a 1 % gain error is the same in every frame).

Half orders without a 720 deg reference: the crank wheel gives the angle
modulo 360 deg, so the sign of every half-order amplitude is unknown. We carry
two states, one per sign, and keep the one whose weighted residual is smaller
(the wrong sign turns the roll equation of H1.5 against the inertia, and the
misfit is large); the ratio of the two residuals is reported.
"""

from __future__ import annotations

import itertools
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimator.channel_noise import ChannelNoise
from estimator.elastic_tail import ELASTIC_TERMS, effective_state, with_tail
from estimator.equations import Linearisation, ParameterLayout, linearisation_at
from estimator.gating import (
    FrameLike,
    OrderGates,
    frame_gate,
    neighbour_leakage,
    overlaps_previous,
    revolution,
)
from estimator.hypotheses import (
    DECIDE_AFTER_FRAMES,
    DECIDE_RATIO,
    Accumulator,
    add_frame,
    better_sign,
)
from estimator.kinematics import KinematicsError, RigidFit, RigidMotion
from estimator.partial_pairs import PartialPairs
from estimator.pending_rows import PendingFrame, RowAssembler
from estimator.redundancy import calibrated_names, redundancy_rows
from estimator.result import Estimate, EstimatorStats, build_estimate
from estimator.rls import RlsSolution, RlsState, rls_solve
from estimator.setup import EstimatorSetup
from estimator.systematic import systematic_names, systematic_stds

# The linearised terms (G x F_unb, row weighting) move slowly once a few frames are in:
# refresh them every few used frames rather than solving after every frame, more
# often while the estimate still moves (each refresh costs a solve and a row batch).
RELINEARISE_EVERY = 8
RELINEARISE_EVERY_LATER = 32
RELINEARISE_LATER_AFTER = 64


def relinearise_due(used: int) -> bool:
    """True after the used frames at which the linearisation point is refreshed."""
    every = RELINEARISE_EVERY if used <= RELINEARISE_LATER_AFTER else RELINEARISE_EVERY_LATER
    return used % every == 1


# Measured channel weights are taken up when one moved by more than this (log ratio):
# each change re-decomposes the fit geometry.
WEIGHT_CHANGE = 0.1

# Frames that see only two sensors are used once that has lasted this many gated frames
# in a row (a sensor dead or unplugged: see estimator/partial.py). Sporadic losses (a
# lost CAN frame takes a sensor out of one window) are rejected as "sensor_geometry":
# their neighbours carry the same information, and on the simulated CAN bus with 1 %
# lost frames and the realistic sensor errors, using them biased Izz by 6 %.
UNSEEN_AFTER_FRAMES = 8

# Frame flags (dsp.frames.FLAGS) that make the crank angle, and so every phase, untrustworthy.
# "nan", "clipped" and "missing_channel" only drop the affected channels (channel_ok).


@dataclass(frozen=True)
class FrameOutcome:
    """What the estimator did with one frame."""

    time_s: float
    rpm: float
    used_orders: tuple[float, ...]
    rejected: dict[float, str]
    reason: str | None  # why the whole frame was rejected, None when used
    relative_residual: dict[float, float]
    motion: RigidMotion | None = None  # the fitted rigid motion (for viewers)


class InertiaEstimator:
    """Frame-by-frame estimate of inertia, cog, (mass), unbalance and crank offset.

    Parameters
    ----------
    setup : the bench as the estimator sees it.
    forgetting : RLS forgetting factor (1: every used frame counts equally).
    """

    def __init__(self, setup: EstimatorSetup, forgetting: float = 1.0) -> None:
        self.setup = setup
        self.forgetting = forgetting
        corr = setup.corrections
        self.layout = ParameterLayout(
            unbalance=corr.unbalance,
            mass=not setup.mass_known,
            offset=corr.crank_offset,
            mount_scales=tuple(m.name for m in setup.mounts) if corr.mount_scale else (),
            calibrate=calibrated_names(setup) if corr.self_calibration else (),
        )
        self.sys_names = systematic_names(setup)
        self._cal = [self.sys_names.index(n) for n in self.layout.calibrate]
        self._cal_cols = [self.layout.index(f"cal:{n}") for n in self.layout.calibrate]
        self._cal_hat: np.ndarray | None = None  # the calibration at the last relinearisation
        self.sys_std = systematic_stds(setup)
        n, n_sys = self.layout.size, len(self.sys_names)
        # one accumulator per half-order sign hypothesis (+1 as measured, -1 flipped)
        # (over theta and the elastic-tail terms: see estimator.elastic_tail)
        n_all = n + ELASTIC_TERMS
        self.acc = {1: Accumulator.empty(n_all, n_sys), -1: Accumulator.empty(n_all, n_sys)}
        # The declared tolerances are the calibrated parameters' priors (mean 0): the
        # rows are whitened to unit variance, so their information is 1 / sigma^2.
        for acc in self.acc.values():
            acc.state.info[self._cal_cols, self._cal_cols] += 1.0 / self.sys_std[self._cal] ** 2
        self.gates = OrderGates(setup)
        self.stats = EstimatorStats()
        self.rows = RowAssembler(setup, self.layout, self._cal, self._cal_cols)
        self._pending: list[PendingFrame] = []  # used frames whose rows are not assembled yet
        self._hypotheses_equal = True  # acc[-1] not kept up to date until it can differ
        self.decided_sign: int | None = None  # half-order sign, once the residuals decided it
        self.decision: dict[str, Any] | None = None
        self.noise_var: dict[float, float] = {}  # smoothed channel noise variance per order
        self.lin = Linearisation(
            cog=np.asarray(setup.cog_nominal, float),
            inertia=np.asarray(setup.inertia_nominal, float),
            mass=float(setup.mass_nominal),
        )
        self.scale = self._parameter_scale()
        self._columns: dict[tuple[str, ...], np.ndarray] = {}  # frame channels -> setup columns
        self._fitters: dict[bytes, RigidFit | None] = {}  # channel mask -> geometry
        # the channels' weights in the rigid fit: declared, measured along the sweep
        # (refreshed at each relinearisation), or equal
        self.channel_noise = ChannelNoise(len(setup.channels))
        self.weights = setup.channel_weights
        self._measure_weights = corr.channel_weights and setup.channel_weights is None
        # frames whose channels leave one rigid-body motion unseen (two sensors left)
        self.partial = PartialPairs(self, self.rows, self.scale, n_sys)
        self._unseen_run = 0  # consecutive gated frames fitted with a rotation unseen

    @property
    def elastic(self) -> dict[str, float] | None:
        """The elastic mode the residual gate confirmed (order, frequency_hz), or None."""
        return self.gates.elastic

    def _parameter_scale(self) -> np.ndarray:
        scale = []
        inertia = float(np.trace(self.setup.inertia_nominal) / 3)
        for name in self.layout.names:
            if name.startswith("I"):
                scale.append(inertia)
            elif name.startswith("G"):
                scale.append(0.1)
            elif name.startswith("unb"):
                scale.append(1e-3 / (self.setup.mass_nominal if self.layout.mass else 1.0))
            elif name == "inv_mass":
                scale.append(1.0 / self.setup.mass_nominal)
            elif name.startswith("kscale:"):
                scale.append(1.0)
            else:
                scale.append(0.01)
        return np.array(scale)

    # -- gating -------------------------------------------------------------------------
    def _channel_mask(self, frame: FrameLike) -> tuple[np.ndarray, np.ndarray]:
        """Usable setup channels (bool) and, per setup channel, its column in the frame."""
        cols = self._columns.get(frame.channels)
        if cols is None:
            index = {c: i for i, c in enumerate(frame.channels)}
            cols = np.array([index.get(name, -1) for name in self.setup.channels])
            self._columns[frame.channels] = cols
        present = cols >= 0
        at = np.where(present, cols, 0)
        finite = np.isfinite(frame.amplitudes[:, at]).all(axis=0)
        ok = present & np.asarray(frame.channel_ok, bool)[at] & finite
        return ok, cols

    def _fitter(self, used: np.ndarray) -> RigidFit | None:
        """The geometry decomposition of these channels (None: degenerate), cached per mask."""
        key = used.tobytes()
        if key not in self._fitters:
            setup = self.setup
            weights = None if self.weights is None else self.weights[used]
            try:
                self._fitters[key] = RigidFit.of(
                    setup.positions[used], setup.directions[used], weights, allow_null=True
                ).on_channels(np.flatnonzero(used))
            except KinematicsError:
                self._fitters[key] = None
        return self._fitters[key]

    def _track_noise(self, frame: FrameLike, used: np.ndarray, cols: np.ndarray) -> None:
        """Add a gated frame's amplitudes to the channel noise estimate (when measured)."""
        if not self._measure_weights or (rev := revolution(frame)) is None:
            return
        x = np.where(used, frame.amplitudes[:, np.where(used, cols, 0)], np.nan)
        self.channel_noise.add(rev, tuple(frame.orders), x)

    def _refresh_weights(self) -> None:
        """Weigh the channels by their measured noise from now on (new frames' fits)."""
        if not self._measure_weights:
            return
        w = self.channel_noise.weights()
        if w is None:
            return
        if self.weights is None or np.max(np.abs(np.log(w / self.weights))) > WEIGHT_CHANGE:
            self.weights = w
            self._fitters.clear()

    def measured_weights(self) -> dict[str, float] | None:
        """The channels' weights in the rigid fit when measured from their noise, by name."""
        if not self._measure_weights or self.weights is None:
            return None
        return dict(zip(self.setup.channels, self.weights.tolist(), strict=True))

    # -- update -------------------------------------------------------------------------
    def update(self, frame: FrameLike) -> FrameOutcome:
        """Gate one frame and, if usable, add its rows to the estimate."""
        return self.update_many([frame])[0]

    def update_many(self, frames: Sequence[FrameLike]) -> list[FrameOutcome]:
        """:meth:`update` for consecutive frames, their arithmetic done together.

        The decisions are taken frame by frame in stream order, as :meth:`update`
        would; only the rigid fits and the curvature gate run on all frames at once
        (the per-call overhead of numpy dominates at one frame's size).
        """
        outcomes: list[FrameOutcome | None] = [None] * len(frames)
        todo: list[tuple[int, RigidFit, np.ndarray]] = []  # (index, geometry, readings)
        for i, frame in enumerate(frames):
            if self.setup.gates.independent_frames and overlaps_previous(frame):
                self.stats.skipped += 1
                outcomes[i] = FrameOutcome(frame.time_s, frame.rpm, (), {}, "overlapping", {})
                continue
            reason = frame_gate(frame, self.setup.gates)
            fitter = None
            if reason is None:
                used, cols = self._channel_mask(frame)
                self._track_noise(frame, used, cols)
                if used.sum() < 6:
                    reason = "too_few_channels"
                elif (fitter := self._fitter(used)) is None:
                    reason = "sensor_geometry"
                elif fitter.null is None:
                    self._unseen_run = 0
                else:
                    self._unseen_run += 1
                    if self._unseen_run < UNSEEN_AFTER_FRAMES:
                        reason = "sensor_geometry"
            if reason is not None:
                outcomes[i] = self._reject(frame, reason)
                continue
            assert fitter is not None
            todo.append((i, fitter, frame.amplitudes[:, cols[used]]))

        # Fit runs of consecutive frames with the same channels and orders together.
        def same_fit(item: tuple[int, RigidFit, np.ndarray]) -> tuple[int, tuple[float, ...]]:
            return id(item[1]), tuple(frames[item[0]].orders)

        for _, group in itertools.groupby(todo, key=same_fit):
            run = list(group)
            first_index, fit, _ = run[0]
            readings = np.stack([r for _, _, r in run])  # (n, k, u)
            motions = fit.fit_many(readings)
            powers = np.mean(readings.real**2 + readings.imag**2, axis=2)  # (n, k)
            orders = np.asarray(frames[first_index].orders, dtype=float)
            bends = self.gates.curvature([frames[i] for i, _, _ in run], orders, motions, fit)
            for j, (i, fitter, r) in enumerate(run):
                outcomes[i] = self._use(
                    frames[i], fitter, motions[j], orders, r, powers[j], bends[j]
                )
        return [o for o in outcomes if o is not None]

    def _use(
        self,
        frame: FrameLike,
        fitter: RigidFit,
        motion: RigidMotion,
        orders: np.ndarray,
        readings: np.ndarray,
        power: np.ndarray,
        curvature: np.ndarray,
    ) -> FrameOutcome:
        """Gate the orders of a fitted frame and queue the usable ones."""
        setup = self.setup
        force, moment = setup.excitation(frame.rpm, orders)
        gas = None
        if setup.gas_moment is not None:
            spectrum = getattr(frame, "spectrum", None)
            if spectrum is None or not np.all(np.isfinite(spectrum)):
                return self._reject(frame, "no_pressure")
            gas = setup.gas_moment(orders, spectrum)
            moment = moment + gas
        # Excitation level per order (force times a typical 0.3 m arm, plus moment):
        # an order the engine does not excite carries no information, only noise.
        level = 0.3 * np.sqrt(np.sum(np.abs(force) ** 2, axis=1)) + np.sqrt(
            np.sum(np.abs(moment) ** 2, axis=1)
        )
        excited = level > 1e-6 * max(float(level.max()), 1e-300)
        off_line = curvature > setup.gates.max_curvature
        leak_var = neighbour_leakage(orders, curvature, power)
        leaking = leak_var > setup.gates.max_curvature**2 * power
        rejected: dict[float, str] = {}
        residuals: dict[float, float] = {}
        ks: list[int] = []
        for k, h in enumerate(orders.tolist()):
            residuals[h] = float(motion.relative_residual[k])
            why = (
                "no_excitation"
                if not excited[k]
                else "near_rigid_modes"
                if self.gates.near_modes(h, frame.rpm)
                else "off_mass_line"
                if off_line[k]
                else "neighbour_leakage"
                if leaking[k]
                else self.gates.residual(h, frame.rpm, motion, k)
            )
            if why:
                rejected[h] = why
                self.stats.orders_rejected[why] += 1
            else:
                ks.append(k)
        if not ks:
            counts = Counter(rejected.values())
            return self._reject(frame, counts.most_common(1)[0][0] if counts else "no_orders")
        # Near a mode the dsp errs by about the bend of the motion across its window,
        # and by what a bending neighbour leaks in: error floors of the readings, so
        # the intervals carry them.
        floor = curvature**2 * power + leak_var
        self._add_orders(
            frame, fitter, motion, np.array(ks), orders, readings, power, force, moment, floor, gas
        )
        self.stats.used += 1
        # (the sign hypotheses of the fully measured frames: frames with an unseen
        # motion decide their own, see estimator.partial_pairs)
        self.stats.ambiguous_frames += int(self._cycle_unknown(frame) and fitter.null is None)
        self.stats.rpm_lo = min(self.stats.rpm_lo, frame.rpm)
        self.stats.rpm_hi = max(self.stats.rpm_hi, frame.rpm)
        # Relinearise after the first used frame (the nominal cog may be centimetres
        # off) and then after every full batch.
        # (Counted in used frames, not queued ones: an early flush for a published
        # estimate must not move the relinearisation points.)
        if relinearise_due(self.stats.used):
            self._flush()
            self._relinearise()
        used_orders = tuple(float(orders[k]) for k in ks)
        return FrameOutcome(frame.time_s, frame.rpm, used_orders, rejected, None, residuals, motion)

    def _reject(self, frame: FrameLike, reason: str) -> FrameOutcome:
        self.stats.rejected[reason] += 1
        return FrameOutcome(frame.time_s, frame.rpm, (), {}, reason, {})

    def _redundancy_raw(
        self, fit: RigidFit, motion: RigidMotion, readings: np.ndarray, ks: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The redundancy rows of the orders ``ks`` of a fitted frame, not whitened (None
        without self-calibration, or when two sensors leave no redundancy)."""
        if not self._cal or fit.null is not None:
            return None
        return redundancy_rows(
            self.setup,
            fit,
            readings[ks],
            motion.gamma_o[ks],
            motion.omega_dot[ks],
            np.ones(len(ks)),
        )

    def _raw_noise_var(
        self, motion: RigidMotion, ks: np.ndarray, rows: tuple[np.ndarray, np.ndarray] | None
    ) -> np.ndarray:
        """Per-order channel noise variance of one frame: what the rigid fit leaves, less
        what the calibrated sensor errors explain once they are estimated (``rows``: the
        orders ``ks``'s redundancy rows)."""
        if rows is None or self._cal_hat is None:
            return motion.noise_var
        H, y = rows
        resid = y - H[:, :, self._cal] @ self._cal_hat
        raw = motion.noise_var.copy()
        raw[ks] = np.sum(resid**2, axis=1) / resid.shape[1]
        return raw

    def _noise_var(
        self, raw_var: np.ndarray, ks: np.ndarray, orders: np.ndarray, floor: float
    ) -> np.ndarray:
        """Per-order channel noise variance, smoothed over frames (3 dof per frame is noisy),
        floored so noise-free data keep finite weights."""
        out = []
        for k in ks:
            h = float(orders[k])
            raw = float(raw_var[k])
            var = 0.8 * self.noise_var[h] + 0.2 * raw if h in self.noise_var else raw
            self.noise_var[h] = var
            out.append(max(var, floor))
        return np.array(out)

    def _add_orders(
        self,
        frame: FrameLike,
        fit: RigidFit,
        motion: RigidMotion,
        ks: np.ndarray,
        orders: np.ndarray,
        readings: np.ndarray,
        power: np.ndarray,
        force: np.ndarray,
        moment: np.ndarray,
        dsp_var: np.ndarray,
        gas: np.ndarray | None,
    ) -> None:
        """Queue the used orders ``ks`` of a frame; their rows are assembled a batch at a time.

        ``readings`` (k, u) are the fitted channels' amplitudes, ``power`` (k,) their
        mean square per order, ``dsp_var`` (k,) a floor for the channel noise variance
        (what the dsp errs by near modes), ``gas`` the measured gas moment in ``moment``.
        """
        floor = max(1e-16 * float(np.mean(power)), 1e-30)
        redundancy = self._redundancy_raw(fit, motion, readings, ks)
        var = self._noise_var(self._raw_noise_var(motion, ks, redundancy), ks, orders, floor)
        var = np.maximum(var, dsp_var[ks])
        h = orders[ks]
        self._pending.append(
            PendingFrame(
                gamma_o=motion.gamma_o[ks],
                omega_dot=motion.omega_dot[ks],
                origin=motion.origin,
                cov_unit=motion.cov_unit,
                orders=h,
                rpm=float(frame.rpm),
                force=force[ks],
                moment=moment[ks],
                var=var,
                fit=fit,
                amplitudes=readings[ks],
                half=((2 * h) % 2 == 1) & self._cycle_unknown(frame),
                measured_moment=None if gas is None else gas[ks],
                redundancy=redundancy,
            )
        )

    def _cycle_unknown(self, frame: FrameLike) -> bool:
        """Whether the frame's half orders may be seen through phi + 360 deg with a sign
        that matters: not when the gas moment is measured in the same angle (it flips too)."""
        return "cycle_ambiguous" in frame.flags and self.setup.gas_moment is None

    def _flush(self) -> None:
        """Assemble the queued frames' rows and add them, frame by frame, to both hypotheses.

        The two sign hypotheses differ only in the half orders of frames whose 720 deg
        cycle is unknown (there the motion, and every measurement-derived term, flips
        sign): only those rows are computed twice, and only until the residuals have
        decided between the hypotheses.
        """
        batch, self._pending = self._pending, []
        unseen = [p for p in batch if p.fit.null is not None]
        batch = [p for p in batch if p.fit.null is None]
        if batch:
            self._flush_measured(batch)
        if unseen:
            self.partial.take(unseen)

    def _flush_measured(self, batch: list[PendingFrame]) -> None:
        """:meth:`_flush` for the frames whose motion is fully measured."""
        half = np.concatenate([p.half for p in batch])
        flip = np.where(half, -1.0, 1.0)
        everything = np.ones(len(half), dtype=bool)
        dm = self.rows.sensitivity(batch)
        if self.decided_sign is not None:
            sign = flip if self.decided_sign < 0 else np.ones(len(half))
            hyp = {self.decided_sign: self.rows.rows(batch, sign, everything, dm, self.lin)}
        elif self.stats.ambiguous_frames == 0:
            # No frame without a 720 deg reference yet: both hypotheses are the same
            # sums; keep one, and copy it when the first ambiguous frame arrives.
            hyp = {1: self.rows.rows(batch, np.ones(len(half)), everything, dm, self.lin)}
            self._hypotheses_equal = True
        else:
            if self._hypotheses_equal:
                self.acc[-1] = Accumulator(state=self.acc[1].state, sens=self.acc[1].sens)
                self._hypotheses_equal = False
            H, y, dr = self.rows.rows(batch, np.ones(len(half)), everything, dm, self.lin)
            hyp = {1: (H, y, dr), -1: (H, y, dr)}
            if np.any(half):
                Hf, yf, drf = H.copy(), y.copy(), dr.copy()
                Hf[half], yf[half], drf[half] = self.rows.rows(batch, flip, half, dm, self.lin)
                hyp[-1] = (Hf, yf, drf)
        bounds = np.cumsum([0] + [len(p.orders) for p in batch])
        kin = self.rows.redundancy(batch) if self._cal else None
        f_hz = np.concatenate([p.orders * p.rpm / 60.0 for p in batch])
        for sign_, (Hs, ys, drs) in hyp.items():
            Ha = with_tail(Hs, f_hz)
            # one update per frame, in stream order: the same sums whatever the batch
            for a, b in itertools.pairwise(bounds):
                # the frame's redundancy rows (already discounted with the frame's own)
                own = None if kin is None else (kin[0][a:b], kin[1][a:b], kin[2][a:b])
                self.acc[sign_] = add_frame(
                    self.acc[sign_], Ha[a:b], ys[a:b], drs[a:b], self.forgetting, own
                )

    def _decide_half_order_sign(self) -> None:
        """Stop carrying the losing sign hypothesis once the residuals leave no doubt."""
        if self.decided_sign is not None or self.stats.ambiguous_frames < DECIDE_AFTER_FRAMES:
            return
        best, ratio = better_sign(self._sign_rss())
        if ratio >= DECIDE_RATIO:
            self.decided_sign = best
            self.decision = {"ratio": ratio, "after_frames": self.stats.ambiguous_frames}

    def _relinearise(self) -> None:
        self._refresh_weights()
        self._decide_half_order_sign()
        sol = self.solve(self.best_state().state)
        if not np.all(sol.observable[:9]):
            return
        lin = linearisation_at(self.layout, sol.theta, sol.observable, self.lin.mass)
        if np.linalg.eigvalsh(lin.inertia)[0] <= 0:
            return
        self.lin = lin
        if self._cal:
            self._cal_hat = sol.theta[self._cal_cols]

    def _effective(self, sign: int) -> Accumulator:
        """A sign hypothesis's state of theta (:func:`estimator.elastic_tail.effective_state`)."""
        return effective_state(
            self.acc[sign], self.layout.size, self.scale, self.elastic is not None
        )

    def solve(self, state: RlsState) -> RlsSolution:
        """The estimate of a state of theta: rank decisions on the parameter scale,
        the self-calibrated sensor errors held by their priors."""
        return rls_solve(state, scale=self.scale, anchored=self._cal_cols)

    def best_state(self) -> Accumulator:
        """The state of the estimate: the sign hypothesis with the smaller weighted
        residual (+1 unless ambiguous), with the frames of an unseen motion added."""
        self._flush()
        return self.partial.added_to(self.measured_state(self.partial.joint_sign()))

    def measured_state(self, sign: int | None = None) -> Accumulator:
        """:meth:`best_state` of the fully measured frames alone (no flush); ``sign``:
        that half-order hypothesis rather than the better one."""
        if self.stats.ambiguous_frames == 0:
            return self._effective(1)
        if self.decided_sign is not None:
            return self._effective(self.decided_sign)
        if sign is not None:
            return self._effective(sign)
        eff = {s: self._effective(s) for s in self.acc}
        return eff[better_sign(self._sign_rss(eff))[0]]

    def _sign_rss(self, eff: dict[int, Accumulator] | None = None) -> dict[int, float]:
        """Weighted residual sum of squares of each half-order sign hypothesis
        (``eff``: their states, when already at hand)."""
        eff = {s: self._effective(s) for s in self.acc} if eff is None else eff
        return {s: self.solve(a.state).rss for s, a in eff.items()}

    def half_order_resolution(self) -> dict[str, Any] | None:
        """How the 720 deg ambiguity was resolved (None when a phase reference existed)."""
        self._flush()
        if self.stats.ambiguous_frames == 0:
            return None
        if self.decided_sign is not None and self.decision is not None:
            return {
                "method": "residual",
                "half_order_sign": self.decided_sign,
                "residual_ratio": self.decision["ratio"],
                "decided_after_frames": self.decision["after_frames"],
                "frames": self.stats.ambiguous_frames,
            }
        best, ratio = better_sign(self._sign_rss())
        return {
            "method": "residual",
            "half_order_sign": best,
            "residual_ratio": ratio,
            "decided_after_frames": None,
            "frames": self.stats.ambiguous_frames,
        }

    def estimate(self, final: bool = True) -> Estimate:
        """The current estimate. ``final=False`` (a live update) skips the full re-solve
        of frames with an unseen motion that the final estimate makes."""
        if final:
            self._flush()
            self.partial.solve()
        acc = self.best_state()
        return build_estimate(
            acc,
            self.solve(acc.state),
            self.sys_std,
            self.layout.names,
            self.setup,
            self.stats,
            half_order=self.half_order_resolution(),
            elastic_mode=None if self.elastic is None else dict(self.elastic),
            unseen_motion=self.partial.report(),
            channel_weights=self.measured_weights(),
        )
