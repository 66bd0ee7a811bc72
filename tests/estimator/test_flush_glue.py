"""The flush's glue (estimator/pending_rows.FrameStack, MisfitSample.add_frames, the
compiled rows' constants kept per linearisation) against what it replaced: the
concatenations per call, the per-frame misfit adds, the constants made per call.
Each must give the same bits."""

from __future__ import annotations

import dataclasses
import itertools
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from support.estimator_harness import Body, SplitExcitation, frames, make_setup

from estimator import compiled_model_rows, compiled_rows, row_kernels
from estimator.equations import Linearisation
from estimator.frame_stack import FrameStack, PendingFrame
from estimator.misfit import MisfitSample
from estimator.pending_rows import RowAssembler
from estimator.setup import ModelInput
from estimator.streaming import InertiaEstimator
from estimator.systematic import motion_sensitivity, sensor_blocks

NUMBA = pytest.mark.skipif(not row_kernels.AVAILABLE, reason="numba not installed")


def _queued(compiled: bool, **setup_kw: object) -> InertiaEstimator:
    """An estimator with used frames queued (not flushed), under their linearisation."""
    body = Body(unbalance=4e-4 * np.exp(-1j * 0.7))
    est = InertiaEstimator(dataclasses.replace(make_setup(body), **setup_kw))
    est.rows.compiled = compiled
    rng = np.random.default_rng(3)
    data = [
        dataclasses.replace(f, amplitudes=f.amplitudes * (1 + 0.01 * rng.normal(size=(3, 9))))
        for f in frames(body, np.linspace(1500.0, 3500.0, 30))
    ]
    est.update_many(data)
    assert len(est.queue.frames) >= 5
    return est


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
def test_stacked_frames_give_the_rows_of_the_frame_list(compiled: bool) -> None:
    est = _queued(compiled)
    batch = est.queue.frames
    stack = FrameStack(batch)
    # the per-pair arrays as concatenated and repeated per call before
    assert np.array_equal(stack.bounds, np.cumsum([0] + [len(p.orders) for p in batch]))
    rpm = np.repeat([p.rpm for p in batch], [len(p.orders) for p in batch])
    assert np.array_equal(stack.f_hz, np.concatenate([p.orders for p in batch]) * rpm / 60.0)
    # a fit's shared origin and cov_unit (one broadcast copy), and the same batch with
    # every frame's arrays its own (np.repeat): both np.repeat's array, dtype and shape
    counts = [len(p.orders) for p in batch]
    own = FrameStack([p._replace(origin=p.origin.copy()) for p in batch])
    for name in ("origin", "cov_unit"):
        want = np.repeat(np.array([getattr(p, name) for p in batch]), counts, axis=0)
        for s in (stack, own):
            got = s.per_pair(name)
            assert got.dtype == want.dtype and np.array_equal(got, want)
    dm = est.rows.sensitivity(batch)
    assert np.array_equal(est.rows.sensitivity(stack), dm)
    n_p = len(dm)
    sign = np.where(np.arange(n_p) % 3 == 1, -1.0, 1.0)
    some = np.arange(n_p) % 2 == 0
    for sel in (np.ones(n_p, bool), some):
        want = est.rows.rows(list(batch), sign, sel, dm, est.lin)
        # twice from one stack: the shared arrays are not written by the first call
        for _ in range(2):
            got = est.rows.rows(stack, sign, sel, dm, est.lin)
            for g, w in zip(got, want, strict=True):
                assert np.array_equal(g, w)
    # every pair (sel None) and the motions as measured (sign None): the bits of
    # selecting every pair and multiplying by +1
    want = est.rows.rows(stack, np.ones(n_p), np.ones(n_p, bool), dm, est.lin)
    got = est.rows.rows(stack, None, None, dm, est.lin)
    for g, w in zip(got, want, strict=True):
        assert np.array_equal(g, w)


def test_sensitivity_of_a_batch_fitted_with_fits_of_other_widths() -> None:
    """Frames of two fits reading 3 and 5 channels: one motion sensitivity per run of a
    fit, in stream order (their amplitudes cannot be stacked into one array)."""
    rng = np.random.default_rng(8)
    setup = SimpleNamespace(
        channels=[f"c{i}" for i in range(6)],
        n_sensors=3,
        model_inputs=[],
        sensor_of_channel=np.array([0, 0, 1, 1, 2, 2]),
        positions=rng.normal(size=(6, 3)),
        directions=rng.normal(size=(6, 3)),
    )
    fits = [
        SimpleNamespace(
            channels=np.array(ch), origin=rng.normal(size=3), gain=rng.normal(size=(6, len(ch)))
        )
        for ch in ([0, 2, 4], [0, 1, 2, 3, 5])
    ]

    def frame(fit: SimpleNamespace, k: int) -> PendingFrame:
        c = lambda *s: rng.normal(size=s) + 1j * rng.normal(size=s)  # noqa: E731
        u = len(fit.channels)
        # (a queued frame with only what the sensitivity reads)
        unread: dict[str, Any] = dict.fromkeys(PendingFrame._fields)
        return PendingFrame(
            **unread
            | dict(
                fit=fit, orders=np.ones(k), gamma_o=c(k, 3), omega_dot=c(k, 3), amplitudes=c(k, u)
            )
        )

    batch = [frame(fits[i], k) for i, k in ((0, 3), (0, 2), (1, 3), (1, 1), (0, 3))]
    rows = RowAssembler(setup, None, [], [])  # type: ignore[arg-type]
    for compiled in (False, True) if row_kernels.AVAILABLE else (False,):
        rows.compiled = compiled
        got = rows.sensitivity(FrameStack(batch))
        want = np.concatenate(
            [
                motion_sensitivity(
                    setup,  # type: ignore[arg-type]
                    p.fit,
                    p.amplitudes,
                    p.gamma_o,
                    p.omega_dot,
                    sensor_blocks(setup, p.fit),  # type: ignore[arg-type]
                )
                for p in batch
            ]
        )
        assert np.array_equal(got, want)


def test_misfit_sample_of_consecutive_frames_is_the_per_frame_sample() -> None:
    """Past the sample's capacity (it thins): the same frames kept, the same bits."""
    rng = np.random.default_rng(1)
    sizes = rng.integers(1, 4, 300)
    bounds = np.cumsum([0, *sizes])
    orders = rng.choice([0.5, 1.0, 1.5, 2.0], bounds[-1])
    H, y = rng.normal(size=(bounds[-1], 12, 6)), rng.normal(size=(bounds[-1], 12))
    each, batched = MisfitSample(), MisfitSample()
    for a, b in itertools.pairwise(bounds):
        each.add_frames(1, orders[a:b], H[a:b], y[a:b], np.array([0, b - a]))  # one frame
    for a, b in itertools.pairwise([0, 40, 41, 190, 300]):
        # blocks of frames, bounds from the block's first pair
        at = bounds[a : b + 1]
        batched.add_frames(1, orders[at[0] :], H[at[0] :], y[at[0] :], at - at[0])
    want, got = each._rows[1], batched._rows[1]
    assert (got._seen, got._stride) == (want._seen, want._stride) == (300, 4)
    assert len(got.items) == len(want.items) > 0
    for g, w in zip(got.items, want.items, strict=True):
        for a, b in zip(g, w, strict=True):
            assert np.array_equal(a, b) and a.flags.owndata  # copies, not views of the batch


# inputs whose constants are kept: a spin inertia and a mount's stiffness; an excitation
# input whose tables are kept (SplitExcitation offers them)
MODEL_INPUTS = (
    ModelInput("spin_inertia", "spin_inertia", 0.01),
    ModelInput("mount:m1", "mount", 0.15, mount=1),
    ModelInput("exc", "excitation", 0.05, d_excitation=SplitExcitation()),
)


@pytest.mark.parametrize("mass_known", [True, False])
@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=NUMBA)])
def test_kept_row_constants_are_the_ones_made_per_call(compiled: bool, mass_known: bool) -> None:
    """The compiled rows' constants kept by the assembler: the same as made per call,
    made anew when the linearisation (its mass too, when the mass is estimated) changes,
    and (compiled) the same rows as a fresh assembler's."""
    est = _queued(compiled, model_inputs=MODEL_INPUTS, mass_known=mass_known)
    assert bool(est.layout.mass) is not mass_known
    setup, layout = est.setup, est.layout
    lin = est.lin
    other = Linearisation(cog=lin.cog + 0.002, inertia=lin.inertia * 1.01, mass=lin.mass * 1.1)

    def made(x: Linearisation) -> tuple:
        return (
            compiled_rows.row_constants(setup, layout, x, False),
            compiled_model_rows.model_constants(setup, x, not layout.mass),
        )

    batch = est.queue.frames
    dm = est.rows.sensitivity(batch)
    ones, every = np.ones(len(dm)), np.ones(len(dm), bool)
    for x in (lin, other, lin):
        for got, want in zip(est.rows._constants_at(x, False), made(x), strict=True):
            for a, b in zip(got, want, strict=True):
                assert np.array_equal(a, b)
        fresh = RowAssembler(setup, layout, est.rows.cal, est.rows.cal_cols)
        fresh.compiled = compiled
        for a, b in zip(
            est.rows.rows(batch, ones, every, dm, x),
            fresh.rows(batch, ones, every, dm, x),
            strict=True,
        ):
            assert np.array_equal(a, b)
    assert est.rows._constants_at(other, False) is est.rows._constants_at(other, False)
    # measured gas moment: its column flag
    assert est.rows._constants_at(other, True)[0][-1][-1] == 1


def test_stacked_noise_variances_are_the_per_frame_arrays_concatenated() -> None:
    """FrameStack.cat('var') turns the queue's lists of floats into the flush's array in one
    go: the bits of np.array(var) per frame, concatenated (NaN, -0.0, a subnormal, an
    infinity, a frame without pairs, numpy scalars beside Python floats)."""
    lists = [
        [1.5, np.float64(2.25), -0.0],
        [],
        [float("nan"), 5e-324, float("inf")],
        [np.float64(1e-300)],
    ]
    blank = dict.fromkeys(PendingFrame._fields)
    stack = FrameStack([PendingFrame(**{**blank, "orders": v, "var": v}) for v in lists])
    want = np.concatenate([np.array(v, dtype=float) for v in lists])
    got = stack.cat("var")
    assert got.dtype == want.dtype == np.float64
    assert got.tobytes() == want.tobytes()


def test_finite_pressure_spectra_whose_sum_overflows_keep_every_frame() -> None:
    """gas_moments checks every spectrum finite by one sum; finite spectra whose sum
    overflows take the row-by-row test, keep every frame, and raise no floating-point
    warning; a NaN or an infinity drops its frame only."""
    from estimator.fitted_runs import gas_moments

    class Gas:
        def __call__(self, orders, p):
            return np.zeros((len(orders), 3), complex)

        def many(self, orders, stack):
            return np.zeros((len(stack), len(orders), 3), complex)

    setup = SimpleNamespace(gas_moment=Gas())
    big = [SimpleNamespace(spectrum=np.full(3, 1e308 + 0j)) for _ in range(3)]
    bad = np.array([np.nan, 1.0, 1.0], complex)
    with np.errstate(all="raise"):
        assert gas_moments(setup, big, np.array([1.0]))[1] == [0, 1, 2]
        mixed = [*big[:2], SimpleNamespace(spectrum=bad)]
        assert gas_moments(setup, mixed, np.array([1.0]))[1] == [0, 1]
