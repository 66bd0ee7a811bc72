"""The streaming estimator's store of frames fitted with one rigid-body motion unseen.

See :mod:`estimator.partial` for the method. Streaming: the pairs are kept
(up to ``MAX_PAIRS``); each new batch is linearised at the current estimate and
added; whenever the stored pairs have doubled, and for the final estimate, all
of them are solved again jointly with the fully measured frames. The work
over a sweep is then a few times that of one final solve, and the live
estimate is never more than a doubling behind the final one.
"""

from __future__ import annotations

import functools
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from estimator.equations import INERTIA_TERMS, Linearisation, linearisation_at
from estimator.hypotheses import DECIDE_RATIO, Accumulator, better_sign
from estimator.partial import (
    MAX_PAIRS,
    Contribution,
    PartialRows,
    PartialSolution,
    solve_partial,
)
from estimator.pending_rows import PendingFrame, RowAssembler
from estimator.result import capped_ratio
from estimator.rls import RlsSolution, RlsState
from powertrain.rigidbody import inertia_terms

FIRST_SOLVE_PAIRS = 48


class MeasuredFrames(Protocol):
    """What the pairs need of the estimator of the fully measured frames."""

    decided_sign: int | None  # their half-order sign, once their residuals decided it
    lin: Linearisation  # their current linearisation point

    def measured_state(self, sign: int | None = None) -> Accumulator:
        """Their state of theta (``sign``: that half-order hypothesis, else the better)."""
        ...

    def solve(self, state: RlsState) -> RlsSolution:
        """The estimate of a state of theta."""
        ...


class PartialPairs:
    """The (frame, order) pairs of an unseen motion and their share of the estimate.

    Parameters
    ----------
    est : the fully measured frames' estimator, which the pairs are solved jointly with.
    assembler : builds the pairs' rows (its layout and setup are the estimator's).
    scale : (n,) the parameters' scale (convergence of the joint solve).
    n_sys : the number of systematic sensor errors.
    """

    def __init__(
        self, est: MeasuredFrames, assembler: RowAssembler, scale: np.ndarray, n_sys: int
    ) -> None:
        self.est = est
        self.assembler = assembler
        self.layout = assembler.layout
        self.scale = scale
        n = self.layout.size
        self.stored: list[PendingFrame] = []
        self.n_stored = 0  # pairs (frame, order) in ``stored``
        self.solved = Contribution.empty(n, n_sys)  # of the pairs of the last solve
        self.since = Contribution.empty(n, n_sys)  # stored pairs added since, linearised once
        self.unstored = Contribution.empty(n, n_sys)  # pairs beyond MAX_PAIRS, linearised once
        self.n_since = 0
        self.n_unstored = 0
        self.next_solve = FIRST_SOLVE_PAIRS
        self.solution: PartialSolution | None = None
        self.unseen: np.ndarray | None = None  # (6,) the last unseen [gamma_O, Omega'] direction
        self.origin: np.ndarray | None = None
        # the sign of the half orders seen without a 720 deg reference, when the fully
        # measured frames have not decided it: the better of both at each solve
        self.own_sign = 1
        self.sign_ratio: float | None = None
        self.has_half = False
        self.sign_decided = False  # once the ratio leaves no doubt, the other sign is dropped

    @property
    def pairs(self) -> int:
        return self.n_stored + self.n_unstored

    def take(self, batch: list[PendingFrame]) -> None:
        """Add the used orders of frames fitted with a motion unseen."""
        # The unseen direction is projected out with each pair's w; give it a finite
        # variance in the row weighting (any value gives the same projected rows) so
        # that the whitening stays well conditioned.
        batch = [p._replace(cov_unit=p.cov_unit + _unseen_variance(p)) for p in batch]
        self.unseen, self.origin = batch[-1].fit.null, batch[-1].origin
        self.has_half = self.has_half or any(bool(np.any(p.half)) for p in batch)
        count = sum(len(p.orders) for p in batch)
        if self.n_stored + count > MAX_PAIRS:
            theta = self.theta_now()
            self.unstored = self.unstored.plus(Contribution.of(self.rows(batch, theta), theta)[0])
            self.n_unstored += count
            return
        self.stored.extend(batch)
        self.n_stored += count
        if self.n_stored >= self.next_solve:
            self.next_solve = 2 * self.n_stored
            self.solve()
        else:
            theta = self.theta_now()
            self.since = self.since.plus(Contribution.of(self.rows(batch, theta), theta)[0])
            self.n_since += count

    def solve(self) -> None:
        """Solve every stored pair again, jointly with the fully measured frames."""
        if not self.stored or (not self.n_since and self.solution is not None):
            return
        undecided = self.has_half and self.est.decided_sign is None and not self.sign_decided
        signs = [1, -1] if undecided else [self.sign]
        # each sign with the same hypothesis of the fully measured frames: one decision
        bases = {s: self.unstored.added_to(self.est.measured_state(s).state) for s in signs}
        base = bases[signs[0]]
        if self.solution is not None:
            theta0 = self.solution.theta
            w0 = np.vstack([self.solution.w, np.zeros((self.n_stored - len(self.solution.w), 2))])
        else:
            # from the fully measured frames where they decide, else the nominal values:
            # not from the pairs' own one-pass linearisation (made with an untested sign)
            sol = self.est.solve(base)
            theta0 = np.where(sol.observable, sol.theta, self.nominal_theta())
            w0 = np.zeros((self.n_stored, 2))
        solutions, rss = {}, {}
        for sign in signs:
            self.own_sign = sign
            solutions[sign] = solve_partial(
                bases[sign],
                lambda t, w: self.rows(self.stored, t, w),
                theta0,
                w0,
                self.scale,
                self.est.solve,
            )
            rss[sign] = self.est.solve(solutions[sign].contribution.added_to(bases[sign])).rss
        if len(signs) == 2:
            # decided as the measured frames' signs are
            self.own_sign, self.sign_ratio = better_sign(rss)
            self.sign_decided = self.sign_ratio >= DECIDE_RATIO
        else:
            self.own_sign = signs[0]
        self.solution = solutions[self.own_sign]
        self.solved = self.solution.contribution
        self.since = Contribution.empty(*self.since.sens.shape)
        self.n_since = 0

    def added_to(self, acc: Accumulator) -> Accumulator:
        """``acc`` (the fully measured frames' state) with the pairs' information."""
        if not self.pairs:
            return acc
        total = self.solved.plus(self.since).plus(self.unstored)
        return replace(acc, state=total.added_to(acc.state), sens=acc.sens + total.sens)

    def joint_sign(self) -> int | None:
        """The half-order hypothesis of the fully measured frames that goes with the
        pairs' own decision (None: no own decision, they take the better one)."""
        if not self.pairs or not self.has_half or self.est.decided_sign is not None:
            return None
        return self.own_sign

    @property
    def sign(self) -> int:
        """The half-order sign the pairs are used with."""
        decided = self.est.decided_sign
        return self.own_sign if decided is None else decided

    def theta_now(self) -> np.ndarray:
        """The current estimate where determined, the nominal values elsewhere."""
        sol = self.est.solve(self.added_to(self.est.measured_state()).state)
        return np.where(sol.observable, sol.theta, self.nominal_theta())

    def nominal_theta(self) -> np.ndarray:
        """theta at the bench's nominal values (unbalance, offset and calibration 0)."""
        setup = self.assembler.setup
        theta = np.zeros(self.layout.size)
        terms = inertia_terms(setup.inertia_nominal)
        theta[:6] = [terms[k] for k in INERTIA_TERMS]
        theta[6:9] = setup.cog_nominal
        names = self.layout.names
        if "inv_mass" in names:
            theta[names.index("inv_mass")] = 1.0 / setup.mass_nominal
        for k, name in enumerate(names):
            if name.startswith("kscale:"):
                theta[k] = 1.0
        return theta

    def rows(
        self, batch: list[PendingFrame], theta: np.ndarray, w: np.ndarray | None = None
    ) -> PartialRows:
        """The pairs' rows at ``theta``; ``dr`` at the motions completed by ``w`` (P, 2)."""
        # theta is determined everywhere (theta_now and the solves fill in the nominal values)
        lin = linearisation_at(self.layout, theta, np.ones(theta.size, bool), self.est.lin.mass)
        counts = [len(p.orders) for p in batch]
        e = np.repeat(np.array([p.fit.null for p in batch]), counts, axis=0).astype(complex)
        g0 = np.concatenate([p.gamma_o for p in batch])
        o0 = np.concatenate([p.omega_dot for p in batch])
        half = np.concatenate([p.half for p in batch])
        sign = np.where(half & (self.sign == -1), -1.0, 1.0)
        every = np.ones(len(sign), dtype=bool)
        wc = np.zeros(len(sign), complex) if w is None else w[:, 0] + 1j * w[:, 1]
        done = (g0 + wc[:, None] * e[:, :3], o0 + wc[:, None] * e[:, 3:])
        dm = self.assembler.sensitivity(batch, motion=done)
        # Two sensors leave no redundancy to calibrate them by (estimator.redundancy):
        # the equations of motion alone would let the calibration follow the noise
        # (sensor C dead, 6 realistic seeds: Iyz -25 %, cog 8 mm, outside the intervals).
        # Here the sensor errors stay type-B errors.
        rows = functools.partial(self.assembler.rows, batch, sign, every, dm, lin, calibrate=False)
        h0, y0, dr = rows(motion=(g0, o0), model_motion=done)  # dr: sensor and model terms
        h1, y1, _ = rows(motion=(g0 + e[:, :3], o0 + e[:, 3:]))
        h2, y2, _ = rows(motion=(g0 + 1j * e[:, :3], o0 + 1j * e[:, 3:]))
        return PartialRows(h0, y0, h1 - h0, y1 - y0, h2 - h0, y2 - y0, dr)

    def report(self) -> dict[str, Any] | None:
        """What the result says about the unseen motion (None when every frame saw all six)."""
        if not self.pairs or self.unseen is None or self.origin is None:
            return None
        size = max(float(np.linalg.norm(self.unseen[3:])), 1e-300)
        axis = self.unseen[3:] / size
        # the unseen motion is a rotation about a line: its point nearest the fit origin,
        # from gamma_O = Omega' x (O - P)
        point = self.origin + np.cross(axis, self.unseen[:3]) / size
        sol = self.solution
        return {
            "pairs": self.pairs,
            "unseen_rotation_axis": [float(v) for v in axis],
            "unseen_rotation_point_m": [float(v) for v in point],
            "method": "variable projection: per (frame, order) the unseen rotation fitted, "
            "the rest solved by Gauss-Newton with the fully measured frames",
            "iterations": None if sol is None else sol.iterations,
            "converged": None if sol is None else sol.converged,
            "half_order_sign": (
                None
                if not self.has_half
                else {"sign": self.sign, "residual_ratio": capped_ratio(self.sign_ratio)}
                if self.est.decided_sign is None
                else {"sign": self.sign, "from": "fully measured frames"}
            ),
        }


def _unseen_variance(pair: PendingFrame) -> np.ndarray:
    """(6, 6) a finite variance along the pair's unseen motion (see :meth:`PartialPairs.take`)."""
    assert pair.fit.null is not None
    return np.trace(pair.cov_unit) / 5 * np.outer(pair.fit.null, pair.fit.null)
