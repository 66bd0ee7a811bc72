"""A block's frame gates in one loop (``frame_gates.frame_reasons``, ``revolutions``) give
each frame what the per-frame gates give it (``frame_gate``, ``overlaps_previous``,
``revolution``): the same reason, in the same precedence, for every kind of frame."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from estimator.frame_gates import (
    frame_gate,
    frame_reasons,
    overlaps_previous,
    revolution,
    revolutions,
)
from estimator.setup import Gates


@dataclass
class _Frame:
    rpm: float
    rpm_change: float
    flags: frozenset[str] = field(default_factory=frozenset)
    crank_angle_rad: float | None = None


def _frames() -> list[Any]:  # (_Frame: the fields the frame gates read)
    rpms = (2500.0, 700.0, 7000.0, 0.0, -10.0, math.nan, math.inf)
    changes = (0.0, -0.01, 0.2, -0.2)
    flag_sets: tuple[frozenset[str], ...] = (
        frozenset(),
        frozenset({"no_tacho"}),
        frozenset({"angle_rebased", "leakage_uncorrected"}),
        frozenset({"leakage_uncorrected"}),
        frozenset({"cycle_ambiguous"}),
    )
    # angles on and near revolutions (odd ones overlap), none, not finite
    angles = (None, 0.0, 2 * np.pi, 3 * 2 * np.pi, 5.4 * 2 * np.pi, 6.6 * 2 * np.pi, math.nan)
    return [
        _Frame(r, c, f, a) for r, c, f, a in itertools.product(rpms, changes, flag_sets, angles)
    ]


def test_one_loop_gives_each_frame_its_own_gates_verdict() -> None:
    frames = _frames()
    revs = revolutions(frames)
    assert revs == [revolution(f) for f in frames]
    assert set(revs) == {None, 0, 1, 3, 5, 7}
    for gates in (
        Gates(),
        Gates(rpm_range=(1000.0, 6000.0), max_rpm_change=0.1),
        Gates(independent_frames=False),
    ):
        got, got_revs = frame_reasons(frames, gates)
        assert got_revs == revs
        want = [
            "overlapping"
            if gates.independent_frames and overlaps_previous(f)
            else frame_gate(f, gates)
            for f in frames
        ]
        assert got == want
        # every verdict occurs (the test covers each branch)
        reasons = {"no_rpm", "tacho", "dsp_settling", "rpm_unsteady", None}
        assert reasons <= set(got)
        assert ("overlapping" in got) == gates.independent_frames
        assert ("rpm_out_of_range" in got) == (gates.rpm_range != Gates().rpm_range)
