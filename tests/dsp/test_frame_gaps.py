"""Lost samples and lost tacho edges cost samples, not frames (dsp.gap_fit, dsp.wheel).

Each check has an independent reference: a least-squares fit by ``numpy.linalg.lstsq``
over the samples present, the signal one cycle earlier, the complete edge list.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from support.tracking import frames_and_events

from acquisition.stream import EdgeBlock
from dsp.config import OrderTrackerConfig
from dsp.gap_fit import NO_HOLES, NO_RECENT, fill_holes, refit, window_weight
from dsp.orders import OrderTracker
from dsp.rejoin import rejoin
from dsp.synthetic import Ramp, SyntheticBench, random_content
from dsp.tacho import TachoConfig
from dsp.wheel import DecoderState, decode_edges


def _signal(phi: np.ndarray, k2: np.ndarray, amps: np.ndarray) -> np.ndarray:
    return np.real(np.exp(1j * np.outer(phi, 0.5 * k2)) @ amps)


def test_refit_is_the_least_squares_fit_over_the_samples_present():
    rng = np.random.default_rng(4)
    k2 = np.arange(1, 9)
    amps = rng.normal(size=k2.size) + 1j * rng.normal(size=k2.size)
    taper = math.radians(45.0)
    lo, hi = 0.0, 4 * math.pi + taper
    phi = np.linspace(lo, hi, 700, endpoint=False)
    q = np.full(phi.size, phi[1] - phi[0])
    x = _signal(phi, k2, amps) + 0.01 * rng.normal(size=phi.size)
    holes = np.zeros(phi.size, bool)
    holes[200:215] = True
    holes[480:490] = True
    w = window_weight(phi, lo, hi, taper)
    big_w = float(np.sum(w * q))
    basis = np.exp(-1j * np.outer(phi, 0.5 * k2))
    sums = 2.0 / big_w * ((w * q * np.where(holes, 0.0, x)) @ basis)
    hole_set = (phi[holes], q[holes], np.zeros(holes.sum(), np.int64), np.ones(holes.sum(), bool))
    got, factor = refit(
        sums[None, None, :], np.array([big_w]), hole_set, np.array([lo]), np.array([hi]),
        k2, np.arange(k2.size), taper,
    )  # fmt: skip
    # the reference: weighted least squares over the samples present, same basis
    keep = ~holes
    design = np.concatenate(
        (np.cos(np.outer(phi, 0.5 * k2)), -np.sin(np.outer(phi, 0.5 * k2))), axis=1
    )[keep]
    sw = np.sqrt((w * q)[keep])
    theta = np.linalg.lstsq(design * sw[:, None], x[keep] * sw, rcond=None)[0]
    ref = theta[: k2.size] + 1j * theta[k2.size :]
    # the window's own orthogonality error is the only difference (as without holes)
    full = 2.0 / big_w * ((w * q * x) @ basis)
    full_ls = np.linalg.lstsq(
        np.concatenate((np.cos(np.outer(phi, 0.5 * k2)), -np.sin(np.outer(phi, 0.5 * k2))), 1)
        * np.sqrt(w * q)[:, None],
        x * np.sqrt(w * q),
        rcond=None,
    )[0]
    ortho = np.abs(full - (full_ls[: k2.size] + 1j * full_ls[k2.size :])).max()
    assert np.abs(got[0, 0] - ref).max() <= 3 * ortho + 1e-12
    assert np.abs(got[0, 0] - amps).max() < 0.01  # and close to the truth
    assert np.abs(sums - amps).max() > 0.05  # the zero-filled sums alone are not
    assert 1.0 < factor[0, 0] < 2.0


def test_missing_samples_are_filled_from_one_cycle_earlier():
    phi = np.arange(3000) * 0.013
    k2 = np.array([1, 3, 6, 9, 13])  # orders beyond any fit's basis too: the cycle repeats
    amps = np.array([1.0, 0.5j, 0.3, -0.2, 0.1 + 0.1j])
    x = _signal(phi, k2, amps)[None, :].repeat(2, axis=0)
    x[1, 2500:2509] = np.nan
    pieces, holes, recent = fill_holes(
        [x[:, :1200], x[:, 1200:]], phi, np.full(phi.size, 0.013), 1.0, NO_HOLES, NO_RECENT
    )
    filled = np.concatenate(pieces, axis=1)
    truth = _signal(phi, k2, amps)
    assert np.abs(filled[1, 2500:2509] - truth[2500:2509]).max() < 2e-3  # linear in angle
    assert holes[2].tolist() == [1] * 9 and not holes[3].any()
    assert recent[0][0] >= phi[-1] - 4 * math.pi - 0.2
    # split into blocks anywhere: the same values
    q = np.full(phi.size, 0.013)
    again, first_holes, kept = fill_holes(
        [x[:, :2400]], phi[:2400], q[:2400], 1.0, NO_HOLES, NO_RECENT
    )
    more, _, _ = fill_holes([x[:, 2400:]], phi[2400:], q[2400:], 1.0, first_holes, kept)
    assert np.array_equal(
        np.concatenate((again[0], more[0]), axis=1)[1, 2500:2509], filled[1, 2500:2509]
    )


def _wheel_times(revs: int) -> np.ndarray:
    """Edge times (s) of a 60-2 wheel speeding up steadily from 1000 rpm."""
    pos = np.array([n for n in range(60 * revs) if n % 60 < 58], dtype=float)
    return pos * 1e-3 - 1e-8 * pos**2


@pytest.mark.parametrize("split", [None, 805])
def test_a_run_of_missing_tacho_edges_is_filled_from_the_neighbouring_teeth(split):
    cfg = TachoConfig(kind="wheel", teeth=60, missing=2)
    t = _wheel_times(30)
    _, ref, _ = decode_edges(DecoderState(), t, cfg)
    kept = np.ones(t.size, bool)
    kept[800:807] = False  # a lost CAN frame of seven edges
    blocks = [t[kept]] if split is None else [t[kept][:split], t[kept][split:]]
    st, knots, events = DecoderState(), [], []
    for block in blocks:
        st, k, ev = decode_edges(st, block, cfg)
        knots.append(k)
        events += ev
    assert [e.kind for e in events] == ["tacho_sync", "tacho_filled"]
    assert events[1].count == 7
    n = np.concatenate([k.n for k in knots])
    t_s = np.concatenate([k.t_s for k in knots])
    assert np.array_equal(n, ref.n)
    # the cubic's slopes are the neighbouring per-pitch intervals, half a pitch off its
    # ends: with t'' = -2e-8 s per pitch^2 each is 1e-8 s/pitch off, which moves the cubic
    # by at most 4/27 of that times the 8 pitches of the hole at each end (2.4e-8 s, a
    # 4e-5 of a pitch); the gap's own edges are exact
    assert np.abs(t_s - ref.t_s).max() <= 2 * 4 / 27 * 8 * 1e-8
    assert np.count_nonzero(t_s != ref.t_s) == 7


def test_a_hole_that_is_no_whole_tooth_count_is_not_filled():
    cfg = TachoConfig(kind="wheel", teeth=60, missing=2)
    t = _wheel_times(30)
    kept = np.ones(t.size, bool)
    kept[800:807] = False
    t = t[kept]
    t[800:] += 0.45e-3  # the hole now spans 8.45 pitches: not a count of teeth
    _, _, events = decode_edges(DecoderState(), t, cfg)
    assert "tacho_filled" not in [e.kind for e in events]
    assert "no_tacho" in [e.kind for e in events]


# -- an outage: the angle re-acquired (dsp.rejoin) -------------------------------------------

TDC = 84.0


def _outage_bench() -> SyntheticBench:
    rng = np.random.default_rng(5)
    return SyntheticBench(
        Ramp(3000.0, 3000.0, 4.0), [random_content(rng) for _ in range(3)], tdc_after_gap_deg=TDC
    )


def _track_all(bench: SyntheticBench, items) -> tuple[list, list]:
    return frames_and_events(bench.layout, items, _config())


def _config() -> OrderTrackerConfig:
    return OrderTrackerConfig(tacho=TachoConfig(tdc_after_gap_deg=TDC), orders=(0.5, 1.0, 1.5, 2.0))


def test_after_a_long_tacho_outage_the_angle_is_reacquired_and_the_gap_reported():
    bench = _outage_bench()
    items = list(bench.items(4.0, block_s=0.1))
    reference, _ = _track_all(bench, items)
    # 0.8 s without edges at 3000 rpm: 40 revolutions, too many to count across
    cut = [
        EdgeBlock(i.channel, i.times_s[(i.times_s < 1.0) | (i.times_s >= 1.8)])
        if isinstance(i, EdgeBlock)
        else i
        for i in items
    ]
    frames, events = _track_all(bench, cut)
    (gap,) = [e for e in events if e.kind == "angle_gap"]
    assert 0.99 < gap.time_s < 1.0 and 1.8 <= gap.end_s < 1.85
    assert "re-acquired" in gap.message
    by_time = {round(f.time_s, 9): f for f in reference}
    after = [f for f in frames if f.time_s > 1.9]
    # (only the frame that overlaps the outage keeps the flag: it has no amplitudes at all)
    assert after and not any("angle_rebased" in f.flags for f in after)
    assert all("no_tacho" in f.flags for f in frames if "angle_rebased" in f.flags)
    settled = [f for f in after if "leakage_uncorrected" not in f.flags]
    assert len(settled) >= len(after) - 4
    for f in settled:
        ref = by_time[round(f.time_s, 9)]
        assert f.crank_angle_rad == ref.crank_angle_rad
        # the same samples, the same angle: the same amplitudes, half orders included
        np.testing.assert_allclose(
            f.amplitudes, ref.amplitudes, rtol=0, atol=1e-9 * np.abs(ref.amplitudes).max()
        )


def test_a_cycle_slipped_across_an_outage_is_turned_back_by_the_half_orders():
    bench = _outage_bench()
    frames, _ = _track_all(bench, bench.items(2.0, block_s=0.1))
    frames = [f for f in frames if not f.flags - {"cycle_ambiguous"}]
    st = OrderTracker.from_layout(bench.layout, _config()).state
    before, later = frames[:20], frames[20:]
    st, out = rejoin(st, before, np.zeros(len(before), np.int64))
    assert out == before  # nothing to re-acquire
    half = np.array([0, 2])  # orders 0.5 and 1.5
    # the same frames as after a re-sync one revolution off: half orders turned by 180 deg
    slipped = []
    for f in later:
        amp = f.amplitudes.copy()
        amp[half] *= -1
        slipped.append(replace(f, amplitudes=amp, crank_angle_rad=f.crank_angle_rad - 2 * np.pi,
                               flags=f.flags | {"angle_rebased"}))  # fmt: skip
    st2, back = rejoin(st, slipped, np.ones(len(slipped), np.int64))
    assert st2.chain_sign == {1: -1}
    for f, ref in zip(back, later, strict=True):
        assert f.flags == ref.flags
        assert f.crank_angle_rad == ref.crank_angle_rad
        assert np.array_equal(f.amplitudes, ref.amplitudes)
    # a cam decided the new chain's cycle: nothing to turn, the angle is good as it is
    decided = [replace(f, flags=frozenset({"angle_rebased"})) for f in later[:3]]
    _, kept = rejoin(st, decided, np.full(3, 2, np.int64))
    assert all(
        not f.flags and f.amplitudes is g.amplitudes for f, g in zip(kept, decided, strict=True)
    )
    # half orders that match neither sign (noise): the frames stay out
    rng = np.random.default_rng(1)
    noise = [
        replace(f, amplitudes=f.amplitudes * np.exp(1j * rng.uniform(0, 6.3, f.amplitudes.shape)),
                flags=f.flags | {"angle_rebased"})
        for f in later[:1]
    ]  # fmt: skip
    st3, unsure = rejoin(st, noise, np.full(1, 3, np.int64))
    assert st3.chain_sign == st.chain_sign and "angle_rebased" in unsure[0].flags
