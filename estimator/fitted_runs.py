"""Runs of frames fitted alike: the streaming estimator's arithmetic for many frames at once.

A block of frames (a replay's chunk, a study's sweep, an acquisition read) holds runs
of consecutive frames with the same usable channels and orders: one rigid-fit
geometry serves the whole run. Everything that does not remember earlier frames is
done here for the whole run in a few array operations (numpy's per-call overhead,
not the arithmetic, is what a frame costs at these sizes): the rigid fits, the
mass-line curvature (which remembers, in stream order, the run's own motions), the
excitation, the noise levels and the order gates that remember nothing. The gates
that remember, the queue and the relinearisations stay frame by frame in
:meth:`estimator.streaming.InertiaEstimator.update_many`.

Every array operation here treats each frame alone (elementwise, or one matrix
product per frame): a frame gets the same bits in a run of one as in a run of fifty.

What the queue and the residual gate take of a run's frames is made here once per run
as Python lists (:class:`FittedRun`), and a block's revolutions once
(:func:`estimator.frame_gates.frame_reasons`). Measured (issue 24; the estimator stage
alone on the 60 s log's blocks, ``stage_prof.py est``, CPU best of 5, runs alternating
with main's, load 2.3-5.7): compiled 0.067-0.075 s a minute on main, 0.063-0.065 s with
these per-run lists and the per-frame calls they spare (3-9 ms less, median 6); numpy
0.131-0.133 s, 0.125-0.128 s; the same bits on both paths.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from estimator import row_kernels
from estimator.compiled_runs import fitted_arrays
from estimator.frame_gates import FrameLike
from estimator.gating import OrderGates
from estimator.kinematics import RigidFit, RigidMotion
from estimator.rigidity import excess_many, noise_levels_many
from estimator.setup import EstimatorSetup


class Screened(NamedTuple):
    """A gated frame with its channels screened (:meth:`estimator.channel_fits.ChannelFits.screen`)."""

    position: int  # its position in the block
    used: np.ndarray  # (n_setup,) bool, the usable setup channels
    cols: np.ndarray  # (n_setup,) their columns in the frame
    variance: Any  # the channel noise variance after the frame (n_setup,), or None
    estimates: int  # the channel noise's estimate count after the frame
    steps: np.ndarray | None = (
        None  # the used channels' variance steps (ChannelFits.variance_steps)
    )


def run_end(frames: Sequence[FrameLike], todo: list[Screened], at: int) -> int:
    """The end of the run starting at ``todo[at]``: the frames after it with the same
    usable channels, variance steps (the same fit geometry) and orders."""
    first = todo[at]
    used_row, steps = first.used, first.steps
    used = used_row.tobytes()
    orders = frames[first.position].orders
    steps_bytes = None if steps is None else steps.tobytes()
    end, n = at + 1, len(todo)
    # (the first frame's key once, each later frame's compared part by part)
    while end < n:
        s = todo[end]
        if s.used is not used_row and s.used.tobytes() != used:  # (frames of a block share it)
            break
        more = s.steps
        if (more is None) != (steps_bytes is None) or (
            more is not None and more.tobytes() != steps_bytes
        ):
            break
        o = frames[s.position].orders
        if o is not orders and tuple(o) != tuple(orders):
            break
        end += 1
    return end


# FittedRun.queued: half, readings, power sum, force, moment, floor, gas of a frame
Queued = tuple[
    np.ndarray, np.ndarray, float, np.ndarray, np.ndarray, list[float], np.ndarray | None
]


@dataclass(frozen=True)
class FittedRun:
    """A run's fits and what the gates that remember nothing make of them; the arrays'
    leading axes are (frame, order)."""

    index: list[int]  # the frames' positions in the block
    orders: np.ndarray  # (k,)
    readings: np.ndarray  # (n, k, u) complex, the fitted channels' amplitudes, m/s^2
    motions: list[RigidMotion]
    power: np.ndarray  # (n, k) the readings' mean square per order, (m/s^2)^2
    force: np.ndarray  # (n, k, 3) complex, the excitation force, N
    moment: np.ndarray  # (n, k, 3) complex, the excitation moment with the gas's, N m
    gas: list[np.ndarray | None]  # (k, 3) the measured gas moment; None without pressure
    why: np.ndarray  # (n, k) int, OrderGates.screen_orders
    floor: np.ndarray  # (n, k) the dsp's error floor near a mode, (m/s^2)^2
    relative: np.ndarray  # (n, k) the relative rigidity residual
    share: np.ndarray  # (n, k) that less the channel noise's mean
    beyond: np.ndarray  # (n, k) that beyond the channel noise's quantile
    # set in __post_init__ (per run): the orders as Python floats (a list and a tuple,
    # which the frames' outcomes share), the rows of ``why``, ``relative``, ``share``,
    # ``beyond`` as the residual gate takes them (:meth:`estimator.gating.OrderGates.judge`)
    order_list: list[float] = field(init=False, repr=False)
    order_key: tuple[float, ...] = field(init=False, repr=False)
    gate_lists: tuple[list[Any], ...] = field(init=False, repr=False)
    # what the queue takes of each frame (:meth:`queued`), as per-frame lists
    queue_rows: tuple[list[Any], ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        # per run, not per frame: the rows the residual gate and the queue take as Python
        # numbers (made here: a cached_property's first look-up costs more, one run per
        # frame when frames come one at a time)
        lists = (
            self.why.tolist(), self.relative.tolist(), self.share.tolist(),
            self.beyond.tolist(),
        )  # fmt: skip
        object.__setattr__(self, "gate_lists", lists)
        object.__setattr__(self, "order_list", self.orders.tolist())
        object.__setattr__(self, "order_key", tuple(self.order_list))
        # each frame's readings, power summed over its orders (the bits of a frame's own
        # sum: one reduction per row), force, moment, floor (a list) and gas: the rows
        # taken once per run (an array's rows by iterating it: the views indexing makes)
        rows = (
            list(self.readings), np.add.reduce(self.power, axis=1).tolist(), list(self.force),
            list(self.moment), self.floor.tolist(), self.gas,
        )  # fmt: skip
        object.__setattr__(self, "queue_rows", rows)

    def queued(self, j: int, cycle_unknown: bool) -> Queued:
        """Frame ``j``'s half orders of unknown sign (``cycle_unknown``: the run's frames
        have no 720 deg reference), readings, power, force, moment, floor (a list) and gas,
        as :meth:`estimator.pending_rows.FrameQueue.add` takes them (the streaming
        estimator reads them from ``queue_rows`` and :func:`half_orders` directly)."""
        readings, power, force, moment, floor, gas = self.queue_rows
        return (
            half_orders(self.order_key, cycle_unknown), readings[j], power[j], force[j],
            moment[j], floor[j], gas[j],
        )  # fmt: skip


@functools.lru_cache(maxsize=32)
def half_orders(orders: tuple[float, ...], unknown: bool) -> np.ndarray:
    """(k,) bool: the half orders among ``orders`` when the cycle is ``unknown``, else
    none (read-only: every frame with these orders shares it)."""
    half = ((2 * np.array(orders)) % 2 == 1) & unknown
    half.flags.writeable = False
    return half


def fit_run(
    setup: EstimatorSetup,
    gates: OrderGates,
    fit: RigidFit,
    frames: Sequence[FrameLike],
    run: list[Screened],
    revs: list[int | None] | None = None,
) -> FittedRun:
    """Fit a run of screened frames with ``fit`` and apply the gates that remember
    nothing (the curvature gate's history takes the run's motions); ``revs``: the
    block's :func:`estimator.frame_gates.revolutions`, when at hand."""
    index = [s.position for s in run]
    run_frames = [frames[i] for i in index]
    orders = np.asarray(run_frames[0].orders, dtype=float)
    if row_kernels.USE:  # PTINERTIA_NUMBA=1: the gather, fit and power in one loop
        first = run[0]
        if all(s.cols is first.cols for s in run):
            amps, columns = np.array([f.amplitudes for f in run_frames]), first.cols[first.used]
        else:  # (frames of other channel tuples: gathered frame by frame)
            amps = run_readings(run_frames, run)
            columns = np.arange(amps.shape[2])
        readings, x, residual_rms, relative, noise_var, power = fitted_arrays(fit, amps, columns)
    else:
        readings = run_readings(run_frames, run)
        x, residual_rms, relative, noise_var = fit.fit_arrays(readings)
        # np.mean's sum and division without its wrapper's checks (the same bits)
        power = np.add.reduce(readings.real**2 + readings.imag**2, axis=2) / readings.shape[2]
    motions = fit.motions(x, residual_rms, relative, noise_var)
    run_revs = None if revs is None else [revs[i] for i in index]
    bends = gates.curvature(run_frames, orders, motions, fit, (x[:, :, 3:], noise_var), run_revs)
    rpm_list = [f.rpm for f in run_frames]
    rpm = np.array(rpm_list, dtype=float)
    force, moment = run_excitation(setup, rpm_list, orders)
    gas, at, stack = gas_moments(setup, run_frames, orders)
    if stack is not None:  # the measured gas moments as one array: one sum
        if len(at) == len(gas):
            moment = moment + stack
        else:
            moment[at] = moment[at] + stack
    else:
        for j, g in enumerate(gas):
            if g is not None:
                moment[j] = moment[j] + g
    why, floor = gates.screen_orders(rpm, orders, force, moment, bends, power, relative, fit)
    mean, q = noise_levels_many(fit, [s.variance for s in run])
    share, beyond = excess_many(relative, noise_var, fit, mean, q)
    return FittedRun(
        index, orders, readings, motions, power, force, moment, gas, why, floor,
        relative, share, beyond,
    )  # fmt: skip


def run_readings(frames: list[FrameLike], run: list[Screened]) -> np.ndarray:
    """(n, k, u) complex: the used channels' amplitudes of a run's frames, m/s^2, laid out
    in memory as each frame's gathered alone and stacked: channel-major per frame. The
    numpy fit's sums take their order from that layout (a gather of the whole run at once
    lays the channels out otherwise and moved the relative residual by an ulp), so where
    the frames share their columns (one channel tuple) and are C-ordered, one gather and
    one copy into that layout; else frame by frame."""
    first = run[0]
    k = np.shape(frames[0].amplitudes)[0]
    if (
        k > 1
        and all(s.cols is first.cols for s in run)
        and all(f.amplitudes.flags.c_contiguous for f in frames)
    ):
        gathered = np.array([f.amplitudes for f in frames])[:, :, first.cols[first.used]]
        return gathered.transpose(0, 2, 1).copy().transpose(0, 2, 1)
    return np.stack([f.amplitudes[:, s.cols[s.used]] for f, s in zip(frames, run, strict=True)])


def run_excitation(
    setup: EstimatorSetup, rpm: list[float], orders: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The known excitation force and moment (n, k, 3) of a run's frames at their
    crank speeds ``rpm``: in one call where the setup's excitation offers it."""
    many = getattr(setup.excitation, "many", None)
    if many is not None:
        force, moment = many(rpm, orders)
        return force, moment
    excitation = [setup.excitation(r, orders) for r in rpm]
    return np.stack([f for f, _ in excitation]), np.stack([m for _, m in excitation])


def gas_moments(
    setup: EstimatorSetup, frames: list[FrameLike], orders: np.ndarray
) -> tuple[list[np.ndarray | None], list[int], np.ndarray | None]:
    """The measured gas moment (k, 3) of each of a run's frames, None for a frame
    without a finite pressure spectrum (or without a pressure channel at all); and where
    the setup's gas moment has ``many``, the frames that have one and their moments as
    one (m, k, 3) array (the same rows), else ``[]`` and None."""
    gas: list[np.ndarray | None] = [None] * len(frames)
    if setup.gas_moment is None:
        return gas, [], None
    given: list[tuple[int, np.ndarray]] = [
        (j, p) for j, f in enumerate(frames) if (p := getattr(f, "spectrum", None)) is not None
    ]
    many = getattr(setup.gas_moment, "many", None)
    # (an array's own shape: np.shape's dispatch costs more, once per frame)
    shapes = {p.shape if isinstance(p, np.ndarray) else np.shape(p) for _, p in given}
    if many is not None and len(shapes) == 1 and len(next(iter(shapes))) == 1:
        stack = np.array([p for _, p in given])  # (m, n_half): a frame's pressure orders
        with np.errstate(over="ignore", invalid="ignore"):  # (finite sums to inf: the test below)
            total = complex(np.add.reduce(stack, axis=None))
        if math.isfinite(total.real) and math.isfinite(total.imag):
            # (a NaN or an infinity anywhere makes the sum one: every spectrum finite,
            # the common case, in one reduction)
            finite, at = None, [j for j, _ in given]
        else:
            finite = np.logical_and.reduce(np.isfinite(stack), axis=1)  # (.all, no wrapper)
            at = [j for (j, _), ok in zip(given, finite.tolist(), strict=True) if ok]
        if not at:
            return gas, [], None
        moments = many(orders, stack if len(at) == len(given) else stack[finite])
        if len(at) == len(gas):  # (every frame's: its rows as they are)
            return list(moments), at, moments
        for j, g in zip(at, moments, strict=True):
            gas[j] = g
        return gas, at, moments
    for j, p in given:
        if np.isfinite(p).all():
            gas[j] = setup.gas_moment(orders, p)
    return gas, [], None
