"""The states and solutions one estimate shares (estimator.solve_memo) give every published
estimate the bits of solving each anew, and are not kept from one estimate to the next."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.stream import SourceEvent
from estimator import solve_memo
from estimator.solve_memo import SolveMemo
from estimator.streaming import InertiaEstimator
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.runner import processing_chain
from ptinertia.sources import REALISTIC_SIMULATION, open_source


class Anew(SolveMemo):
    """Keeps nothing: every state and solution made anew (the reference)."""

    @property
    def kept(self) -> None:
        return None

    @kept.setter
    def kept(self, value: object) -> None:
        pass


def _estimators() -> tuple[list[object], InertiaEstimator, InertiaEstimator]:
    bench = load_bench(EXAMPLES_DIR / "i3-bench.toml")  # no phase reference: sign undecided
    sim = dict(REALISTIC_SIMULATION, seed=0, accel_rate_hz=5120.0, duration_s=8.0)
    source = open_source("sim", bench, **sim)
    tracker, memo = processing_chain(bench, source.layout)
    frames: list[object] = []
    for item in source:
        if not isinstance(item, SourceEvent):
            frames += tracker.feed(item)[0]
    frames += tracker.finish()[0]
    anew = processing_chain(bench, source.layout)[1]
    anew.memo = Anew(anew.memo.n, anew.memo.scale, anew.memo.anchored)
    return frames, memo, anew


def test_published_estimates_are_those_solved_anew(monkeypatch: pytest.MonkeyPatch) -> None:
    frames, memo, anew = _estimators()
    solves = {"memo": 0, "anew": 0}
    counting = "memo"
    rls_solve = solve_memo.rls_solve

    def counted(*args: object, **kwargs: object) -> object:
        solves[counting] += 1
        return rls_solve(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(solve_memo, "rls_solve", counted)
    rng = np.random.default_rng(2)
    undecided = 0
    for at in range(0, len(frames), 7):
        block = frames[at : at + 7]
        counting = "memo"
        memo.update_many(block)  # type: ignore[arg-type]
        counting = "anew"
        anew.update_many(block)  # type: ignore[arg-type]
        if rng.random() < 0.5:
            counting = "memo"
            a = memo.estimate(final=False)
            counting = "anew"
            b = anew.estimate(final=False)
            for field in ("theta", "cov", "cov_systematic", "observable"):
                assert np.array_equal(getattr(a, field), getattr(b, field)), field
            assert a.half_order == b.half_order and a.variance_factor == b.variance_factor
            undecided += a.half_order is not None and memo.decided_sign is None
    a, b = memo.estimate(), anew.estimate()
    assert np.array_equal(a.theta, b.theta) and np.array_equal(a.cov, b.cov)
    assert undecided >= 5  # the estimates the memo is for: both signs carried
    assert solves["memo"] < 0.7 * solves["anew"]  # and it was used
