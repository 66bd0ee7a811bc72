"""A block of frames gives the estimator's every decision and every bit of one frame at a time.

Replay, studies and the file sources hand the streaming estimator whole blocks
(``update_many``), a live run one block per acquisition read: what the estimator
remembers of earlier frames (the channel noise, the residual baseline, the
elastic-mode window, the curvature history, the smoothed order noise, the
relinearisations and, with measured weights, the fit geometry they change) must
come out the same whatever the blocks. The frames are those of the simulated i3
through the real dsp, noisy, with self-calibration and measured channel weights
(the paths a block could get out of step on).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from acquisition.stream import SourceEvent
from estimator.channel_noise import ChannelNoise
from estimator.streaming import InertiaEstimator
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.runner import processing_chain
from ptinertia.sources import open_source

I3 = EXAMPLES_DIR / "i3-bench.toml"


@pytest.fixture(scope="module")
def stream() -> tuple[list[object], object, object]:
    bench = load_bench(I3)
    settings = {"self_calibration": True, "channel_weights": "measured"}
    bench = bench.model_copy(update={"estimator": bench.estimator.model_copy(update=settings)})
    source = open_source(
        "sim", bench, accel_rate_hz=5120.0, duration_s=24.0, noise_snr_db=35.0, seed=3
    )
    tracker, _ = processing_chain(bench, source.layout)
    frames: list[object] = []
    for item in source:
        if not isinstance(item, SourceEvent):
            frames += tracker.feed(item)[0]
    frames += tracker.finish()[0]
    return frames, bench, source.layout


def _estimator(bench: object, layout: object) -> InertiaEstimator:
    return processing_chain(bench, layout)[1]  # type: ignore[arg-type]


def test_blocks_of_any_size_give_the_bits_of_one_frame_at_a_time(stream) -> None:
    frames, bench, layout = stream
    single = _estimator(bench, layout)
    one_by_one = [single.update(f) for f in frames]
    assert single.stats.used > 100
    # the measured weights were refreshed within the sweep: a run of frames was refitted
    assert single.channels.generation >= 2
    rng = np.random.default_rng(11)
    blocked = _estimator(bench, layout)
    together = []
    at = 0
    while at < len(frames):
        size = int(rng.choice([1, 2, 7, 25, 60]))
        together += blocked.update_many(frames[at : at + size])
        at += size
        if rng.random() < 0.3:  # a published estimate flushes the queued rows early
            blocked.estimate(final=False)
    assert [(o.reason, o.used_orders, o.rejected) for o in together] == [
        (o.reason, o.used_orders, o.rejected) for o in one_by_one
    ]
    # (the relative residuals to round-off: numpy's sum over a frame's channels may
    # take its elements in another order where the array sits at another alignment,
    # one frame at a time as much as in a block; they only inform the gates)
    for o, ref in zip(together, one_by_one, strict=True):
        assert o.relative_residual.keys() == ref.relative_residual.keys()
        for h, r in ref.relative_residual.items():
            assert o.relative_residual[h] == pytest.approx(r, rel=1e-12, abs=0)
    a, b = single.estimate(), blocked.estimate()
    assert np.array_equal(a.theta, b.theta)
    assert np.array_equal(a.cov, b.cov)
    assert np.array_equal(a.cov_systematic, b.cov_systematic)
    assert a.channel_weights == b.channel_weights


def test_channel_noise_of_a_block_is_that_of_its_frames_one_at_a_time() -> None:
    # revolutions 720 deg apart with a gap (a lost frame breaks the chain), a channel
    # that goes missing for a while, two order sets
    rng = np.random.default_rng(4)
    revs = [*range(0, 40, 2), *range(46, 90, 2)]
    frames = []
    for j, rev in enumerate(revs):
        orders = (1.0, 1.5, 2.0) if j % 9 else (1.0, 2.0)
        x = rng.normal(size=(len(orders), 5)) + 1j * rng.normal(size=(len(orders), 5))
        if 20 <= j < 26:
            x[:, 3] = np.nan
        frames.append((rev, orders, x))
    single, blocked = ChannelNoise(5), ChannelNoise(5)
    after_each = []
    for f in frames:
        single.add(*f)
        after_each.append(single.variance())
    got = []
    at = 0
    while at < len(frames):
        size = int(rng.integers(1, 12))
        got += [v for v, _ in blocked.add_many(frames[at : at + size])]
        at += size
    blocked.release(blocked.estimates)
    assert sum(v is not None for v in after_each) > 20
    for a, b in zip(after_each, got, strict=True):
        assert (a is None and b is None) or np.array_equal(a, b, equal_nan=True)
    assert single.weights() is not None
    assert np.array_equal(single.weights(), blocked.weights())


def test_a_channel_lost_in_some_frames_while_self_calibrating(stream) -> None:
    """A self-calibrating run whose fits see one channel fewer in some frames (a NaN
    amplitude, a channel flagged bad for a span) beside whole frames in one flush: those
    frames give fewer redundancy rows, which used to be stacked with the others' and
    raised; now they are used, and blocks still give the bits of one frame at a time."""
    frames, bench, layout = stream
    hurt = []
    for j, f in enumerate(frames):
        amps, ok = np.array(f.amplitudes), np.array(f.channel_ok)
        if j % 20 == 0:
            amps[1, 4] = np.nan
        if 300 <= j < 340:
            ok[3] = False
        hurt.append(dataclasses.replace(f, amplitudes=amps, channel_ok=ok))
    single = _estimator(bench, layout)
    one_by_one = [single.update(f) for f in hurt]
    blocked = _estimator(bench, layout)
    together = blocked.update_many(hurt)
    lost = [o for j, o in enumerate(one_by_one) if 300 <= j < 340 and o.reason is None]
    assert len(lost) > 10  # frames without channel 3 were used
    assert [(o.reason, o.used_orders) for o in together] == [
        (o.reason, o.used_orders) for o in one_by_one
    ]
    a, b = single.estimate(), blocked.estimate()
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.cov, b.cov)
    assert np.all(np.isfinite(a.theta))
