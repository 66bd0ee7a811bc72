"""Used frames waiting for their rows, and the assembly of those rows a batch at a time.

The streaming estimator (:mod:`estimator.streaming`) queues each used frame as a
:class:`estimator.frame_stack.PendingFrame` (its fitted motion and what the rows need, per order) and
assembles the whitened rows of a whole batch at once (:class:`RowAssembler`):
the equations of motion (:func:`estimator.equations.frame_rows`), their
sensitivity to the declared systematic sensor errors and, with
self-calibration, the rigid fits' redundancy rows. The store of frames with an
unseen motion (:mod:`estimator.partial_pairs`) builds its rows with the same
assembler. With ``PTINERTIA_NUMBA=1`` the assembler builds the rows and both
sensitivities with compiled loops (:mod:`estimator.compiled_rows`,
:mod:`estimator.compiled_model_rows`), within rounding of
the numpy functions, which stay the default and the reference.

A flush hands the assembler its frames stacked (:mod:`estimator.frame_stack`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from estimator import row_kernels
from estimator.compiled_model_rows import (
    kernel_model_input_rows,
    model_constants,
    model_linearisation,
)
from estimator.compiled_rows import (
    kernel_motion_sensitivity,
    kernel_rows,
    row_constants,
    row_linearisation,
)
from estimator.elastic_tail import ELASTIC_TERMS
from estimator.equations import Linearisation, ParameterLayout, frame_rows
from estimator.frame_stack import FrameStack, PendingFrame, stacked
from estimator.hypotheses import Redundancy
from estimator.kinematics import RigidFit, RigidMotion
from estimator.model_inputs import model_input_rows
from estimator.redundancy import redundancy_rows
from estimator.setup import EstimatorSetup
from estimator.systematic import SensorBlocks, motion_sensitivity, sensor_blocks


class FrameQueue:
    """Used frames queued for their rows, and the per-order channel noise variance
    their rows are whitened with.

    Parameters
    ----------
    setup : the bench as the estimator sees it.
    cal : the self-calibrated sensor errors, as indices into the systematic parameters.
    """

    def __init__(self, setup: EstimatorSetup, cal: Sequence[int]) -> None:
        self.setup = setup
        self.cal = list(cal)
        self.frames: list[PendingFrame] = []
        self.noise_var: dict[float, float] = {}  # smoothed channel noise variance per order
        self.cal_hat: np.ndarray | None = None  # the calibration at the last relinearisation
        # Once a frame with an unseen motion is queued, when the queue is flushed changes
        # the estimate: estimator.partial_pairs linearises each batch it takes at the state
        # of that flush. Until then flushes may come whenever (the sums are the same bits),
        # so a caller may skip running estimates nobody reads (ptinertia.pipeline).
        self.flush_timing_matters = False

    def take(self) -> list[PendingFrame]:
        """The queued frames, in stream order; the queue is left empty."""
        frames, self.frames = self.frames, []
        return frames

    def add(
        self,
        rpm: float,
        fit: RigidFit,
        motion: RigidMotion,
        ks: list[int],
        orders: np.ndarray,
        half: np.ndarray,
        readings: np.ndarray,
        power_sum: float,
        force: np.ndarray,
        moment: np.ndarray,
        dsp_var: np.ndarray | list[float],
        gas: np.ndarray | None,
        order_list: list[float] | None = None,
    ) -> None:
        """Queue the used orders ``ks`` of a frame; their rows are assembled a batch at a time.

        ``half`` (k,) bool: the frame's half orders of unknown sign (no 720 deg
        reference; never changed: frames share it). ``readings`` (k, u) are the fitted
        channels' amplitudes, ``power_sum`` their mean square summed over the orders,
        ``dsp_var`` (k,) a floor for the channel noise variance (what the dsp errs by
        near modes; a list: its values, as a run makes them once), ``gas`` the measured
        gas moment in ``moment``; ``order_list``: ``orders`` as a list, when at hand.
        """
        if fit.null is not None:
            self.flush_timing_matters = True
        floor = max(1e-16 * (power_sum / len(orders)), 1e-30)  # of the mean square
        if self.cal:
            redundancy = self._redundancy_raw(fit, motion, readings, ks)
            raw = self._raw_noise_var(motion, ks, redundancy)
        else:  # (without self-calibration: what the rigid fit leaves)
            redundancy, raw = None, motion.noise_var
        var = self._noise_var(raw, ks, orders if order_list is None else order_list, floor, dsp_var)
        gamma_o, omega_dot, h = motion.gamma_o, motion.omega_dot, orders
        if len(ks) < len(orders):  # (every order used, the common case: the arrays as they are)
            at = np.array(ks)
            gamma_o, omega_dot, h, half = gamma_o[at], omega_dot[at], h[at], half[at]
            force, moment, readings = force[at], moment[at], readings[at]
            gas = None if gas is None else gas[at]
        self.frames.append(
            # (by position, in field order, and with tuple.__new__, which the named
            # tuple's __new__ calls: 0.4 us a frame less than by name, and its frame less)
            tuple.__new__(
                PendingFrame,
                (
                    gamma_o,
                    omega_dot,
                    motion.origin,
                    motion.cov_unit,
                    h,  # orders
                    float(rpm),
                    force,
                    moment,
                    var,  # (a list: FrameStack.cat makes a flush's array in one go)
                    fit,
                    readings,  # amplitudes
                    half,
                    gas,  # measured_moment
                    redundancy,
                ),
            )
        )

    def _redundancy_raw(
        self, fit: RigidFit, motion: RigidMotion, readings: np.ndarray, ks: list[int]
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The redundancy rows of the orders ``ks`` of a fitted frame, not whitened (None
        without self-calibration, or when two sensors leave no redundancy)."""
        if not self.cal or fit.null is not None:
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
        self, motion: RigidMotion, ks: list[int], rows: tuple[np.ndarray, np.ndarray] | None
    ) -> np.ndarray:
        """Per-order channel noise variance of one frame: what the rigid fit leaves, less
        what the calibrated sensor errors explain once they are estimated (``rows``: the
        orders ``ks``'s redundancy rows)."""
        if rows is None or self.cal_hat is None:
            return motion.noise_var
        H, y = rows
        resid = y - H[:, :, self.cal] @ self.cal_hat
        raw = motion.noise_var.copy()
        raw[ks] = np.sum(resid**2, axis=1) / resid.shape[1]
        return raw

    def _noise_var(
        self,
        raw_var: np.ndarray,
        ks: list[int],
        orders: np.ndarray | list[float],
        floor: float,
        dsp_var: np.ndarray | list[float],
    ) -> list[float]:
        """Per-order channel noise variance of the orders ``ks``, smoothed over frames (3
        dof per frame is noisy), floored so noise-free data keep finite weights, and at
        least what the dsp errs by (``dsp_var``, per order). (``orders`` and ``dsp_var``
        may come as lists: a run makes them once for all its frames.)"""
        out = []
        smoothed = self.noise_var
        hs = orders if isinstance(orders, list) else orders.tolist()
        dsps = dsp_var if isinstance(dsp_var, list) else dsp_var.tolist()
        raws = raw_var.tolist()
        for k in ks:
            h, raw, dsp = hs[k], raws[k], dsps[k]
            var = 0.8 * smoothed[h] + 0.2 * raw if h in smoothed else raw
            smoothed[h] = var
            if floor > var:  # (max(var, floor) without the call: var when either is NaN)
                var = floor
            # np.maximum on floats: the larger, NaN if either is (max() would drop a NaN dsp)
            out.append(var if var >= dsp or var != var else dsp)
        return out


class RowAssembler:
    """The rows of queued frames under one parameter layout.

    Parameters
    ----------
    setup : the bench as the estimator sees it.
    layout : where each unknown sits in theta.
    cal : the self-calibrated sensor errors, as indices into the systematic parameters.
    cal_cols : their columns in theta (same order as ``cal``).
    """

    def __init__(
        self,
        setup: EstimatorSetup,
        layout: ParameterLayout,
        cal: Sequence[int],
        cal_cols: Sequence[int],
    ) -> None:
        self.setup = setup
        self.layout = layout
        self.cal = list(cal)
        self.cal_cols = list(cal_cols)
        # the last fit's channels grouped by sensor (a bench keeps its fit frame after frame)
        self._blocks: tuple[RigidFit, SensorBlocks] | None = None
        # the compiled rows (PTINERTIA_NUMBA=1; tests and benchmarks switch it per assembler)
        self.compiled = row_kernels.USE
        # the compiled rows' constants under the last linearisation (one per relinearisation)
        self._constants: tuple[Linearisation, bool, tuple[Any, Any]] | None = None
        # the compiled model-input rows' excitation tables per set of orders (fixed)
        self._tables: dict[tuple[float, ...], np.ndarray] = {}

    def _constants_at(self, lin: Linearisation, measured: bool) -> tuple[Any, Any]:
        """:func:`estimator.compiled_rows.row_constants` and
        :func:`estimator.compiled_model_rows.model_constants`, kept while ``lin`` stays."""
        kept = self._constants
        if kept is not None and kept[1] == measured:
            if kept[0] is lin:
                return kept[2]
            # (a relinearisation, before nearly every flush: only what lin moves anew)
            rows, model = kept[2]
            made = (
                (*row_linearisation(self.layout, lin), *rows[2:]),
                (*model[:3], model_linearisation(self.setup, lin, not self.layout.mass)),
            )
        else:
            made = (
                row_constants(self.setup, self.layout, lin, measured),
                model_constants(self.setup, lin, not self.layout.mass),
            )
        self._constants = (lin, measured, made)
        return made

    def _sensor_blocks(self, fit: RigidFit) -> SensorBlocks:
        if self._blocks is None or self._blocks[0] is not fit:
            self._blocks = (fit, sensor_blocks(self.setup, fit))
        return self._blocks[1]

    def sensitivity(
        self,
        batch: list[PendingFrame] | FrameStack,
        motion: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> np.ndarray:
        """(P, 12, n_sys): d motion / d systematic parameters of every pair of ``batch``
        (at the pairs' motions, or at ``motion``: (P, 3) gamma_O and Omega' in pair order)."""
        stack = stacked(batch)
        frames = stack.frames
        if motion is None:
            motion = (stack.cat("gamma_o"), stack.cat("omega_dot"))
        bounds = stack.bounds
        out = []
        start = 0
        for end in range(1, len(frames) + 1):
            if end == len(frames) or frames[end].fit is not frames[start].fit:
                a, b = bounds[start], bounds[end]
                # (fits of other channels read other widths: one array per run of a fit)
                run = frames[start:end]
                amplitudes = (
                    stack.cat("amplitudes")
                    if len(run) == len(frames)
                    else np.concatenate([p.amplitudes for p in run])
                )
                blocks = self._sensor_blocks(frames[start].fit)
                if self.compiled:
                    out.append(
                        kernel_motion_sensitivity(
                            blocks, amplitudes, motion[0][a:b], motion[1][a:b]
                        )
                    )
                else:
                    out.append(
                        motion_sensitivity(
                            self.setup,
                            frames[start].fit,
                            amplitudes,
                            motion[0][a:b],
                            motion[1][a:b],
                            blocks,
                        )
                    )
                start = end
        return out[0] if len(out) == 1 else np.concatenate(out)

    def rows(
        self,
        batch: list[PendingFrame] | FrameStack,
        sign: np.ndarray | None,
        sel: np.ndarray | None,
        dm_real: np.ndarray,
        lin: Linearisation,
        motion: tuple[np.ndarray, np.ndarray] | None = None,
        calibrate: bool = True,
        model_motion: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, ...]:
        """Whitened rows (k, 12, n), (k, 12) and sensitivities (k, 12, n_sys) of the
        selected (frame, order) pairs of ``batch`` (``sel`` (P,) bool; None: every
        pair), motions multiplied by ``sign`` (P,) (None: +1, the motions as they are)
        (the pairs' own motions, or ``motion``: (P, 3) gamma_O and Omega' in pair
        order), linearised at ``lin``. ``calibrate=False``: the self-calibrated
        sensor errors stay systematic errors in these rows. ``model_motion``: the
        motion the model inputs' sensitivities are taken at (default: the rows')."""
        # every pair selected (the common case): the concatenations as they are, no copies
        pick: slice | np.ndarray = slice(None) if sel is None or bool(np.all(sel)) else sel
        stack = stacked(batch)
        cat = lambda name: stack.cat(name)[pick]  # noqa: E731
        gamma_o, omega_dot = (cat("gamma_o"), cat("omega_dot")) if motion is None else motion

        def rep(name):
            return stack.per_pair(name)[pick]

        origin, orders, rpm = rep("origin"), cat("orders"), rep("rpm")
        # (sign None: the motions as they are, which times +1 they are bit for bit)
        sg = np.ones(len(orders)) if sign is None else sign[pick]
        signed: tuple[np.ndarray, np.ndarray] = (
            (gamma_o, omega_dot)
            if sign is None
            else (sg[:, None] * gamma_o, sg[:, None] * omega_dot)
        )
        args = (
            *signed,
            origin,
            rep("cov_unit"),
            orders,
            rpm,
            cat("force"),
            cat("moment"),
            cat("var"),
        )
        measured = None if stack.frames[0].measured_moment is None else cat("measured_moment")
        model = None
        if self.setup.model_inputs:
            # the model inputs' columns (zero in dm_real: they do not touch the readings)
            if model_motion is not None:
                signed = (
                    model_motion
                    if sign is None
                    else (sg[:, None] * model_motion[0], sg[:, None] * model_motion[1])
                )
            model_args = (self.setup, lin, not self.layout.mass, *signed, origin, orders, rpm)
            if self.compiled:
                fixed = self._constants_at(lin, measured is not None)[1]
                model = kernel_model_input_rows(*model_args, constants=fixed, tables=self._tables)
            else:
                model = model_input_rows(*model_args)
        if self.compiled and not self.layout.mount_scales:
            no_model = np.zeros((len(sg), 12, 0))
            H, y, dr = kernel_rows(
                self.setup, self.layout, lin, *args, measured, dm_real[pick], sg,
                no_model if model is None else model,
                constants=self._constants_at(lin, measured is not None)[0],
            )  # fmt: skip
        else:
            r = frame_rows(self.setup, self.layout, lin, *args, measured_moment=measured)
            H, y = r.H, r.y
            dm = dm_real[pick] if sign is None else sg[:, None, None] * dm_real[pick]
            dr = r.whiten @ r.d_meas @ dm
            if model is not None:
                dr[:, :, -model.shape[2] :] += r.whiten @ model
        if self.cal and calibrate:
            # self-calibration: what was a systematic error becomes an unknown
            H[:, :, self.cal_cols] = dr[:, :, self.cal]
            dr[:, :, self.cal] = 0.0
        return H, y, dr

    def redundancy(self, batch: list[PendingFrame]) -> Redundancy:
        """Self-calibration rows from the rigid fits' redundancy (:mod:`estimator.redundancy`),
        a frame of ``batch`` an entry: H (k, 2r, n_all) on the calibration columns for its
        k pairs, y (k, 2r), the sensitivities to the other systematic errors (k, 2r, n_sys);
        r may differ between frames (a channel lost in some): not stacked. The same under
        both half-order signs: a flipped motion flips the residual and its sensitivity
        alike. (Frames that see only two sensors have no redundancy and give none.)"""
        rows, ys, drs = [], [], []
        for p in batch:
            assert p.redundancy is not None
            # whitened with the variance the frame's rows got
            s = 1.0 / np.sqrt(p.var)
            dr, y = p.redundancy[0] * s[:, None, None], p.redundancy[1] * s[:, None]
            H = np.zeros((*dr.shape[:2], self.layout.size + ELASTIC_TERMS))
            H[:, :, self.cal_cols] = dr[:, :, self.cal]
            dr[:, :, self.cal] = 0.0
            rows.append(H)
            ys.append(y)
            drs.append(dr)
        return rows, ys, drs
