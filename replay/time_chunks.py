"""Chunks by stream time: each chunk holds one ``chunk_s`` slice of the run, so chunks do not overlap.

A recording mixes two kinds of messages: the raw stream, which arrives in
stream-time order, and what the dsp stage and the estimator computed from it
(order frames, gating, estimates, dsp events), which arrives a little later
than the data it describes (the frame's centre lags the newest sample by
about one dsp block: 41 ms in the default i3 run). Closing a chunk when the
newest message passes its end, as the recorder did before, put each frame
for the end of slice ``k`` into chunk ``k + 1``: 119 of the 120 chunks of a
60 s run overlapped their neighbour, and a reader seeking to a time had to
open two chunks, merging them (Rerun's MCAP importer warns about it).

Here a message goes to the slice ``floor(t / chunk_s)`` of its stream time,
and a slice is closed only once the stream has moved ``late_s`` past its end
(or it has been open ``chunk_s + late_s`` of wall time, for a crawling
stream), so late results still find their slice open. Within a chunk the
messages keep the order they came in; and since replay reads the raw stream
in file order (the order the live dsp saw it), a message never goes to a
slice before the one the previous message of its kind (raw or result) went
to. A message later than ``late_s`` goes to the oldest open slice; its chunk
then reaches back before its slice's start, the only way chunks overlap.

The price is crash safety: a killed run loses the open slices, at most
``chunk_s + late_s`` (0.75 s by default) of stream or wall time plus one
block, where a single open chunk lost at most ``chunk_s`` plus one block.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

# (channel id, log time ns, data, publish time ns) of one message waiting for its chunk
Pending = tuple[int, int, Any, int]  # data: bytes or replay.mcap_output.LateBytes


@dataclass
class _Slice:
    wall_opened: float  # monotonic s of the first message
    messages: list[Pending] = field(default_factory=list)


class TimeChunker:
    """Assigns messages to stream-time slices; says which slices are ready to be written.

    Parameters
    ----------
    chunk_s : float
        Length of a slice, s of stream time.
    late_s : float
        How far past a slice's end the stream must be before it is closed, s.

    Times are integer ns of stream time, as rounded for the log time: a slice is then
    exactly the log times it may hold, and a message at 5.9999999999 s (logged at
    6.000000000 s) does not end one chunk where the next one starts.
    monotonic : callable returning s, the wall clock of the crawl bound.
    """

    def __init__(self, chunk_s: float, late_s: float, monotonic: Callable[[], float]) -> None:
        self.chunk_ns = round(chunk_s * 1e9)
        self.late_ns = round(late_s * 1e9)
        self.wall_s = float(chunk_s + late_s)
        self._monotonic = monotonic
        self._open: dict[int, _Slice] = {}  # slice index -> messages, in index order
        self._closed_through = -(2**62)  # highest slice index already written
        self._last_slice: dict[str, int] = {}  # kind ("raw", "result") -> slice of its last message
        self._t_max = -(2**62)  # newest stream time seen, ns
        self._oldest = (-(2**62), 0.0)  # when the oldest open slice is due (_note_oldest)
        # messages filed after their slice (missed it, or behind one of their kind): their
        # chunk may reach back into the one before
        self.late_messages = 0

    def add(self, kind: str, t_ns: int, message: Pending) -> list[list[Pending]]:
        """File one message of stream time ``t_ns``; return the slices now ready, oldest first."""
        index = t_ns // self.chunk_ns
        floor = max(self._last_slice.get(kind, index), self._closed_through + 1)
        if index < floor:
            self.late_messages += 1
            index = floor
        self._last_slice[kind] = index
        now = self._monotonic()
        slot = self._open.get(index)
        if slot is None:
            slot = self._open[index] = _Slice(now)
            if len(self._open) > 1 and index < max(self._open):
                self._open = dict(sorted(self._open.items()))
            self._note_oldest()
        slot.messages.append(message)
        if t_ns > self._t_max:
            self._t_max = t_ns
        # the oldest slice not due (the test _ready makes, on its figures kept aside): most
        # messages stop here (6554 a minute; the loop cost them about 1 us each)
        due_ns, wall_opened = self._oldest
        if self._t_max < due_ns and not now - wall_opened >= self.wall_s:
            return []
        return self._ready(now)

    def _note_oldest(self) -> None:
        """Keep aside when the oldest open slice is due: (stream time ns, wall time opened)."""
        if self._open:
            index, slot = next(iter(self._open.items()))
            self._oldest = ((index + 1) * self.chunk_ns + self.late_ns, slot.wall_opened)

    def _ready(self, now: float) -> list[list[Pending]]:
        ready = []
        while self._open:
            index, slot = next(iter(self._open.items()))
            by_stream = (index + 1) * self.chunk_ns + self.late_ns <= self._t_max
            by_wall = now - slot.wall_opened >= self.wall_s
            if not (by_stream or by_wall):
                break
            ready.append(self._pop(index))
        self._note_oldest()
        return ready

    def drain(self) -> list[list[Pending]]:
        """Every open slice, oldest first (at a flush or the end of the run)."""
        return [self._pop(index) for index in list(self._open)]

    def _pop(self, index: int) -> list[Pending]:
        self._closed_through = max(self._closed_through, index)
        return self._open.pop(index).messages
