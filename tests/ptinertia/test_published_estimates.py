"""Running estimates are computed only for sinks that read them, and publishing them does
not move the final estimate (``ptinertia.sinks.Sink.wants_estimates``).

Reference: the same 10 s simulated sweep run twice, once with a sink that takes an
estimate after every block of frames (the pipeline flushing the estimator's queued rows
and solving each time) and once with no sink that reads estimates (no flush but the
estimator's own): the final estimates must be the same bits.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from estimator.result import EstimateUpdate
from ptinertia.config import Bench
from ptinertia.pipeline import Pipeline
from ptinertia.runner import processing_chain, settings_of
from ptinertia.sinks import RunContext, Sink
from ptinertia.sources import open_source


class Updates(Sink):
    def __init__(self, wants: bool) -> None:
        self.wants = wants
        self.updates: list[EstimateUpdate] = []

    def wants_estimates(self) -> bool:
        return self.wants

    def on_estimate(self, update: EstimateUpdate) -> None:
        self.updates.append(update)


def _run(bench: Bench, text: str, sink: Updates) -> Any:
    source = open_source("sim", bench, duration_s=10.0)
    tracker, estimator = processing_chain(bench, source.layout)
    context = RunContext(
        bench_text=text,
        bench=bench,
        layout=source.layout,
        setup=estimator.setup,
        truth=None,
        settings=settings_of(bench, tracker, estimator),
        source="sim",
    )
    # an estimate after every block with a used frame: as many flushes as a live run makes
    return Pipeline(source, tracker, estimator, [sink], context, estimate_period_s=0.0).run()


def test_the_final_estimate_does_not_depend_on_the_estimates_published(
    i3: Bench, i3_path: Path
) -> None:
    text = i3_path.read_text()
    reading, deaf = Updates(wants=True), Updates(wants=False)
    published = _run(i3, text, reading).estimate
    unpublished = _run(i3, text, deaf).estimate
    assert len(reading.updates) > 20 and deaf.updates == []
    assert published is not None and unpublished is not None
    assert published.names == unpublished.names
    np.testing.assert_array_equal(published.theta, unpublished.theta)
    np.testing.assert_array_equal(published.cov, unpublished.cov)
    assert published.variance_factor == unpublished.variance_factor
    assert published.half_order == unpublished.half_order
