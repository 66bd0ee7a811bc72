"""What the pipeline tells its sinks (recorder, viewer, progress line).

A sink subclasses :class:`Sink` and overrides what it needs. Every call runs
on the processing thread, in stream order; a sink must not block for long
(the viewer and the recorder buffer internally). The pipeline calls
``start`` once, then any mix of the ``on_*`` methods, then ``close`` exactly
once, also after an error or Ctrl-C, so a recording is always finished.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from acquisition.stream import SourceEvent, StreamItem, StreamLayout
from estimator.result import Estimate
from estimator.setup import EstimatorSetup
from estimator.streaming import FrameOutcome


@dataclass(frozen=True)
class RunContext:
    """Everything fixed for the run.

    Attributes
    ----------
    bench_text : the bench file as given (stored in recordings).
    bench : the validated bench (``ptinertia.config.Bench``).
    layout : the source's channels and rates.
    setup : the estimator's view of the bench (sensor geometry, mounts).
    truth : the simulated truth (result-JSON shape) or None for real data.
    settings : plain-JSON description of the dsp/estimator settings in force.
    source : the source spec (``sim``, ``file:...``, ``can:...``).
    attachments : extra files to keep with a recording (name -> bytes), e.g. the DBC.
    """

    bench_text: str
    bench: Any
    layout: StreamLayout
    setup: EstimatorSetup
    truth: dict[str, Any] | None
    settings: dict[str, Any]
    source: str
    attachments: dict[str, bytes] = field(default_factory=dict)


@dataclass(frozen=True)
class EstimateUpdate:
    """The estimate after a used frame: time and rpm of that frame, and the estimate."""

    time_s: float
    rpm: float
    estimate: Estimate


class Sink:
    """Base sink: every hook is a no-op."""

    def start(self, context: RunContext) -> None:
        """Called once before the first item."""

    def on_item(self, item: StreamItem) -> None:
        """A raw source item exactly as the dsp stage receives it (samples, edges, events)."""

    def on_frame(self, frame: Any, outcome: FrameOutcome) -> None:
        """An order frame (``dsp.frames.OrderFrame``) and what the estimator did with it."""

    def on_estimate(self, update: EstimateUpdate) -> None:
        """The running estimate after a used frame."""

    def on_event(self, event: SourceEvent) -> None:
        """A reportable event from the source or the dsp stage (gap, re-sync, bus-off)."""

    def on_backlog(self, seconds: float) -> None:
        """Processing is ``seconds`` behind acquisition (reported when it grows)."""

    def close(self, final: Estimate | None) -> None:
        """Called exactly once at the end (normal end, error or Ctrl-C)."""
