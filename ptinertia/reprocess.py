"""A recording's raw data run through the chain again, everything kept in memory.

What ``ptinertia report`` needs from a raw-only recording (``simulate --out x.mcap``,
a crashed run whose final estimate was lost) or a run recording given another bench
file: the frames, the gating decisions, the published estimates and the result, as
``ptinertia replay`` would compute them (:func:`ptinertia.runner.run_source` over the
log's :class:`replay.source.McapSource`). The report only gathers and draws them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from estimator.result import Estimate, EstimateUpdate
from ptinertia.config import Bench
from ptinertia.recorded_run import run_recording
from ptinertia.runner import RunOptions
from ptinertia.sinks import RunContext, Sink
from replay.reader import RecordedLog


class MemorySink(Sink):
    """Keeps what a recording would have kept, in memory."""

    def __init__(self) -> None:
        self.frames: list[Any] = []
        self.outcomes: list[Any] = []
        self.updates: list[EstimateUpdate] = []
        self.context: RunContext | None = None

    def start(self, context: RunContext) -> None:
        self.context = context

    def on_frame(self, frame: Any, outcome: Any) -> None:
        self.frames.append(frame)
        self.outcomes.append(outcome)

    def on_estimate(self, update: EstimateUpdate) -> None:
        self.updates.append(update)


@dataclass(frozen=True)
class Reprocessed:
    """One run of the chain over a recording.

    Attributes
    ----------
    result : the result document, None when there is no estimate.
    final : the final estimate with its full covariance, None when there is none.
    frames, outcomes : the order frames and what the estimator did with each.
    updates : the published estimates.
    settings : the dsp and estimator settings in force.
    """

    result: dict[str, Any] | None
    final: Estimate | None
    frames: list[Any] = field(default_factory=list)
    outcomes: list[Any] = field(default_factory=list)
    updates: list[EstimateUpdate] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)


def reprocess_log(log: RecordedLog, bench: Bench, bench_text: str, where: str) -> Reprocessed:
    """Run the chain on the raw data of ``log`` with ``bench`` (``where`` names the log in
    messages: a channel the bench file needs and the log lacks)."""
    sink = MemorySink()
    summary, doc = run_recording(
        log, where, bench, bench_text, RunOptions(quiet=True, sinks=(sink,))
    )
    ctx = sink.context
    return Reprocessed(
        result=doc,
        final=summary.estimate,
        frames=sink.frames,
        outcomes=sink.outcomes,
        updates=sink.updates,
        settings=dict(ctx.settings) if ctx is not None else {},
    )
