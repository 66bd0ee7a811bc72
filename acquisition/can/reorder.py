"""The decoder's per-message state: counter unwrapping, reorder windows and gap events.

:class:`DecoderOptions` sets the windows, :class:`MessageStream` unwraps one message's
counters and holds its frames until they are given out, :class:`GroupAssembler` tracks
a sample group, :class:`GapReport` merges gap events. Apart from placement (whether a
frame is placed, late or lost), which :class:`~acquisition.can.decoder.FrameDecoder`
decides while it drives them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from acquisition.can.plan import MessagePlan
from acquisition.can.stats import StreamStats
from acquisition.stream import SourceEvent

_PLAUSIBLE_WINDOWS = 4  # a counter may move this many reorder windows beyond what the clock allows
# A receive time this far past the last frame is no longer trusted alone to allow a counter
# jump (one corrupt log timestamp of 1e11 s would move every later frame 1e13 frames on):
# the frame then waits for a second one agreeing with it, as after any implausible jump.
_MAX_TRUSTED_GAP_S = 3600.0


@dataclass(frozen=True)
class DecoderOptions:
    """Tuning of :class:`FrameDecoder`.

    Attributes
    ----------
    reorder_window_s : float
        How far (s of samples) a frame may arrive behind its group's newest frame
        and still be placed; the latency of the gap decision.
    edge_window_frames : int
        The same for edge frames, in frames (they come at the rate of the edges).
    event_interval_s : float
        Gap events of one stream are merged over this much data time.
    emit_chunk_s : float
        Items are given out in chunks of this much data time, all groups and edge
        channels of a chunk together (whatever the size of the batch fed).
    """

    reorder_window_s: float = 0.05
    edge_window_frames: int = 16
    event_interval_s: float = 1.0
    emit_chunk_s: float = 0.1


class MessageStream:
    """Counter unwrapping and the frames of one message not yet given out."""

    def __init__(self, plan: MessagePlan, window_frames: int, stats: StreamStats) -> None:
        self.plan = plan
        self.stats = stats
        self.window = window_frames
        self.modulus = plan.counter_modulus
        self.frame_rate = plan.frame_rate_hz
        self.ref_n: int | None = None  # last accepted frame number and its receive time
        self.ref_t = 0.0
        self.quarantine: list[tuple[int, float, Any]] = []
        self.received: dict[int, Any] = {}
        # given-out frame numbers, to tell duplicates from late frames
        self.recent: set[int] = set()
        self.next_frame: int | None = None  # next frame number to resolve
        self.max_n = -1

    def unwrap(self, c: int, t: float, hint: float | None) -> int:
        if self.ref_n is not None:
            hint = self.ref_n + max(0.0, t - self.ref_t) * self.frame_rate
        if hint is None:
            return c
        return c + self.modulus * round((hint - c) / self.modulus)

    def plausible(self, n: int, t: float) -> bool:
        if self.ref_n is None:
            return False
        d = n - self.ref_n
        dt = min(max(0.0, t - self.ref_t), _MAX_TRUSTED_GAP_S)
        slack = _PLAUSIBLE_WINDOWS * self.window + 2.0 * dt * self.frame_rate
        return -_PLAUSIBLE_WINDOWS * self.window <= d <= slack

    def offer(self, n: int, t: float, payload: Any) -> list[tuple[int, Any]]:
        """Frames now trusted, in arrival order (an implausible counter waits for a second opinion)."""
        if self.plausible(n, t):
            assert self.ref_n is not None
            self.ref_n, self.ref_t = max(self.ref_n, n), t
            return [(n, payload)]
        for i, (qn, _, _) in enumerate(self.quarantine):
            if abs(n - qn) <= _PLAUSIBLE_WINDOWS * self.window:
                q = self.quarantine[i]
                self.stats.bad_counter += len(self.quarantine) - 1
                self.quarantine.clear()
                self.ref_n, self.ref_t = max(q[0], n), t
                return [(q[0], q[2]), (n, payload)]
        self.quarantine.append((n, t, payload))
        if len(self.quarantine) > 3:
            self.quarantine.pop(0)
            self.stats.bad_counter += 1
        return []

    def flush_quarantine(self) -> list[tuple[int, Any]]:
        """At the end: a lone frame of a stream that never had a reference is trusted."""
        out = []
        if self.ref_n is None and self.quarantine:
            qn, _, payload = self.quarantine[0]
            out.append((qn, payload))
            self.stats.bad_counter += len(self.quarantine) - 1
        else:
            self.stats.bad_counter += len(self.quarantine)
        self.quarantine.clear()
        return out

    def forget_before(self, n: int) -> None:
        if len(self.recent) > 16 * self.window + 64:
            keep = n - 8 * self.window
            self.recent = {k for k in self.recent if k >= keep}


class GroupAssembler:
    """A sample group being assembled from its messages' frames."""

    def __init__(self, name: str, rate_hz: float, n_ch: int, window_s: float) -> None:
        self.name = name
        self.rate = rate_hz
        self.n_ch = n_ch
        self.window = max(1, math.ceil(window_s * rate_hz))
        self.members: list[MessageStream] = []
        self.high = -1  # end (exclusive) of the newest received frame, samples
        self.start: int | None = None
        self.next_index = 0
        self.end_index: int | None = None


class GapReport:
    """Gap events merged per stream over ``interval_s`` of data time."""

    def __init__(self, interval_s: float) -> None:
        self.interval = interval_s
        self.pending: dict[tuple[str, str], list[Any]] = {}

    def add(self, key: str, what: str, count: int, t0: float, t1: float) -> None:
        p = self.pending.setdefault((key, what), [key, what, 0, t0, t1])
        p[2] += count
        p[4] = max(p[4], t1)

    def due(self, now: float | None) -> list[SourceEvent]:
        out = []
        for pk in list(self.pending):
            key, what, count, t0, t1 = self.pending[pk]
            if now is None or now - t0 >= self.interval:
                del self.pending[pk]
                out.append(
                    SourceEvent(
                        "gap",
                        f"{key}: {count} {what} lost between {t0:.4f} s and {t1:.4f} s",
                        t0,
                        count,
                    )
                )
        return out
