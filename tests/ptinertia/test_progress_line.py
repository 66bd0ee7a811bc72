"""The progress line asks for a running estimate only when it will show one, and ends on
the final estimate (``ptinertia.progress.ProgressLine``; clock injected)."""

from __future__ import annotations

import io
from types import SimpleNamespace
from typing import Any

from estimator.outcome import FrameOutcome
from estimator.result import EstimateUpdate
from ptinertia.progress import ProgressLine


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _estimate(ixx: float) -> Any:
    values = {"Ixx": ixx, "Iyy": 0.1, "Izz": 0.2}
    return SimpleNamespace(value=values.__getitem__, std=lambda name: 0.0, cog=(0.0, 0.0, 0.0))


def _frame(line: ProgressLine, t: float) -> None:
    line.on_frame(None, FrameOutcome(t, 3000.0, (1.0,), {}, None, {}))


def test_a_quiet_line_wants_no_estimate() -> None:
    line = ProgressLine(io.StringIO(), quiet=True, clock=Clock())
    assert not line.wants_estimates()


def test_a_log_line_wants_one_estimate_in_the_second_before_each_rewrite() -> None:
    clock, out = Clock(), io.StringIO()
    line = ProgressLine(out, clock=clock)  # not a terminal: a line every 10 s
    assert line.wants_estimates()  # nothing written yet: the first line is due
    line.on_estimate(EstimateUpdate(0.5, 3000.0, _estimate(1.0)))
    assert not line.wants_estimates()  # it has what it will show
    _frame(line, 1.0)  # due (100 s after the epoch): written, with that estimate
    assert out.getvalue().count("\n") == 1 and "Ixx 1.0000" in out.getvalue()
    for now, wanted in ((100.0, False), (108.9, False), (109.1, True)):
        clock.now = now
        assert line.wants_estimates() is wanted, now


def test_the_last_line_shows_the_final_estimate() -> None:
    clock, out = Clock(), io.StringIO()
    line = ProgressLine(out, clock=clock)
    line.on_estimate(EstimateUpdate(0.5, 3000.0, _estimate(1.0)))
    _frame(line, 1.0)
    clock.now += 1.0
    _frame(line, 2.0)  # not due: not written
    line.close(_estimate(2.5))
    last = out.getvalue().splitlines()[-1]
    assert "t     2.0 s" in last and "Ixx 2.5000" in last


def test_a_log_line_without_a_fresh_estimate_takes_the_next_one() -> None:
    clock, out = Clock(), io.StringIO()
    line = ProgressLine(out, clock=clock)
    line.on_estimate(EstimateUpdate(0.5, 3000.0, _estimate(1.0)))
    _frame(line, 1.0)  # written with it
    clock.now = 110.5
    _frame(line, 2.0)  # the next rewrite, no estimate came in its window: a stale line
    clock.now = 111.0  # far from the next rewrite, yet it wants the next estimate
    assert line.wants_estimates()
    line.on_estimate(EstimateUpdate(2.5, 3000.0, _estimate(2.0)))
    assert not line.wants_estimates()
