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
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from estimator.equations import Linearisation, ParameterLayout, frame_rows
from estimator.kinematics import KinematicsError, RigidMotion, fit_rigid_motion
from estimator.rls import RlsState, rls_init, rls_solve, rls_update
from estimator.setup import EstimatorSetup
from estimator.vec import cross

# The linearised terms (G x F_unb, row weighting) move slowly once a few frames are in:
# refresh them every few used frames rather than solving after every frame.
RELINEARISE_EVERY = 8

# The half-order sign is decided when, after this many ambiguous frames, the wrong
# hypothesis leaves this many times the weighted residual of the right one.
DECIDE_AFTER_FRAMES = 40
DECIDE_RATIO = 100.0

# Frame flags (dsp.frames.FLAGS) that make the crank angle, and so every phase, untrustworthy.
# "nan", "clipped" and "missing_channel" only drop the affected channels (channel_ok).
TACHO_FLAGS = frozenset({"no_tacho", "tacho_resync", "angle_ambiguous", "angle_rebased"})


class FrameLike(Protocol):
    """The fields of ``dsp.frames.OrderFrame`` the estimator reads."""

    time_s: float
    rpm: float
    orders: tuple[float, ...]
    channels: tuple[str, ...]
    amplitudes: np.ndarray
    channel_ok: np.ndarray
    rpm_change: float
    flags: frozenset[str]


@dataclass
class Accumulator:
    """Information state plus the systematic-error sensitivity ``S`` (n, n_p)."""

    state: RlsState
    sens: np.ndarray

    @classmethod
    def empty(cls, n: int, n_sys: int) -> Accumulator:
        return cls(state=rls_init(n), sens=np.zeros((n, n_sys)))


@dataclass(frozen=True)
class _Pending:
    """A used frame waiting for its rows: its fitted motion and what the rows need, per order."""

    gamma_o: np.ndarray  # (k, 3) complex
    omega_dot: np.ndarray  # (k, 3) complex
    origin: np.ndarray  # (3,)
    cov_unit: np.ndarray  # (6, 6)
    orders: np.ndarray  # (k,)
    rpm: float
    force: np.ndarray  # (k, 3) complex
    moment: np.ndarray  # (k, 3) complex
    var: np.ndarray  # (k,)
    dm_real: np.ndarray  # (k, 12, n_sys)
    half: np.ndarray  # (k,) bool: a half order of a frame with an unknown 720 deg cycle


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


@dataclass
class EstimatorStats:
    used: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    orders_rejected: Counter[str] = field(default_factory=Counter)
    rpm_lo: float = float("inf")
    rpm_hi: float = float("-inf")
    ambiguous_frames: int = 0
    skipped: int = (
        0  # overlapping frames left out (not rejected: their data are in their neighbours)
    )


def systematic_names(setup: EstimatorSetup) -> list[str]:
    names = [f"gain:{c}" for c in setup.channels]
    for s in range(setup.n_sensors):
        names += [f"align:{s}:{ax}" for ax in "xyz"]
        names += [f"pos:{s}:{ax}" for ax in "xyz"]
    return names


def systematic_stds(setup: EstimatorSetup) -> np.ndarray:
    tol = setup.tolerances
    n_ch = len(setup.channels)
    per_sensor = [tol.alignment_rad] * 3 + [tol.position_m] * 3
    return np.array([tol.gain_rel] * n_ch + per_sensor * setup.n_sensors)


def channel_derivatives(
    setup: EstimatorSetup,
    motion: RigidMotion,
    ks: np.ndarray,
    amplitudes: np.ndarray,
    used: np.ndarray,
) -> np.ndarray:
    """d(channel readings)/d(systematic parameters), (n_k, n_used, n_sys) complex, orders ks.

    A reading is ``n . gamma_P``. A relative gain error g scales it by (1 + g);
    turning the sensor by a small angle about bench axis e changes ``n`` by
    ``e x n``, so the reading by ``e . (n x gamma_P)``; moving it along e
    changes ``gamma_P`` by ``Omega' x e``, so the reading by ``e . (n x Omega')``.
    """
    n_ch = len(setup.channels)
    idx = np.flatnonzero(used)
    out = np.zeros((len(ks), idx.size, n_ch + 6 * setup.n_sensors), complex)
    n = setup.directions[idx]  # (u, 3)
    r = setup.positions[idx] - motion.origin  # (u, 3)
    omega_dot = motion.omega_dot[ks]  # (k, 3)
    gamma_p = motion.gamma_o[ks][:, None, :] + cross(omega_dot[:, None, :], r[None])  # (k, u, 3)
    rows = np.arange(idx.size)
    out[:, rows, idx] = amplitudes[np.ix_(ks, idx)]
    base = n_ch + 6 * setup.sensor_of_channel[idx]
    turn = cross(n[None], gamma_p)  # (k, u, 3)
    move = cross(n[None], omega_dot[:, None, :])
    for ax in range(3):
        out[:, rows, base + ax] = turn[:, :, ax]
        out[:, rows, base + 3 + ax] = move[:, :, ax]
    return out


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
            unbalance=corr.unbalance, mass=not setup.mass_known, offset=corr.crank_offset
        )
        self.sys_names = systematic_names(setup)
        self.sys_std = systematic_stds(setup)
        n, n_sys = self.layout.size, len(self.sys_names)
        # one accumulator per half-order sign hypothesis (+1 as measured, -1 flipped)
        self.acc = {1: Accumulator.empty(n, n_sys), -1: Accumulator.empty(n, n_sys)}
        self.stats = EstimatorStats()
        self._pending: list[_Pending] = []  # used frames whose rows are not assembled yet
        self.decided_sign: int | None = None  # half-order sign, once the residuals decided it
        self.decision: dict[str, Any] | None = None
        self.noise_var: dict[float, float] = {}  # smoothed channel noise variance per order
        self.residual_baseline: dict[float, list[float]] = {}  # first rigid-fit residuals per order
        self.residual_limit: dict[float, float] = {}
        # last two (revolution, Omega') per order, for the mass-line curvature gate
        self.motion_history: dict[
            float, list[tuple[int, np.ndarray]]
        ] = {}  # non-rigid gate per order, from the baseline
        self.lin = Linearisation(
            cog=np.asarray(setup.cog_nominal, float),
            inertia=np.asarray(setup.inertia_nominal, float),
            mass=float(setup.mass_nominal),
        )
        self.scale = self._parameter_scale()

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
            else:
                scale.append(0.01)
        return np.array(scale)

    # -- gating -------------------------------------------------------------------------
    def _frame_gate(self, frame: FrameLike) -> str | None:
        gates = self.setup.gates
        if not np.isfinite(frame.rpm) or frame.rpm <= 0:
            return "no_rpm"
        if frame.flags & TACHO_FLAGS:
            return "tacho"
        if "leakage_uncorrected" in frame.flags:
            return "dsp_settling"
        if frame.rpm < gates.rpm_range[0] or frame.rpm > gates.rpm_range[1]:
            return "rpm_out_of_range"
        if abs(frame.rpm_change) > gates.max_rpm_change:
            return "rpm_unsteady"
        return None

    def _channel_mask(self, frame: FrameLike) -> np.ndarray:
        ok = np.zeros(len(self.setup.channels), dtype=bool)
        index = {c: i for i, c in enumerate(frame.channels)}
        for i, name in enumerate(self.setup.channels):
            j = index.get(name)
            if j is not None and bool(frame.channel_ok[j]):
                ok[i] = bool(np.all(np.isfinite(frame.amplitudes[:, j])))
        return ok

    # -- update -------------------------------------------------------------------------
    def update(self, frame: FrameLike) -> FrameOutcome:
        """Gate one frame and, if usable, add its rows to the estimate."""
        setup = self.setup
        if setup.gates.independent_frames and _overlaps_previous(frame):
            self.stats.skipped += 1
            return FrameOutcome(frame.time_s, frame.rpm, (), {}, "overlapping", {})
        reason = self._frame_gate(frame)
        rejected: dict[float, str] = {}
        residuals: dict[float, float] = {}
        used_orders: list[float] = []
        if reason is None:
            used = self._channel_mask(frame)
            if used.sum() < 6:
                reason = "too_few_channels"
        if reason is not None:
            return self._reject(frame, reason)

        index = {c: i for i, c in enumerate(frame.channels)}
        cols = [index[c] for c in np.asarray(setup.channels)[used]]
        amplitudes = np.zeros((len(frame.orders), len(setup.channels)), complex)
        amplitudes[:, used] = frame.amplitudes[:, cols]
        weights = None if setup.channel_weights is None else setup.channel_weights[used]
        try:
            motion = fit_rigid_motion(
                amplitudes[:, used], setup.positions[used], setup.directions[used], weights
            )
        except KinematicsError:
            return self._reject(frame, "sensor_geometry")

        ambiguous = "cycle_ambiguous" in frame.flags
        orders = np.asarray(frame.orders, dtype=float)
        curvature = self._curvature(frame, orders, motion)
        force, moment = setup.excitation(frame.rpm, orders)
        # Excitation level per order (force times a typical 0.3 m arm, plus moment):
        # an order the engine does not excite carries no information, only noise.
        level = 0.3 * np.linalg.norm(force, axis=1) + np.linalg.norm(moment, axis=1)
        excited = level > 1e-6 * max(float(level.max()), 1e-300)
        frame_power = float(np.mean(np.abs(amplitudes[:, used]) ** 2))
        for k, h in enumerate(orders):
            residuals[float(h)] = float(motion.relative_residual[k])
            why = (
                "no_excitation"
                if not excited[k]
                else "off_mass_line"
                if curvature.get(float(h), 0.0) > setup.gates.max_curvature
                else self._order_gate(float(h), frame.rpm, motion, k)
            )
            if why:
                rejected[float(h)] = why
                self.stats.orders_rejected[why] += 1
                continue
            used_orders.append(float(h))

        if used_orders:
            ks = np.array([k for k, h in enumerate(orders) if float(h) in used_orders])
            self._add_orders(
                frame, motion, ks, orders, amplitudes, used, force, moment, frame_power, curvature
            )
        if not used_orders:
            counts = Counter(rejected.values())
            return self._reject(frame, counts.most_common(1)[0][0] if counts else "no_orders")
        self.stats.used += 1
        self.stats.ambiguous_frames += int(ambiguous)
        self.stats.rpm_lo = min(self.stats.rpm_lo, frame.rpm)
        self.stats.rpm_hi = max(self.stats.rpm_hi, frame.rpm)
        # Relinearise after the first used frame (the nominal cog may be centimetres
        # off) and then after every full batch.
        # (Counted in used frames, not queued ones: an early flush for a published
        # estimate must not move the relinearisation points.)
        if self.stats.used % RELINEARISE_EVERY == 1:
            self._flush()
            self._relinearise()
        return FrameOutcome(
            frame.time_s, frame.rpm, tuple(used_orders), rejected, None, residuals, motion
        )

    def _reject(self, frame: FrameLike, reason: str) -> FrameOutcome:
        self.stats.rejected[reason] += 1
        return FrameOutcome(frame.time_s, frame.rpm, (), {}, reason, {})

    def _curvature(
        self, frame: FrameLike, orders: np.ndarray, motion: RigidMotion
    ) -> dict[float, float]:
        """Relative second difference of Omega' per order over three frames 720 deg apart,
        less what the measurement noise explains.

        Along the mass line the rigid motion of an order changes slowly and almost
        linearly with rpm; near a rigid-body mode it bends sharply, and there the
        dsp's cycle-long window (which follows a linear change exactly) errs by
        about as much as the bend. Measured on the simulated i3: below 0.4 % on
        mass-line sweeps up to 150 rpm/s, 0.1-130 % in a 60 rpm/s sweep through the
        modes, where the frame errors reach 0.2-28 %.
        """
        angle = getattr(frame, "crank_angle_rad", None)
        rev = (
            round(float(angle) / (2 * np.pi)) if angle is not None and np.isfinite(angle) else None
        )
        out: dict[float, float] = {}
        for k, h in enumerate(orders):
            key = float(h)
            hist = self.motion_history.get(key, [])
            w = motion.omega_dot[k]
            if (
                rev is not None
                and len(hist) == 2
                and hist[1][0] == rev - 2
                and hist[0][0] == rev - 4
            ):
                size = max(float(np.linalg.norm(w)), 1e-300)
                bend = float(np.linalg.norm(w - 2 * hist[1][1] + hist[0][1])) / size
                # what noise alone puts into a second difference of three fits (sqrt 6
                # sigma), sigma from this frame's rigid-fit residual: only the excess bends
                sigma = np.sqrt(2 * motion.noise_var[k] * np.trace(motion.cov_unit[3:, 3:])) / size
                out[key] = max(0.0, bend - 3 * np.sqrt(6.0) * float(sigma))
            if rev is not None and np.all(np.isfinite(w)):
                self.motion_history[key] = [*hist[-1:], (rev, w.copy())]
        return out

    def _order_gate(self, h: float, rpm: float, motion: RigidMotion, k: int) -> str | None:
        gates = self.setup.gates
        f_hz = h * rpm / 60.0
        if (
            self.setup.mode_max_hz is not None
            and f_hz < gates.min_mode_ratio * self.setup.mode_max_hz
        ):
            return "near_rigid_modes"
        res = float(motion.relative_residual[k])
        if res > gates.max_relative_residual:
            return "non_rigid"
        # Elastic-mode detection: sensor errors leave a residual that is a fixed
        # share of the signal along the mass line, an approaching elastic mode one
        # that grows like (f / f_e)^2. The first frames of each order set the
        # baseline; a frame whose residual has grown past it is off the mass line.
        base = self.residual_baseline.setdefault(h, [])
        if len(base) < gates.baseline_frames:
            base.append(res)
            if len(base) == gates.baseline_frames:
                self.residual_limit[h] = (
                    gates.residual_growth * float(np.median(base)) + gates.residual_margin
                )
            return None
        limit = self.residual_limit[h]
        return "non_rigid" if res > limit else None

    def _noise_var(
        self, motion: RigidMotion, ks: np.ndarray, orders: np.ndarray, floor: float
    ) -> np.ndarray:
        """Per-order channel noise variance, smoothed over frames (3 dof per frame is noisy),
        floored so noise-free data keep finite weights."""
        out = []
        for k in ks:
            h = float(orders[k])
            raw = float(motion.noise_var[k])
            var = 0.8 * self.noise_var[h] + 0.2 * raw if h in self.noise_var else raw
            self.noise_var[h] = var
            out.append(max(var, floor))
        return np.array(out)

    def _add_orders(
        self,
        frame: FrameLike,
        motion: RigidMotion,
        ks: np.ndarray,
        orders: np.ndarray,
        amplitudes: np.ndarray,
        used: np.ndarray,
        force: np.ndarray,
        moment: np.ndarray,
        frame_power: float,
        curvature: dict[float, float],
    ) -> None:
        """Queue the used orders of a frame; their rows are assembled a batch at a time."""
        var = self._noise_var(motion, ks, orders, max(1e-16 * frame_power, 1e-30))
        # Near a mode the dsp errs by about the bend of the motion across its window:
        # make that an error floor of the readings, so the intervals carry it.
        power = np.mean(np.abs(amplitudes[np.ix_(ks, np.flatnonzero(used))]) ** 2, axis=1)
        bends = np.array([curvature.get(float(hh), 0.0) for hh in orders[ks]])
        var = np.maximum(var, bends**2 * power)
        h = orders[ks]
        derivs = channel_derivatives(self.setup, motion, ks, amplitudes, used)  # (k, u, n_sys)
        dmeas = np.einsum("iu,kus->kis", motion.gain, derivs)
        self._pending.append(
            _Pending(
                gamma_o=motion.gamma_o[ks],
                omega_dot=motion.omega_dot[ks],
                origin=motion.origin,
                cov_unit=motion.cov_unit,
                orders=h,
                rpm=float(frame.rpm),
                force=force[ks],
                moment=moment[ks],
                var=var,
                dm_real=np.concatenate([dmeas.real, dmeas.imag], axis=1),  # (k, 12, n_sys)
                half=((2 * h) % 2 == 1) & ("cycle_ambiguous" in frame.flags),
            )
        )

    def _rows(
        self, batch: list[_Pending], sign: np.ndarray, sel: np.ndarray
    ) -> tuple[np.ndarray, ...]:
        """Whitened rows (k, 12, n), (k, 12) and sensitivities (k, 12, n_sys) of the
        selected (frame, order) pairs of ``batch``, motions multiplied by ``sign``."""
        cat = lambda name: np.concatenate([getattr(p, name) for p in batch])[sel]  # noqa: E731
        counts = [len(p.orders) for p in batch]

        def rep(name):
            return np.repeat(np.array([getattr(p, name) for p in batch]), counts, axis=0)[sel]

        sg = sign[sel]
        r = frame_rows(
            self.setup,
            self.layout,
            self.lin,
            sg[:, None] * cat("gamma_o"),
            sg[:, None] * cat("omega_dot"),
            rep("origin"),
            rep("cov_unit"),
            cat("orders"),
            rep("rpm"),
            cat("force"),
            cat("moment"),
            cat("var"),
        )
        return r.H, r.y, r.whiten @ r.d_meas @ (sg[:, None, None] * cat("dm_real"))

    def _flush(self) -> None:
        """Assemble the queued frames' rows and add them, frame by frame, to both hypotheses.

        The two sign hypotheses differ only in the half orders of frames whose 720 deg
        cycle is unknown (there the motion, and every measurement-derived term, flips
        sign): only those rows are computed twice, and only until the residuals have
        decided between the hypotheses.
        """
        batch, self._pending = self._pending, []
        if not batch:
            return
        half = np.concatenate([p.half for p in batch])
        flip = np.where(half, -1.0, 1.0)
        everything = np.ones(len(half), dtype=bool)
        if self.decided_sign is not None:
            sign = flip if self.decided_sign < 0 else np.ones(len(half))
            hyp = {self.decided_sign: self._rows(batch, sign, everything)}
        else:
            H, y, dr = self._rows(batch, np.ones(len(half)), everything)
            hyp = {1: (H, y, dr), -1: (H, y, dr)}
            if np.any(half):
                Hf, yf, drf = H.copy(), y.copy(), dr.copy()
                Hf[half], yf[half], drf[half] = self._rows(batch, flip, half)
                hyp[-1] = (Hf, yf, drf)
        n = self.layout.size
        bounds = np.cumsum([0] + [len(p.orders) for p in batch])
        for sign_, (Hs, ys, drs) in hyp.items():
            acc = self.acc[sign_]
            # one update per frame, in stream order: the same sums whatever the batch
            for a, b in itertools.pairwise(bounds):
                acc.state = rls_update(
                    acc.state, Hs[a:b].reshape(-1, n), ys[a:b].reshape(-1), None, self.forgetting
                )
                acc.sens = self.forgetting * acc.sens + np.einsum("kip,kis->ps", Hs[a:b], drs[a:b])

    def _decide_half_order_sign(self) -> None:
        """Stop carrying the losing sign hypothesis once the residuals leave no doubt."""
        if self.decided_sign is not None or self.stats.ambiguous_frames < DECIDE_AFTER_FRAMES:
            return
        rss = {s: rls_solve(a.state, scale=self.scale).rss for s, a in self.acc.items()}
        best = min(rss, key=lambda s: rss[s])
        ratio = rss[-best] / rss[best] if rss[best] > 0 else float("inf")
        if ratio >= DECIDE_RATIO:
            self.decided_sign = best
            self.decision = {"ratio": ratio, "after_frames": self.stats.ambiguous_frames}

    def _relinearise(self) -> None:
        self._decide_half_order_sign()
        sol = rls_solve(self.best_state().state, scale=self.scale)
        if not np.all(sol.observable[:9]):
            return
        from estimator.result import tensor_from_terms

        inertia = tensor_from_terms(sol.theta[:6])
        if np.linalg.eigvalsh(inertia)[0] <= 0:
            return
        mass = self.lin.mass
        if self.layout.mass and sol.observable[self.layout.index("inv_mass")]:
            inv = sol.theta[self.layout.index("inv_mass")]
            if inv > 0:
                mass = 1.0 / inv
        self.lin = Linearisation(cog=sol.theta[6:9].copy(), inertia=inertia, mass=mass)

    def best_state(self) -> Accumulator:
        """The sign hypothesis with the smaller weighted residual (+1 unless ambiguous)."""
        self._flush()
        if self.stats.ambiguous_frames == 0:
            return self.acc[1]
        if self.decided_sign is not None:
            return self.acc[self.decided_sign]
        rss = {s: rls_solve(a.state, scale=self.scale).rss for s, a in self.acc.items()}
        return self.acc[min(rss, key=lambda s: rss[s])]

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
        rss = {s: rls_solve(a.state, scale=self.scale).rss for s, a in self.acc.items()}
        best = min(rss, key=lambda s: rss[s])
        ratio = rss[-best] / rss[best] if rss[best] > 0 else float("inf")
        return {
            "method": "residual",
            "half_order_sign": best,
            "residual_ratio": ratio,
            "decided_after_frames": None,
            "frames": self.stats.ambiguous_frames,
        }

    def estimate(self) -> Any:
        from estimator.result import build_estimate

        return build_estimate(self)


def _overlaps_previous(frame: FrameLike) -> bool:
    """True for the frames between the 720 deg-spaced ones (odd revolution numbers)."""
    angle = getattr(frame, "crank_angle_rad", None)
    if angle is None or not np.isfinite(angle):
        return False
    return round(float(angle) / (2 * np.pi)) % 2 == 1
