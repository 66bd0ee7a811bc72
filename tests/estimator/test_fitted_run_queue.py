"""What a fitted run hands the frame queue per frame (``FittedRun.queued``): the half-order
masks and power sums it makes once per run are each frame's own; and its fits are those
of each frame alone."""

from __future__ import annotations

from typing import cast

import numpy as np
import pytest
from support.estimator_harness import Body, frames, make_setup

from estimator import row_kernels
from estimator.channel_fits import ChannelFits
from estimator.fitted_runs import FittedRun, Screened, fit_run, run_end, run_readings
from estimator.gating import OrderGates
from estimator.pending_rows import FrameQueue
from estimator.setup import EstimatorSetup


def _run(orders: list[float], n: int, seed: int) -> FittedRun:
    rng = np.random.default_rng(seed)
    k = len(orders)
    power = rng.lognormal(size=(n, k)) * 10.0 ** rng.integers(-8, 3, size=(n, 1))
    cplx = rng.normal(size=(n, k, 3)) + 1j * rng.normal(size=(n, k, 3))
    real = rng.normal(size=(n, k))
    return FittedRun(
        list(range(n)), np.array(orders), rng.normal(size=(n, k, 9)) + 0j, [], power,
        cplx, cplx, [None] * n, np.zeros((n, k), int), real, real, real, real,
    )  # fmt: skip


@pytest.mark.parametrize("orders", [[1.0, 1.5, 2.0], [0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.5, 6.0, 7.5]])
def test_each_frame_gets_its_own_half_orders_and_power_sum(orders: list[float]) -> None:
    run = _run(orders, 23, seed=len(orders))
    h = np.array(orders)
    for j in range(23):
        for unknown in (False, True):
            half, readings, power_sum, *_ = run.queued(j, unknown)
            assert np.array_equal(half, ((2 * h) % 2 == 1) & unknown)
            assert np.array_equal(readings, run.readings[j])
            # the frame's own sum, bit for bit (np.mean's sum of a frame's orders)
            assert power_sum == float(np.add.reduce(run.power[j]))
    # the masks are shared by the run's frames: nobody may change them
    half = run.queued(0, True)[0]
    assert half.any() and not half.all()
    with pytest.raises(ValueError):
        half[0] = not half[0]


def test_queued_noise_variance_is_the_smoothed_one_floored_as_np_maximum_floors_it() -> None:
    """FrameQueue._noise_var floors the smoothed variance by the dsp's in plain floats:
    np.maximum's values, NaN wherever either side is NaN."""
    queue = FrameQueue(cast(EstimatorSetup, None), [])
    orders = np.array([1.0, 1.5, 2.0, 3.0])
    rng = np.random.default_rng(4)
    for frame in range(6):
        raw = rng.lognormal(size=4) * 1e-6
        dsp = rng.lognormal(size=4) * 1e-6
        dsp[frame % 4] = raw[frame % 4] = 3e-7  # (a tie)
        if frame == 4:
            dsp[1] = np.nan
        if frame == 5:
            raw[3] = np.nan  # (a NaN smoothed variance)
        ks = [0, 1, 3] if frame % 2 else [0, 1, 2, 3]
        before = dict(queue.noise_var)
        got = queue._noise_var(raw, ks, orders, 1e-12, dsp)
        smoothed = [
            0.8 * before[h] + 0.2 * raw[k] if h in before else raw[k]
            for k, h in zip(ks, orders[ks].tolist(), strict=True)
        ]
        want = np.maximum(np.maximum(smoothed, 1e-12), dsp[ks])
        assert np.array_equal(np.array(got), want, equal_nan=True)
        assert np.isnan(got[1]) == (frame == 4) and np.isnan(got[-1]) == (frame == 5)


def test_a_runs_fits_are_its_frames_fitted_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    # the numpy path: a run's readings, motions and power are those of its frames fitted
    # as runs of one (live) and RigidFit.fit's of each frame, bit for bit; the relative
    # residual within rounding (RigidFit.fit_arrays copies a stack of frames to sum the
    # channels' power, where a frame's is a view, and numpy's sums take another order)
    monkeypatch.setattr(row_kernels, "USE", False)
    body = Body()
    setup = make_setup(body)
    data = list(frames(body, np.linspace(1500.0, 4000.0, 14)))
    channels = ChannelFits(setup)
    run = [Screened(i, *s) for i, s in enumerate(channels.screen(data))]
    assert run_end(data, run, 0) == len(run)
    reason, fit = channels.choose(run[0].used, run[0].steps)
    assert reason is None and fit is not None
    r = fit_run(setup, OrderGates(setup), fit, data, run)
    for j, (f, s) in enumerate(zip(data, run, strict=True)):
        alone = fit_run(setup, OrderGates(setup), fit, [f], [s._replace(position=0)])
        assert np.array_equal(r.readings[j], alone.readings[0])
        assert np.array_equal(r.power[j], alone.power[0])
        for name in ("gamma_o", "omega_dot", "residual_rms", "noise_var"):
            assert np.array_equal(getattr(r.motions[j], name), getattr(alone.motions[0], name))
        rel, rel_alone = r.motions[j].relative_residual, alone.motions[0].relative_residual
        np.testing.assert_allclose(rel, rel_alone, rtol=1e-14, atol=0)
        own = f.amplitudes[:, s.cols[s.used]]
        one = fit.fit(own)
        assert np.array_equal(r.readings[j], own)
        for name in ("gamma_o", "omega_dot", "residual_rms", "noise_var"):
            assert np.array_equal(getattr(r.motions[j], name), getattr(one, name)), name
        assert np.array_equal(alone.motions[0].relative_residual, one.relative_residual)
        assert r.power[j] == pytest.approx(np.mean(abs(own) ** 2, axis=1), rel=1e-14)


def test_a_runs_readings_are_laid_out_as_its_frames_gathered_alone() -> None:
    # the numpy fit's sums take their order from the memory layout: a run's readings
    # must be the frames' own gathers stacked, in values and in strides
    body = Body()
    setup = make_setup(body)
    for orders in ((1.0, 1.5, 2.0), (1.0, 2.0), (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)):
        data = list(frames(body, np.linspace(1500.0, 4000.0, 9), orders=orders))
        data[4].channel_ok[6] = False  # (its own run: another channel set)
        run = [Screened(i, *s) for i, s in enumerate(ChannelFits(setup).screen(data))]
        for part in (run[:4], run[5:]):
            got = run_readings([data[s.position] for s in part], part)
            want = np.stack([data[s.position].amplitudes[:, s.cols[s.used]] for s in part])
            assert np.array_equal(got, want) and got.strides == want.strides


def test_a_run_ends_where_the_channels_steps_or_orders_change() -> None:
    # run_end compares each frame's usable channels, variance steps and orders with the
    # run's first frame part by part: the runs of comparing the three as one key
    class _F:
        def __init__(self, orders: tuple[float, ...]) -> None:
            self.orders = orders

    used = np.ones(9, bool)
    fewer = used.copy()
    fewer[4] = False
    steps = np.zeros(9, np.int64)
    steps[2] = 3
    other_steps = steps.copy()
    other_steps[2] = 4
    kinds = [
        (used, None, (1.0, 1.5, 2.0)),
        (used.copy(), None, (1.0, 1.5, 2.0)),  # (equal, not the same arrays and tuples)
        (fewer, None, (1.0, 1.5, 2.0)),
        (used, steps, (1.0, 1.5, 2.0)),
        (used, steps.copy(), (1.0, 1.5, 2.0)),
        (used, other_steps, (1.0, 1.5, 2.0)),
        (used, None, (1.0, 2.0, 3.0)),
    ]
    rng = np.random.default_rng(7)
    picks = rng.integers(0, len(kinds), 60)
    picks[10:14] = 0  # (runs of several frames)
    data = [_F(tuple(kinds[p][2])) for p in picks]
    todo = [
        Screened(j, kinds[p][0], np.arange(9), None, 0, kinds[p][1]) for j, p in enumerate(picks)
    ]

    def key(s: Screened) -> tuple[bytes, bytes, tuple[float, ...]]:
        return (
            s.used.tobytes(),
            b"" if s.steps is None else s.steps.tobytes(),
            tuple(data[s.position].orders),
        )

    ends = []
    for at in range(len(todo)):
        want = at + 1
        while want < len(todo) and key(todo[want]) == key(todo[at]):
            want += 1
        assert run_end(data, todo, at) == want
        ends.append(want - at)
    assert max(ends) >= 4 and min(ends) == 1
