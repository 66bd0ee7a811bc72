"""What the pipeline tells its sinks (recorder, viewer, progress line).

:class:`Sink` is a :class:`typing.Protocol`: the app defines it, and a sink
from a lower layer (``replay.recorder.McapRecorder``) satisfies it by shape,
without importing the app. The app's own sinks subclass it and inherit its
no-op hooks, overriding what they need. The data a sink is handed lives below
the app: stream items in :mod:`acquisition.stream`, order frames in
:mod:`dsp.frames`, frame outcomes in :mod:`estimator.streaming`, and the
estimate and its updates (:class:`estimator.result.EstimateUpdate`) in
:mod:`estimator.result`, so replay reads and writes them without the app;
only :class:`RunContext`, which carries the validated ``Bench``, is the app's.

Every call runs on the processing thread, in stream order; a sink must not
block for long (the viewer and the recorder buffer internally). The pipeline
calls ``start`` once, then any mix of the ``on_*`` methods, then ``close``
exactly once, also after an error or Ctrl-C, so a recording is always finished.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

from acquisition.stream import SourceEvent, StreamItem, StreamLayout
from estimator.outcome import FrameOutcome
from estimator.result import Estimate, EstimateUpdate
from estimator.setup import EstimatorSetup


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


class Sink(Protocol):
    """What the pipeline calls; as a base class every hook is a no-op.

    The hooks ``return None`` explicitly: a protocol method with an empty body is
    abstract to mypy, and a subclass must be free to override only what it needs.
    """

    def start(self, context: RunContext) -> None:
        """Called once before the first item."""
        return None

    def on_item(self, item: StreamItem) -> None:
        """A raw source item exactly as the dsp stage receives it (samples, edges, events)."""
        return None

    def on_frame(self, frame: Any, outcome: FrameOutcome) -> None:
        """An order frame (``dsp.frames.OrderFrame``) and what the estimator did with it."""
        return None

    def prepare_frames(self, frames: Sequence[Any]) -> None:
        """A block's frames, before their :meth:`on_frame` calls: what a sink does better
        with the block at once (the recorder encodes its frames together)."""
        return None

    def on_estimate(self, update: EstimateUpdate) -> None:
        """The running estimate after a used frame: computed on schedule when a sink wants
        it (an optional ``wants_estimates()``, see :func:`wants_estimates`), then every sink
        gets it."""
        return None

    def on_event(self, event: SourceEvent) -> None:
        """A reportable event from the source or the dsp stage (gap, re-sync, bus-off)."""
        return None

    def on_backlog(self, seconds: float) -> None:
        """Processing is ``seconds`` behind acquisition (reported when it grows)."""
        return None

    def close(self, final: Estimate | None) -> None:
        """Called exactly once at the end (normal end, error or Ctrl-C)."""
        return None


def wants_estimates(sink: Any) -> bool:
    """Whether ``sink`` reads the next running estimate: its ``wants_estimates()`` where it
    has one (an optional hook, asked before each estimate), else True.

    When no sink of a run wants it (a quiet replay, a campaign's runs), the pipeline does
    not compute the estimate: a published estimate costs a flush and a solve (about 0.04 s
    a minute of log at 79 estimates). The final estimate has the same bits either way: the
    sums of fully measured frames do not depend on when the queue is flushed, and once a
    frame with an unseen motion is queued (whose rows do depend on it) the estimate is
    computed on schedule whether wanted or not (``ptinertia.pipeline``;
    ``tests/ptinertia/test_published_estimates.py`` pins both). A computed estimate goes
    to every sink.
    """
    return not hasattr(sink, "wants_estimates") or bool(sink.wants_estimates())


def prepare_frames(sink: Any, frames: Sequence[Any]) -> None:
    """``sink.prepare_frames`` where the sink has it (a sink satisfies :class:`Sink` by
    shape and need not define every hook)."""
    if hasattr(sink, "prepare_frames"):
        sink.prepare_frames(frames)
