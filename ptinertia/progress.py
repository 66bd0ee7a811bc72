"""The terminal progress line of ``ptinertia run`` / ``replay``, and a bar for other long work.

One line, rewritten in place on a terminal (at most 5 times a second), one
line every 10 s when stderr is a file or a CI log: stream time, rpm, frames
used/rejected, and the current estimate of the largest inertia term with its
95 % interval.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Any, TextIO

from acquisition.stream import SourceEvent
from estimator.outcome import FrameOutcome
from estimator.result import Z95, Estimate, EstimateUpdate
from ptinertia.sinks import RunContext, Sink


class ProgressLine(Sink):
    """Progress on stderr; events (gaps, re-syncs, backlog) as their own lines."""

    def __init__(
        self,
        stream: TextIO | None = None,
        quiet: bool = False,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.clock = clock  # s, monotonic (injectable for tests)
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.period = 0.2 if self.tty else 10.0
        self._last = 0.0
        self.time_s = 0.0
        self.rpm = float("nan")
        self.used = 0
        self.rejected = 0
        self.estimate: Estimate | None = None
        self._dirty = False
        self._fresh = False  # an estimate came since the last rewrite
        self._missed = False  # the last rewrite had no fresh estimate to show

    def start(self, context: RunContext) -> None:
        self._t0 = self.clock()

    def on_frame(self, frame: object, outcome: FrameOutcome) -> None:
        self.time_s = outcome.time_s
        self.rpm = outcome.rpm
        if outcome.reason is None:
            self.used += 1
        elif outcome.reason != "overlapping":
            self.rejected += 1
        self._tick()

    def on_estimate(self, update: EstimateUpdate) -> None:
        self.estimate = update.estimate
        self._fresh = True

    def wants_estimates(self) -> bool:
        # only what the line will show: none when quiet; else one estimate per rewrite,
        # taken in the last second before it is due (on a terminal's 0.2 s: right after
        # the previous rewrite), so the line is never more than a second behind; and the
        # next one whenever the line has none, or a rewrite went out without a fresh one
        if self.quiet or self._fresh:
            return False
        if self.estimate is None or self._missed:
            return True
        return self.clock() - self._last >= self.period - min(1.0, self.period)

    def on_event(self, event: SourceEvent) -> None:
        if not self.quiet:
            self._clear()
            when = f" at {event.time_s:.2f} s" if event.time_s is not None else ""
            print(f"[{event.kind}]{when}: {event.message}", file=self.stream)

    def on_backlog(self, seconds: float) -> None:
        if not self.quiet:
            self._clear()
            print(f"[backlog] processing is {seconds:.1f} s behind acquisition", file=self.stream)

    def line(self) -> str:
        text = f"t {self.time_s:7.1f} s  rpm {self.rpm:6.0f}  frames {self.used} used, {self.rejected} rejected"
        est = self.estimate
        if est is not None:
            name = max(("Ixx", "Iyy", "Izz"), key=lambda n: est.value(n))
            text += f"  {name} {est.value(name):.4f} +- {Z95 * est.std(name):.4f} kg m^2"
            text += "  cog [" + ", ".join(f"{1e3 * v:.1f}" for v in est.cog) + "] mm"
        return text

    def _tick(self) -> None:
        self._dirty = True
        if self.quiet:
            return
        now = self.clock()
        if now - self._last < self.period:
            return
        self._last = now
        self._write()

    def _write(self) -> None:
        if self.tty:
            self.stream.write("\r\x1b[2K" + self.line())
        else:
            self.stream.write(self.line() + "\n")
        self.stream.flush()
        self._dirty = False
        self._missed = not self._fresh
        self._fresh = False

    def _clear(self) -> None:
        if self.tty:
            self.stream.write("\r\x1b[2K")

    def close(self, final: Estimate | None) -> None:
        if self.quiet:
            return
        if final is not None:  # the last line shows the run's final estimate
            self.estimate = final
            self._dirty = True
        if self._dirty or self.tty:
            self._write()
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def work_bar(total: float, desc: str, unit: str = "s", stream: TextIO | None = None) -> Any:
    """A tqdm bar on stderr for long work that is not a run (``report``, ``can-sim --log``).

    Shown after 1 s (short work prints nothing) and only on a terminal (a CI log or a
    pipe gets no bar). ``unit="s"``: advanced by seconds of stream time; ``"step"``: one
    per stage, whose name :func:`set_postfix_str` shows.
    """
    from tqdm import tqdm  # on use: a run or a replay never needs it

    out = stream or sys.stderr
    fmt = (
        "{l_bar}{bar}| {n:.1f}/{total:.1f} s"
        if unit == "s"
        else "{l_bar}{bar}| {n_fmt}/{total_fmt}{postfix}"
    )
    return tqdm(
        total=round(total, 3),
        unit=unit,
        delay=1.0,
        file=out,
        disable=not getattr(out, "isatty", lambda: False)(),
        desc=desc,
        leave=False,
        bar_format=fmt,
    )
