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

Half orders: without a 720 deg reference, and to check one, two sign hypotheses are
carried and the residuals decide between them (:mod:`estimator.hypotheses`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any

import numpy as np

from acquisition.stream import SourceEvent
from estimator.channel_fits import ChannelFits
from estimator.elastic_tail import ELASTIC_TERMS, elastic_mode_event
from estimator.equations import (
    Linearisation,
    ParameterLayout,
    linearisation_at,
    parameter_scale,
)
from estimator.fitted_runs import Screened, fit_run, half_orders, run_end
from estimator.flush import flush
from estimator.frame_gates import FrameLike, frame_reasons
from estimator.gating import OrderGates
from estimator.hypotheses import (
    DECIDE_AFTER_FRAMES,
    DECIDE_RATIO,
    Accumulator,
    better_sign,
    half_order_report,
)
from estimator.kinematics import RigidFit
from estimator.misfit import MisfitSample, misfit_report, misfits
from estimator.outcome import FrameOutcome
from estimator.partial_pairs import PartialPairs
from estimator.pending_rows import FrameQueue, RowAssembler
from estimator.redundancy import calibrated_names
from estimator.relinearise import next_relinearisation, relinearise
from estimator.result import Estimate, EstimatorStats, build_estimate
from estimator.rls import RlsSolution, RlsState
from estimator.setup import EstimatorSetup
from estimator.solve_memo import SolveMemo, within_one_call
from estimator.systematic import systematic_names, systematic_stds


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
            couple=corr.unbalance and corr.unbalance_location,
            mass=not setup.mass_known,
            offset=corr.crank_offset,
            mount_scales=tuple(m.name for m in setup.mounts) if corr.mount_scale else (),
            calibrate=calibrated_names(setup) if corr.self_calibration else (),
        )
        self.sys_names = systematic_names(setup)
        self._cal = [self.sys_names.index(n) for n in self.layout.calibrate]
        self._cal_cols = [self.layout.index(f"cal:{n}") for n in self.layout.calibrate]
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
        self.queue = FrameQueue(setup, self._cal)  # used frames whose rows are not assembled yet
        self._hypotheses_equal = True  # acc[-1] not kept up to date until it can differ
        self.decided_sign: int | None = None  # half-order sign, once the residuals decided it
        self.decision: dict[str, Any] | None = None
        self.lin = Linearisation(
            cog=np.asarray(setup.cog_nominal, float),
            inertia=np.asarray(setup.inertia_nominal, float),
            mass=float(setup.mass_nominal),
        )
        # half orders may be seen 360 deg off (no 720 deg reference, or a checked one), and
        # the sign matters unless the gas moment is measured in that angle (it flips too)
        self.cycle_unknown = setup.gas_moment is None
        self.scale = parameter_scale(self.layout, setup.inertia_nominal, setup.mass_nominal)
        self.memo = SolveMemo(n, self.scale, self._cal_cols)  # (kept within a call only)
        self.channels = ChannelFits(setup)  # the used channels and their fits' geometry
        # frames whose channels leave one rigid-body motion unseen (two sensors left)
        self.partial = PartialPairs(self, self.rows, self.scale, n_sys)
        self._events: list[SourceEvent] = []  # reportable events not taken yet
        self.misfit = MisfitSample()  # rows of a sample of frames: where the model misfits

    @property
    def elastic(self) -> dict[str, float] | None:
        """The elastic mode the residual gate confirmed (order, frequency_hz), or None."""
        return self.gates.elastic

    @property
    def flush_timing_matters(self) -> bool:
        """An estimate now changes nothing later unless True: once a frame with an unseen
        motion is queued, each flush's batch is linearised at the state of that flush
        (:mod:`estimator.partial_pairs`), so a stream must flush at the same frames on
        every run; until then a caller may skip estimates nobody reads."""
        return self.queue.flush_timing_matters

    # -- update -------------------------------------------------------------------------
    def update(self, frame: FrameLike) -> FrameOutcome:
        """Gate one frame and, if usable, add its rows to the estimate."""
        return self.update_many([frame])[0]

    def update_many(self, frames: Sequence[FrameLike]) -> list[FrameOutcome]:
        """:meth:`update` for consecutive frames (a block of a replay, a study, a file):
        the same decisions and bits as one frame at a time but a frame's relative residual
        (within an ulp: numpy sums a run's stack of readings in another order than one
        frame's; a replay feeds the live run's blocks, so it is bit-identical to it), the
        arithmetic of runs of frames fitted alike done together (:mod:`estimator.fitted_runs`);
        what remembers earlier frames (the residual baseline, the elastic-mode window, the
        smoothed noise, the relinearisations) runs frame by frame in stream order.
        """
        outcomes: list[FrameOutcome | None] = [None] * len(frames)
        elastic_before = self.elastic
        gated: list[int] = []
        # (the revolutions once: the overlap gate, channel noise and curvature read them)
        reasons, revs = frame_reasons(frames, self.setup.gates)
        reject, skipped = self._reject, 0
        for i, reason in enumerate(reasons):
            if reason is None:
                gated.append(i)
            elif reason == "overlapping":
                skipped += 1
                frame = frames[i]
                outcomes[i] = FrameOutcome(frame.time_s, frame.rpm, (), {}, "overlapping", {})
            else:
                outcomes[i] = reject(frames[i], reason)
        self.stats.skipped += skipped
        screened = self.channels.screen([frames[i] for i in gated], [revs[i] for i in gated])
        # (tuple.__new__: what the named tuple's __new__ calls, without its frame)
        todo = [tuple.__new__(Screened, (i, *s)) for i, s in zip(gated, screened, strict=True)]
        at = 0
        while at < len(todo):
            reason, fit = self.channels.choose(todo[at].used, todo[at].steps)
            if reason is not None:
                outcomes[todo[at].position] = self._reject(frames[todo[at].position], reason)
                at += 1
                continue
            assert fit is not None
            at += self._fit_run(frames, todo[at : run_end(frames, todo, at)], fit, outcomes, revs)
        self.channels.channel_noise.release(self.channels.channel_noise.estimates)
        if elastic_before is None and self.elastic is not None and frames:
            self._events.append(elastic_mode_event(self.elastic, frames[-1].time_s))
        return [o for o in outcomes if o is not None]

    def _fit_run(
        self,
        frames: Sequence[FrameLike],
        run: list[Screened],
        fit: RigidFit,
        outcomes: list[FrameOutcome | None],
        revs: list[int | None] | None = None,
    ) -> int:
        """Fit, gate and queue a run of frames fitted alike with ``fit``; returns how many
        were done: all, or those up to a relinearisation that changed the channel
        weights (the rest are fitted anew)."""
        history = self.gates.motion_history.copy()
        r = fit_run(self.setup, self.gates, fit, frames, run, revs)
        order_list, order_key, n_orders = r.order_list, r.order_key, len(r.order_list)
        channels, stats, motions = self.channels, self.stats, r.motions
        generation = channels.generation
        # (per run, not per frame: the bound methods and what every frame reads)
        judge, add = self.gates.judge, self.queue.add
        why, relative, share, beyond = r.gate_lists
        gas_known, orders = self.setup.gas_moment is not None, r.orders
        readings, power, force, moment, floor, gas = r.queue_rows  # (FittedRun.queued)
        cycle_unknown = self.cycle_unknown
        half = half_orders(order_key, cycle_unknown)
        # (the sign hypotheses of the fully measured frames: frames with an unseen
        # motion decide their own, see estimator.partial_pairs)
        tested = cycle_unknown and fit.null is None
        done, due = len(run), next_relinearisation(stats.used)
        for j, i in enumerate(r.index):
            frame = frames[i]
            if gas_known and gas[j] is None:
                outcomes[i] = self._reject(frame, "no_pressure")
                continue
            rpm = frame.rpm
            rejected, residuals, ks = judge(
                rpm, order_list, why[j], relative[j], share[j], beyond[j]
            )
            if rejected:
                stats.orders_rejected.update(rejected.values())
            if not ks:
                counts = Counter(rejected.values())
                reason = counts.most_common(1)[0][0] if counts else "no_orders"
                outcomes[i] = self._reject(frame, reason)
                continue
            motion = motions[j]
            add(
                rpm, fit, motion, ks, orders, half, readings[j], power[j], force[j],
                moment[j], floor[j], gas[j], order_list,
            )  # fmt: skip
            stats.count_used(rpm, tested, tested and "cycle_ambiguous" not in frame.flags)
            used_orders = order_key if len(ks) == n_orders else tuple([order_list[k] for k in ks])
            outcomes[i] = FrameOutcome(
                frame.time_s, rpm, used_orders, rejected, None, residuals, motion
            )
            # Relinearise after the first used frame (the nominal cog may be centimetres
            # off) and then after every full batch.
            # (Counted in used frames, not queued ones: an early flush for a published
            # estimate must not move the relinearisation points.)
            if stats.used != due:  # (relinearise_due: one more used frame at a time)
                continue
            channels.channel_noise.release(run[j].estimates)  # weights: frames so far
            relinearise(self)
            due = next_relinearisation(stats.used)
            if channels.generation != generation and j + 1 < len(run):
                # the next frames are fitted with the new weights: the curvature
                # history must hold this run's motions only up to here
                self.gates.motion_history = history
                before = [frames[k] for k in r.index[: j + 1]]
                self.gates.curvature(before, orders, motions[: j + 1], fit)
                done = j + 1
                break
        channels.again(fit, done - 1)  # counts how long a sensor has been missing
        return done

    def take_events(self) -> list[SourceEvent]:
        """What the estimator has to report since the last call (an elastic mode confirmed)."""
        events, self._events = self._events, []
        return events

    def _reject(self, frame: FrameLike, reason: str) -> FrameOutcome:
        self.stats.rejected[reason] += 1
        return FrameOutcome(frame.time_s, frame.rpm, (), {}, reason, {})

    def _flush(self) -> None:
        """Add the queued frames' rows to the sign hypotheses (:func:`estimator.flush.flush`)."""
        flush(self)

    @within_one_call
    def _relinearise(self) -> None:
        self.channels.refresh_weights()
        # stop carrying the losing sign hypothesis once the residuals leave no doubt
        if self.decided_sign is None and self.stats.ambiguous_frames >= DECIDE_AFTER_FRAMES:
            best, ratio = better_sign(self._sign_rss())
            if ratio >= DECIDE_RATIO:
                self.decided_sign = best
                self.decision = {"ratio": ratio, "after_frames": self.stats.ambiguous_frames}
        sol = self.solve(self.best_state().state)
        if not sol.observable[:9].all():
            return
        lin = linearisation_at(self.layout, sol.theta, sol.observable, self.lin.mass)
        if np.linalg.eigvalsh(lin.inertia)[0] <= 0:
            return
        self.lin = lin
        if self._cal:
            self.queue.cal_hat = sol.theta[self._cal_cols]

    def _effective(self, sign: int) -> Accumulator:
        """A sign hypothesis's state of theta (:func:`estimator.elastic_tail.effective_state`)."""
        return self.memo.effective(sign, self.acc[sign], self.elastic is not None)

    def solve(self, state: RlsState) -> RlsSolution:
        """The estimate of a state of theta: rank decisions on the parameter scale,
        the self-calibrated sensor errors held by their priors."""
        return self.memo.solve(state)

    def best_state(self) -> Accumulator:
        """The state of the estimate: the sign hypothesis with the smaller weighted
        residual (+1 unless ambiguous), with the frames of an unseen motion added."""
        self._flush()
        return self.partial.added_to(self.measured_state(self.partial.joint_sign()))

    def measured_state(self, sign: int | None = None) -> Accumulator:
        """:meth:`best_state` of the fully measured frames alone (no flush); ``sign``:
        that half-order hypothesis rather than the one in use (a decided sign wins)."""
        if sign is None or self.decided_sign is not None or not self.stats.ambiguous_frames:
            return self._effective(self._sign_in_use())
        return self._effective(sign)

    def _sign_rss(self, eff: dict[int, Accumulator] | None = None) -> dict[int, float]:
        """Weighted residual sum of squares of each half-order sign hypothesis
        (``eff``: their states, when already at hand)."""
        eff = {s: self._effective(s) for s in self.acc} if eff is None else eff
        return {s: self.solve(a.state).rss for s, a in eff.items()}

    def half_order_resolution(self) -> dict[str, Any] | None:
        """How the 720 deg ambiguity was resolved, or how the phase reference fared
        against the residual test (None when no half order was tested)."""
        self._flush()
        if self.stats.ambiguous_frames == 0:
            return None
        if self.decided_sign is not None and self.decision is not None:
            best, ratio = self.decided_sign, self.decision["ratio"]
            after = self.decision["after_frames"]
        else:
            (best, ratio), after = better_sign(self._sign_rss()), None
        return half_order_report(
            self.decided_sign,
            best,
            ratio,
            after,
            self.stats.ambiguous_frames,
            referenced=bool(self.stats.referenced_frames),
        )

    @within_one_call
    def estimate(self, final: bool = True) -> Estimate:
        """The current estimate. ``final=False`` (a live update) skips the full re-solve
        of frames with an unseen motion that the final estimate makes."""
        if final:
            self._flush()
            self.partial.solve()
        acc = self.best_state()
        sol = self.solve(acc.state)
        misfit = None
        if final and misfits(sol.rss, sol.dof, acc.state.yty):
            misfit = misfit_report(
                self.misfit,
                self._sign_in_use(),
                sol.theta[: self.layout.size],
                sol.rss / sol.dof,
                self.setup.crank_axis,
                self.layout.unbalance and not self.setup.corrections.unbalance_location,
            )
        return build_estimate(
            acc,
            sol,
            self.sys_std,
            self.layout.names,
            self.setup,
            self.stats,
            half_order=self.half_order_resolution(),
            elastic_mode=None if self.elastic is None else dict(self.elastic),
            unseen_motion=self.partial.report(),
            channel_weights=self.channels.measured_weights(),
            misfit=misfit,
        )

    def _sign_in_use(self) -> int:
        """The half-order sign hypothesis the estimate stands on."""
        if self.decided_sign is not None:
            return self.decided_sign
        if not self.stats.ambiguous_frames or self.stats.referenced_frames:
            return 1
        return better_sign(self._sign_rss())[0]
