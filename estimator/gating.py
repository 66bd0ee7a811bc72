"""Order gates of the streaming estimator (see :mod:`estimator.streaming`; the gates of
whole frames: :mod:`estimator.frame_gates`).

A frame is used only where the motion is rigid and on the mass line: the rpm
steady and in range, the tacho sound, the orders away from the rigid-body
modes, the motion of each order bending slowly from frame to frame, its
rigidity residual at the level of the sweep's first frames. :class:`OrderGates`
keeps what those decisions remember of earlier frames, and confirms an elastic
mode when one order keeps failing the residual gate. That gate judges only the
residual the measured channel noise cannot explain (:mod:`estimator.rigidity`):
noise grows along a sweep and must never confirm a mode.
"""

from __future__ import annotations

import collections

import numpy as np

from estimator import row_kernels
from estimator.compiled_runs import bend_excess, order_screen
from estimator.frame_gates import FrameLike, revolutions
from estimator.kinematics import RigidFit, RigidMotion
from estimator.order_evidence import UNLOADED_MODE_RATIO, leak_matrix, neighbour_leakage, responds
from estimator.setup import EstimatorSetup

# An elastic mode is confirmed when ELASTIC_CONFIRM of the last ELASTIC_WINDOW gated
# frames of one order were non-rigid (what the estimator then does: see
# estimator.elastic_tail).
ELASTIC_WINDOW = 5
ELASTIC_CONFIRM = 3

# the curvature gate: three fits' noise in a second difference (sqrt 6 sigma), 3 of them
BEND_NOISE = 3 * np.sqrt(6.0)

# OrderGates.judge: why each rejected order was rejected, every order's relative
# residual, the indices of the orders that passed
Judged = tuple[dict[float, str], dict[float, float], list[int]]

# why an order is rejected by the gates that remember nothing (OrderGates.screen_orders)
ORDER_REASONS = ("", "no_excitation", "near_rigid_modes", "off_mass_line", "neighbour_leakage")


class OrderGates:
    """The gates that remember earlier frames, per tracked order set and per order."""

    def __init__(self, setup: EstimatorSetup) -> None:
        self.setup = setup
        self.elastic: dict[str, float] | None = None  # set once the residual gate confirms one
        # per order, whether its last ELASTIC_WINDOW gated frames were non-rigid
        self._non_rigid_recent: dict[float, collections.deque[bool]] = {}
        self.residual_baseline: dict[float, list[float]] = {}  # first rigid-fit residuals per order
        self.residual_limit: dict[float, float] = {}
        # the last two revolutions and their Omega' (k, 3) per tracked order set
        # (and unseen motion direction) for the mass-line curvature gate
        self.motion_history: dict[
            tuple[tuple[float, ...], bytes | None], tuple[int, int, tuple[np.ndarray, np.ndarray]]
        ] = {}

    def screen_orders(
        self,
        rpm: np.ndarray,
        orders: np.ndarray,
        force: np.ndarray,
        moment: np.ndarray,
        curvature: np.ndarray,
        power: np.ndarray,
        relative: np.ndarray | None = None,
        fit: RigidFit | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The order gates that remember nothing, for n fitted frames at once.

        Parameters
        ----------
        rpm : (n,) the frames' crank speeds.
        orders : (k,) their orders.
        force, moment : (n, k, 3) complex, the excitation per order (N, N m).
        curvature : (n, k) the mass-line curvature (:meth:`curvature`).
        power : (n, k) the fitted channels' mean square readings per order, (m/s^2)^2.
        relative : (n, k) the relative rigidity residual; fit : the frames' rigid-fit
            geometry (either None: an order with no known excitation is never used).

        Returns
        -------
        why : (n, k) int, the index in ``ORDER_REASONS`` of why each order is
            rejected (0: not by these gates; :meth:`judge` adds the residual gate).
        floor : (n, k) the channel variance the dsp errs by near a mode, (m/s^2)^2.
        """
        corr = self.setup.corrections
        unloaded = None
        if corr.unbalance and corr.unbalance_location and fit is not None and relative is not None:
            # the estimated unbalance drives order 1 (a balanced inline 4 has no known
            # order-1 load): its rows hold the mount reactions and the unbalance. Only
            # with the couple free: pinned at the reference point, the simulated inline
            # 4's intervals held in 2 of 10 realistic seeds (10 of 10 with it)
            unloaded = (
                (orders[None, :] == 1.0)
                & responds(relative, power, fit)
                & self.far_from_modes(orders, rpm)
            )
        top = self.setup.mode_max_hz
        max_curvature = self.setup.gates.max_curvature
        if row_kernels.USE:  # PTINERTIA_NUMBA=1: the arithmetic below in one loop
            return order_screen(
                rpm, orders, force, moment, curvature, power,
                leak_matrix(tuple(orders.tolist())),
                -np.inf if top is None else self.setup.gates.min_mode_ratio * top,
                max_curvature,
                np.zeros(curvature.shape, bool) if unloaded is None else unloaded,
            )  # fmt: skip
        # Excitation level per order (force times a typical 0.3 m arm, plus moment):
        # an order the engine does not excite carries no information, only noise.
        # (force and moment as one array: each element's operations as for either alone)
        norms = np.sqrt(np.add.reduce(np.abs(np.array((force, moment))) ** 2, axis=3))
        level = 0.3 * norms[0] + norms[1]
        excited = level > 1e-6 * np.maximum(level.max(axis=1, keepdims=True), 1e-300)
        if unloaded is not None:
            excited |= unloaded
        if top is None:
            near = np.zeros(level.shape, dtype=bool)
        else:
            near = orders[None, :] * rpm[:, None] / 60.0 < self.setup.gates.min_mode_ratio * top
        leak_var = neighbour_leakage(orders, curvature, power)
        leaking = leak_var > max_curvature**2 * power
        # np.select([~excited, near, curvature > max_curvature, leaking], [1, 2, 3, 4]):
        # the first reason that holds, as nested np.where (a tenth of np.select's overhead)
        why = np.where(
            ~excited,
            1,
            np.where(near, 2, np.where(curvature > max_curvature, 3, np.where(leaking, 4, 0))),
        )
        # Near a mode the dsp errs by about the bend of the motion across its window,
        # and by what a bending neighbour leaks in: error floors of the readings, so
        # the intervals carry them.
        return why, curvature**2 * power + leak_var

    def far_from_modes(self, orders: np.ndarray, rpm: np.ndarray) -> np.ndarray:
        """(n, k) whether each order is ``UNLOADED_MODE_RATIO`` above the rigid-body modes
        at each of the crank speeds ``rpm`` (all of them when the modes are unknown)."""
        top = self.setup.mode_max_hz
        shape = (np.size(rpm), len(orders))
        if top is None:
            return np.ones(shape, dtype=bool)
        hz = np.asarray(orders)[None, :] * np.reshape(rpm, (-1, 1)) / 60.0
        return hz >= UNLOADED_MODE_RATIO * top

    def judge(
        self,
        rpm: float,
        orders: list[float],
        why: list[int],
        relative: list[float],
        share: list[float],
        beyond: list[float],
    ) -> Judged:
        """The order gates of one fitted frame, in stream order: those of
        :meth:`screen_orders` (``why``, one of its rows) and the residual gate.

        ``relative`` is each order's relative rigidity residual, ``share`` and
        ``beyond`` that less the channel noise's mean and beyond its quantile
        (:func:`estimator.rigidity.excess_beyond`). Returns why each rejected order
        was rejected, every order's relative residual, and the orders that passed.
        """
        rejected: dict[float, str] = {}
        residuals = dict(zip(orders, relative, strict=True))
        used: list[int] = []
        limits, top = self.residual_limit, self.setup.gates.max_relative_residual
        past_limit, recents = self._past_limit, self._non_rigid_recent
        for k, h in enumerate(orders):
            w = why[k]
            if w:
                reason: str | None = ORDER_REASONS[w]
            elif relative[k] <= top and (limit := limits.get(h)) is not None:
                # :meth:`residual` once the order's baseline is set (the rule), directly;
                # within the limit, :meth:`_past_limit`'s one step inline (most orders)
                excess = beyond[k]
                if excess > limit or (recent := recents.get(h)) is None:
                    reason = past_limit(h, rpm, excess, limit)
                else:
                    recent.append(False)
                    reason = None
            else:
                reason = self.residual(h, rpm, relative[k], share[k], beyond[k])
            if reason:
                rejected[h] = reason
            else:
                used.append(k)
        return rejected, residuals, used

    def curvature(
        self,
        frames: list[FrameLike],
        orders: np.ndarray,
        motions: list[RigidMotion],
        fit: RigidFit,
        arrays: tuple[np.ndarray, np.ndarray] | None = None,
        revs: list[int | None] | None = None,
    ) -> np.ndarray:
        """(n_frames, k): relative second difference of Omega' per order over three frames
        720 deg apart, less what the measurement noise explains (0 where not known).
        ``arrays``: the ``motions``' Omega' (n, k, 3) and noise variances (n, k) as
        arrays, when at hand (:meth:`RigidFit.fit_arrays`; then the motions are ``fit``'s);
        ``revs``: the frames' :func:`revolutions`, when at hand.

        Along the mass line the rigid motion of an order changes slowly and almost
        linearly with rpm; near a rigid-body mode it bends sharply, and there the
        dsp's cycle-long window (which follows a linear change exactly) errs by
        about as much as the bend. Measured on the simulated i3: below 0.4 % on
        mass-line sweeps up to 150 rpm/s, 0.1-130 % in a 60 rpm/s sweep through the
        modes, where the frame errors reach 0.2-28 %.
        """
        if revs is None:
            revs = revolutions(frames)
        at = [j for j, r in enumerate(revs) if r is not None]
        if not at:
            return np.zeros((len(frames), len(orders)))
        # Motions fitted with a rotation unseen lack it: compare them only with motions
        # that lack the same one.
        key = (tuple(orders.tolist()), None if fit.null is None else fit.null.tobytes())
        last = self.motion_history.get(key)
        if last is None:
            none = np.full((len(orders), 3), np.nan + 0j)
            last = (-(10**9), -(10**9), (none, none))
        r0, r1, (w0, w1) = last
        seq_rev = [r0, r1, *(r for r in revs if r is not None)]
        every = len(at) == len(frames)
        if arrays is None:
            omega = np.array([motions[j].omega_dot for j in at])
            noise = np.array([motions[j].noise_var for j in at])  # (n, k)
        else:
            omega, noise = arrays if every else (arrays[0][at], arrays[1][at])
        seq_w = np.concatenate((np.array((w0, w1)), omega))  # (2 + n, k, 3)
        # each frame's revolution 2 and 4 after the two before it (frames 720 deg apart)
        chained = np.array(
            [seq_rev[i + 1] == c - 2 and seq_rev[i] == c - 4 for i, c in enumerate(seq_rev[2:])]
        )
        # (the motions' covariances: their fit's, or listed)
        fitted = [] if arrays is not None else [motions[j] for j in at]
        if row_kernels.USE and all(m.cov_unit is fit.cov_unit for m in fitted):
            # PTINERTIA_NUMBA=1: the arithmetic in one loop
            excess = bend_excess(seq_w, chained, noise, fit.omega_trace, BEND_NOISE)
        else:
            excess = self._bend_excess(seq_w, chained, noise, fitted, fit)
        self.motion_history[key] = (seq_rev[-2], seq_rev[-1], (seq_w[-2], seq_w[-1]))
        if every:
            return excess
        out = np.zeros((len(frames), len(orders)))
        out[at] = excess
        return out

    @staticmethod
    def _bend_excess(
        seq_w: np.ndarray,
        chained: np.ndarray,
        noise: np.ndarray,
        motions: list[RigidMotion],
        fit: RigidFit,
    ) -> np.ndarray:
        """:meth:`curvature`'s arithmetic (``estimator.compiled_runs.bend_excess``: the
        compiled loop) for n frames: ``seq_w`` (2 + n, k, 3) the two Omega' before them
        and theirs, ``chained`` (n,), ``noise`` (n, k) their fits' noise variances,
        ``motions`` theirs where their covariances may not be ``fit``'s (else empty)."""
        w = seq_w[2:]
        d = w - 2 * seq_w[1:-1] + seq_w[:-2]
        # |w| and |d| per order in one pass (elementwise, the bits of each alone)
        both = np.concatenate((w, d))
        norms = np.sqrt(np.add.reduce(both.real**2 + both.imag**2, axis=2))
        size = np.maximum(norms[: len(w)], 1e-300)  # (n, k)
        bend = norms[len(w) :] / size
        # what noise alone puts into a second difference of three fits (sqrt 6
        # sigma), sigma from this frame's rigid-fit residual: only the excess bends
        covs = [fit.cov_unit] if not motions else [m.cov_unit for m in motions]
        if all(c is fit.cov_unit for c in covs):  # a run's frames share their fit's
            # (2 noise trace: doubling is exact, so either product rounds alike)
            sigma = np.sqrt(noise * (2 * fit.omega_trace)) / size
        else:
            trace = np.array([np.trace(c[3:, 3:]) for c in covs])
            sigma = np.sqrt(2 * noise * trace[:, None]) / size
        excess = np.maximum(0.0, bend - BEND_NOISE * sigma)
        usable = np.isfinite(excess) if chained.all() else chained[:, None] & np.isfinite(excess)
        return np.where(usable, excess, 0.0)

    def residual(
        self, h: float, rpm: float, relative: float, share: float, excess: float
    ) -> str | None:
        """Whether order ``h`` of a fitted frame is rigid enough (None) or "non_rigid",
        from its relative rigidity residual, that less the noise's mean (``share``) and
        beyond the noise's quantile (``excess``)."""
        gates = self.setup.gates
        res = float(excess)
        if relative > gates.max_relative_residual:
            # a residual this large makes the frame unusable whatever its cause; it
            # counts towards an elastic mode only if the noise cannot explain it
            if (limit := self.residual_limit.get(h)) is not None:
                self._past_limit(h, rpm, res, limit)  # (noted; non-rigid whatever it says)
            return "non_rigid"
        # Elastic-mode detection: sensor errors leave a residual that is a fixed
        # share of the signal along the mass line, an approaching elastic mode one
        # that grows like (f / f_e)^2, noise one that follows the measured channel
        # noise (left out of ``excess``). The first frames of each order set the
        # baseline; a frame whose excess has grown past it is off the mass line.
        base = self.residual_baseline.get(h)
        if base is None:  # (not setdefault: that would build a list per order and frame)
            base = self.residual_baseline[h] = []
        if len(base) < gates.baseline_frames:
            base.append(float(share))
            if len(base) == gates.baseline_frames:
                self.residual_limit[h] = (
                    gates.residual_growth * float(np.median(base)) + gates.residual_margin
                )
            return None
        return self._past_limit(h, rpm, res, self.residual_limit[h])

    def _past_limit(self, h: float, rpm: float, excess: float, limit: float) -> str | None:
        """The residual gate once order ``h``'s baseline is set: "non_rigid" when its
        ``excess`` has grown past the ``limit``, else None; either way noted in the
        order's last ``ELASTIC_WINDOW`` frames, and an elastic mode confirmed (at
        ``rpm``) once one order keeps failing the gate. (One method, not two: it runs
        for every gated order of every frame.)"""
        flagged = excess > limit
        recent = self._non_rigid_recent.get(h)
        if recent is None:
            recent = self._non_rigid_recent[h] = collections.deque(maxlen=ELASTIC_WINDOW)
        recent.append(flagged)
        if not flagged:
            return None
        # (only a flagged frame can confirm: while no mode is, the window held fewer than
        # ELASTIC_CONFIRM after every earlier frame, and a rigid one adds none)
        if self.elastic is None and sum(recent) >= ELASTIC_CONFIRM:
            self.elastic = {"order": h, "frequency_hz": h * rpm / 60.0}
        return "non_rigid"
