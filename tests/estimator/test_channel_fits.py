"""The channels a frame's fit uses (estimator/channel_fits.py) whatever the order of the
frame's channels: frames whose channels come in the setup's order (gathered as they are)
and the same frames with their channels shuffled, one of them absent, give the same
usable channels, columns and amplitudes in setup order."""

from __future__ import annotations

import dataclasses

import numpy as np
from support.estimator_harness import Body, frames, make_setup

from estimator.channel_fits import ChannelFits


def test_a_frames_channels_in_any_order_are_screened_alike() -> None:
    body = Body()
    setup = make_setup(body)
    plain = list(frames(body, np.linspace(1500.0, 3000.0, 6)))
    plain[2].channel_ok[4] = False  # flagged bad
    plain[3].amplitudes[1, 7] = np.nan  # not finite in one order
    order = np.array([3, 0, 8, 5, 1, 6, 2, 4])  # ch7 absent
    shuffled = [
        dataclasses.replace(
            f,
            channels=tuple(f.channels[i] for i in order),
            amplitudes=f.amplitudes[:, order],
            channel_ok=f.channel_ok[order].tolist(),  # (a list: taken as bools)
        )
        for f in plain
    ]
    got_plain = ChannelFits(setup)._masks(plain)
    got_shuffled = ChannelFits(setup)._masks(shuffled)
    for (used, cols), (used_s, cols_s), f, g in zip(
        got_plain[0], got_shuffled[0], plain, shuffled, strict=True
    ):
        assert np.array_equal(cols, np.arange(9))
        assert np.array_equal(used_s, used & (np.arange(9) != 7))
        assert np.array_equal(g.amplitudes[:, cols_s[used_s]], f.amplitudes[:, used_s])
    assert got_plain[0][2][0].tolist() == [True] * 4 + [False] + [True] * 4
    assert not got_plain[0][3][0][7] and got_plain[0][0][0].all()
    expected = np.where(got_shuffled[0][0][0], plain[0].amplitudes, np.nan)
    assert np.array_equal(got_shuffled[1][0], expected, equal_nan=True)
    assert np.array_equal(got_plain[1][0], plain[0].amplitudes)
