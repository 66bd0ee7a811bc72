"""Running estimates are computed only for sinks that read them, and publishing them does
not move the final estimate (``ptinertia.sinks.wants_estimates``).

Reference: the same 10 s simulated sweep run twice, once with a sink that takes an
estimate after every block of frames (the pipeline flushing the estimator's queued rows
and solving each time) and once with no sink that reads estimates (no flush but the
estimator's own): the final estimates must be the same bits. Also with a sensor going
dead half way: its frames leave a rigid-body motion unseen, whose rows depend on when they
are flushed, so from then on the estimates are computed on schedule, wanted or not.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acquisition.stream import SampleBlock, Source, StreamItem, StreamLayout
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


class DeadAfter(Source):
    """``source`` with the channels named ``prefix...`` NaN from ``time_s`` on."""

    def __init__(self, source: Source, prefix: str, time_s: float) -> None:
        super().__init__()
        self.source, self.prefix, self.time_s = source, prefix, time_s

    @property
    def layout(self) -> StreamLayout:
        return self.source.layout

    def _iter_items(self) -> Iterator[StreamItem]:
        for item in self.source:
            if isinstance(item, SampleBlock):
                group = self.layout.group(item.group)
                rows = [i for i, c in enumerate(group.channels) if c.name.startswith(self.prefix)]
                t = group.t0_s + (item.first_index + np.arange(item.n_samples)) / group.rate_hz
                if rows and t[-1] >= self.time_s:
                    data = item.data.copy()
                    data[np.ix_(np.array(rows), np.flatnonzero(t >= self.time_s))] = np.nan
                    item = dataclasses.replace(item, data=data)
            yield item


def _run(bench: Bench, text: str, sink: Updates, dead: bool = False) -> Any:
    source: Source = open_source("sim", bench, duration_s=10.0)
    if dead:  # sensor C from 5 s on: two sensors left, one motion unseen
        source = DeadAfter(source, "C_", 5.0)
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


@pytest.mark.parametrize("dead", [False, True], ids=["all sensors", "a sensor dead at 5 s"])
def test_the_final_estimate_does_not_depend_on_the_estimates_published(
    i3: Bench, i3_path: Path, dead: bool
) -> None:
    text = i3_path.read_text()
    reading, deaf = Updates(wants=True), Updates(wants=False)
    published = _run(i3, text, reading, dead).estimate
    unpublished = _run(i3, text, deaf, dead).estimate
    assert len(reading.updates) > 20
    if dead:  # computed on schedule from the first frame of two sensors on, and handed on
        assert 0 < len(deaf.updates) < len(reading.updates)
        assert deaf.updates[0].time_s >= 5.0
        assert published.unseen_motion is not None
    else:
        assert deaf.updates == []
    assert published is not None and unpublished is not None
    assert published.names == unpublished.names
    np.testing.assert_array_equal(published.theta, unpublished.theta)
    np.testing.assert_array_equal(published.cov, unpublished.cov)
    assert published.variance_factor == unpublished.variance_factor
    assert published.half_order == unpublished.half_order
