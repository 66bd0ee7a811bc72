"""CAN sources: frames -> stream items (:class:`FrameDecoder`), and the live bus (:class:`CanBusSource`).

Placement. A sample frame's counter, unwrapped, is its frame number ``n``: it holds
samples ``n S .. n S + S - 1`` of its group, so a sample lands on its grid index
whatever happened to the frames around it. Counters shorter than the run
(an ECU's 16-bit counter) are unwrapped against the receive time: the frame
number nearest to ``last_n + dt * frame_rate``.

Losses. The frames of one group that are still missing when the group's newest
frame is ``reorder_window_s`` ahead of them are lost: their samples are NaN (or
left out, an index jump, where every channel of the group lost them) and a
``"gap"`` event reports them. A frame arriving after that is *late* (rejected: its
samples were already given out). Duplicates are dropped. Malformed frames (wrong
length, bad CRC, implausible counter, unknown id) are counted and dropped; a
counter is implausible when it jumps further than the receive time allows, and
two consecutive frames that agree on a new counter are taken as a resynchronisation
(after a long outage). Every decision depends only on the order the frames
arrived in, never on how they were batched: live and replay give the same items.

The end. A DAQ status frame with ``STATE = stopped`` gives the end of the
acquisition: frames missing before it are counted lost (none can follow) and
padded samples after it are cut.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

import numpy as np

from acquisition.can_codec import (
    STATE_STOPPED,
    CanPlan,
    MessagePlan,
    RawFrame,
    as_rows,
    frame_crc,
    load_plan,
    raw_fields_slow,
    read_fields,
    scale_samples,
)
from acquisition.stream import (
    EdgeBlock,
    SampleBlock,
    Source,
    SourceError,
    SourceEvent,
    StreamItem,
    StreamLayout,
)

if TYPE_CHECKING:
    from ptinertia.config import Bench

_PLAUSIBLE_WINDOWS = 4  # a counter may move this many reorder windows beyond what the clock allows


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
    """

    reorder_window_s: float = 0.05
    edge_window_frames: int = 16
    event_interval_s: float = 1.0


@dataclass
class StreamStats:
    """Frame counts of one DBC message (``lost`` includes ``late`` and malformed ones)."""

    frames: int = 0
    lost: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    late: int = 0
    bad_length: int = 0
    bad_crc: int = 0
    bad_counter: int = 0
    bad_payload: int = 0
    before_start: int = 0

    @property
    def malformed(self) -> int:
        return self.bad_length + self.bad_crc + self.bad_counter + self.bad_payload


@dataclass
class DecoderStats:
    """Everything :class:`FrameDecoder` counted."""

    streams: dict[str, StreamStats] = field(default_factory=dict)
    unknown_ids: dict[int, int] = field(default_factory=dict)
    frames_in: int = 0
    ignored: int = 0
    bus_errors: int = 0

    def total(self, name: str) -> int:
        return sum(getattr(s, name) for s in self.streams.values())

    @property
    def malformed(self) -> int:
        return sum(s.malformed for s in self.streams.values()) + sum(self.unknown_ids.values())

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames_in": self.frames_in,
            "ignored": self.ignored,
            "unknown_ids": {f"0x{k:X}": v for k, v in self.unknown_ids.items()},
            "bus_errors": self.bus_errors,
            "streams": {
                n: {f.name: getattr(s, f.name) for f in fields(s)} for n, s in self.streams.items()
            },
        }

    def summary(self) -> str:
        """One line for the user."""
        frames = self.total("frames")
        lost = self.total("lost")
        pct = 100.0 * lost / max(1, frames + lost)
        parts = [f"CAN: {self.frames_in} frames in, {frames} placed, {lost} lost ({pct:.3g} %)"]
        for name in ("duplicate", "out_of_order", "late"):
            if self.total(name):
                parts.append(f"{self.total(name)} {name.replace('_', ' ')}")
        bad = {k: self.total(f"bad_{k}") for k in ("length", "crc", "counter", "payload")}
        bad["unknown id"] = sum(self.unknown_ids.values())
        if any(bad.values()):
            parts.append("malformed " + ", ".join(f"{k} {v}" for k, v in bad.items() if v))
        if self.bus_errors:
            parts.append(f"{self.bus_errors} bus errors")
        return "; ".join(parts)


# -- per-message state -----------------------------------------------------------------------------


class _Stream:
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
        slack = _PLAUSIBLE_WINDOWS * self.window + 2.0 * max(0.0, t - self.ref_t) * self.frame_rate
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


class _Group:
    """A sample group being assembled from its messages' frames."""

    def __init__(self, name: str, rate_hz: float, n_ch: int, window_s: float) -> None:
        self.name = name
        self.rate = rate_hz
        self.n_ch = n_ch
        self.window = max(1, math.ceil(window_s * rate_hz))
        self.members: list[_Stream] = []
        self.high = -1  # end (exclusive) of the newest received frame, samples
        self.start: int | None = None
        self.next_index = 0
        self.end_index: int | None = None


class _Gaps:
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


class FrameDecoder:
    """CAN frames in (any batches, arrival order), stream items out.

    Parameters
    ----------
    plan : CanPlan
    options : DecoderOptions

    Attributes
    ----------
    stats : DecoderStats
    stopped_s : float or None
        End of the acquisition, once the DAQ's stop frame arrived.
    """

    def __init__(self, plan: CanPlan, options: DecoderOptions | None = None) -> None:
        self.plan = plan
        self.options = options or DecoderOptions()
        self.stats = DecoderStats()
        self.stopped_s: float | None = None
        self._by_key = plan.by_key()
        self._streams: dict[str, _Stream] = {}
        self._groups: dict[str, _Group] = {}
        self._group_of: dict[str, _Group] = {}
        self._edge_last: dict[str, float] = {}
        self._gaps = _Gaps(self.options.event_interval_s)
        self._clock: float | None = None  # min (receive time - DAQ time), s
        self._data_time = 0.0
        for g in plan.layout.groups:
            self._groups[g.name] = _Group(
                g.name, g.rate_hz, len(g.channels), self.options.reorder_window_s
            )
        for m in plan.messages:
            stats = self.stats.streams.setdefault(m.name, StreamStats())
            if m.kind == "samples":
                grp = self._groups[m.group]
                window = math.ceil(grp.window / m.samples_per_frame)
                s = _Stream(m, window, stats)
                grp.members.append(s)
                self._group_of[m.name] = grp
            else:
                s = _Stream(m, self.options.edge_window_frames if m.kind == "edges" else 1, stats)
            self._streams[m.name] = s
        for ch in plan.layout.edge_channels:
            self._edge_last[ch] = -math.inf

    @property
    def layout(self) -> StreamLayout:
        return self.plan.layout

    # -- input ---------------------------------------------------------------------------------

    def feed(self, frames: Sequence[RawFrame]) -> list[StreamItem]:
        """Decode a batch of frames (arrival order); return the items now complete."""
        self.stats.frames_in += len(frames)
        payloads = self._decode_batch(frames)
        for i, f in enumerate(frames):
            p = payloads[i]
            if p is None:
                continue
            plan, c, payload = p
            stream = self._streams[plan.name]
            t = f.timestamp_ns * 1e-9
            if plan.kind == "status":
                self._status(payload, t)
                continue
            n = stream.unwrap(c, t, self._hint(plan, t))
            for n_ok, pl in stream.offer(n, t, payload):
                self._accept(stream, n_ok, t, pl)
        return self._collect(final=False)

    def finish(self) -> list[StreamItem]:
        """End of input: resolve every frame still missing, give out the rest."""
        for s in self._streams.values():
            for n, pl in s.flush_quarantine():
                self._accept(s, n, s.ref_t, pl)
        items = self._collect(final=True)
        return items + self._gaps.due(None)

    def _hint(self, plan: MessagePlan, t: float) -> float | None:
        """Expected frame number of a stream's first frame from the DAQ clock, if known."""
        if self._clock is None or plan.kind != "samples":
            return None
        return (t - self._clock) * plan.frame_rate_hz

    def _decode_batch(
        self, frames: Sequence[RawFrame]
    ) -> list[tuple[MessagePlan, int, Any] | None]:
        """Vectorised per message: (plan, raw counter, payload) per frame, None if dropped."""
        out: list[tuple[MessagePlan, int, Any] | None] = [None] * len(frames)
        groups: dict[str, list[int]] = {}
        for i, f in enumerate(frames):
            key = (f.arbitration_id, f.is_extended_id)
            plan = self._by_key.get(key)
            if plan is None:
                if key in self.plan.dbc_ids:  # in the DBC, unused by this bench (pressure, cam)
                    self.stats.ignored += 1
                else:
                    self.stats.unknown_ids[f.arbitration_id] = (
                        self.stats.unknown_ids.get(f.arbitration_id, 0) + 1
                    )
            elif len(f.data) != plan.length:
                self._streams[plan.name].stats.bad_length += 1
            else:
                groups.setdefault(plan.name, []).append(i)
        for name, idx in groups.items():
            stream = self._streams[name]
            plan = stream.plan
            datas = [frames[i].data for i in idx]
            rows = as_rows(datas, plan.length)
            ok = np.ones(len(idx), dtype=bool)
            if plan.crc is not None:
                stored = read_fields(rows, [plan.crc])[:, 0]
                ok = np.array([frame_crc(d, plan.crc) for d in datas]) == stored
                stream.stats.bad_crc += int(np.count_nonzero(~ok))
            counters = (
                read_fields(rows, [plan.counter])[:, 0]
                if plan.counter is not None
                else np.zeros(len(idx), np.int64)
            )
            if plan.kind == "samples":
                raw = read_fields(rows, plan.payload) if plan.fast else raw_fields_slow(plan, datas)
                values: Any = scale_samples(plan, raw)
            elif plan.kind == "edges":
                values = self._edge_payload(plan, read_fields(rows, plan.payload), ok)
            else:
                values = read_fields(rows, plan.payload)
            for j, i in enumerate(idx):
                if ok[j]:
                    out[i] = (plan, int(counters[j]), values[j])
        return out

    def _edge_payload(
        self, plan: MessagePlan, raw: np.ndarray, ok: np.ndarray
    ) -> list[np.ndarray | None]:
        """Edge times (s) per frame; a count out of range or times not increasing is a bad payload."""
        stats = self.stats.streams[plan.name]
        k = plan.samples_per_frame
        count = raw[:, 0]
        deltas = raw[:, 2:]
        used = np.arange(1, k)[None, :] < count[:, None]
        prev = np.concatenate([np.zeros((raw.shape[0], 1), np.int64), deltas[:, :-1]], axis=1)
        good = (count >= 1) & (count <= k) & np.all(~used | (deltas > prev), axis=1)
        stats.bad_payload += int(np.count_nonzero(ok & ~good))
        ok &= good
        times = (
            np.concatenate([np.zeros((raw.shape[0], 1), np.int64), deltas], axis=1) + raw[:, 1:2]
        ) * plan.tick_s
        return [times[j, : count[j]] if ok[j] else None for j in range(raw.shape[0])]

    def _status(self, payload: np.ndarray, t: float) -> None:
        plan = next(m for m in self.plan.messages if m.kind == "status")
        state, daq_ticks = int(payload[0]), int(payload[1])
        daq_t = daq_ticks * plan.tick_s
        self._clock = t - daq_t if self._clock is None else min(self._clock, t - daq_t)
        if state == STATE_STOPPED and self.stopped_s is None:
            self.stopped_s = daq_t
            for g in self._groups.values():
                # the simulator's last sample is ceil(T rate) - 1; the tolerance absorbs the ns rounding
                g.end_index = math.ceil(daq_t * g.rate - 1e-4)

    # -- placement -----------------------------------------------------------------------------

    def _accept(self, s: _Stream, n: int, t: float, payload: Any) -> None:
        if s.plan.kind == "edges":
            self._accept_edges(s, n, payload)
            return
        g = self._group_of[s.plan.name]
        size = s.plan.samples_per_frame
        a, b = n * size, (n + 1) * size
        if g.start is None:
            g.start = 0 if a <= g.window else a  # a receiver joining late starts where it joined
            g.next_index = g.start
            for m in g.members:
                m.next_frame = g.start // m.plan.samples_per_frame
        if b <= g.start:
            s.stats.before_start += 1
            return
        if n in s.received or n in s.recent:
            s.stats.duplicate += 1
            return
        assert s.next_frame is not None
        if n < s.next_frame or b <= g.high - g.window:
            s.stats.late += 1
            return
        s.received[n] = payload
        s.stats.frames += 1
        if n < s.max_n:
            s.stats.out_of_order += 1
        s.max_n = max(s.max_n, n)
        g.high = max(g.high, b)
        if s.modulus >= 1 << 32:  # an absolute DAQ counter dates the receive clock
            daq_t = b / g.rate
            self._clock = t - daq_t if self._clock is None else min(self._clock, t - daq_t)

    def _accept_edges(self, s: _Stream, n: int, times: np.ndarray) -> None:
        if s.next_frame is None:
            s.next_frame = 0 if n <= s.window else n
        if n in s.received or n in s.recent:
            s.stats.duplicate += 1
            return
        if n < s.next_frame or n <= s.max_n - s.window:
            s.stats.late += 1
            return
        s.received[n] = times
        s.stats.frames += 1
        if n < s.max_n:
            s.stats.out_of_order += 1
        s.max_n = max(s.max_n, n)

    # -- output --------------------------------------------------------------------------------

    def _collect(self, final: bool) -> list[StreamItem]:
        items: list[tuple[float, int, StreamItem]] = []
        for gi, g in enumerate(self._groups.values()):
            for blk in self._emit_group(g, final):
                items.append((blk.first_index / g.rate, gi, blk))
        for s in self._streams.values():
            if s.plan.kind == "edges":
                eb = self._emit_edges(s, final)
                if eb is not None:
                    items.append((float(eb.times_s[0]), 100, eb))
        items.sort(key=lambda it: (it[0], it[1]))
        out: list[StreamItem] = [it[2] for it in items]
        if items:
            self._data_time = max(self._data_time, items[-1][0])
        if not final:
            out += self._gaps.due(self._data_time)
        return out

    def _emit_group(self, g: _Group, final: bool) -> list[SampleBlock]:
        if g.start is None:
            return []
        cap = g.high if g.end_index is None else g.end_index
        limit = cap if final else min(cap, g.high - g.window)
        upto = cap
        for s in g.members:
            size = s.plan.samples_per_frame
            assert s.next_frame is not None
            lost_from = None
            n = s.next_frame
            while n in s.received or (n + 1) * size <= limit or (final and n * size < limit):
                if n not in s.received:
                    s.stats.lost += 1
                    lost_from = n if lost_from is None else lost_from
                elif lost_from is not None:
                    self._report_lost(s, g, lost_from, n)
                    lost_from = None
                n += 1
            if lost_from is not None:
                self._report_lost(s, g, lost_from, n)
            s.next_frame = n
            upto = min(upto, n * size)
        i0 = g.next_index
        # samples no member received are an index jump: skip them without building NaNs
        # (an hour-long outage would otherwise allocate gigabytes)
        first = min(
            (n * m.plan.samples_per_frame for m in g.members for n in m.received), default=upto
        )
        i0 = max(i0, min(first, upto))
        g.next_index = i0
        if upto <= i0:
            return []
        data = np.empty((g.n_ch, upto - i0))
        for s in g.members:
            size = s.plan.samples_per_frame
            f0, f1 = i0 // size, -(-upto // size)
            hole = np.full((size, len(s.plan.rows)), np.nan)
            # one copy per member: the frames (received or NaN) end to end, then the window
            run = np.concatenate([s.received.get(n, hole) for n in range(f0, f1)])
            data[list(s.plan.rows)] = run[i0 - f0 * size : upto - f0 * size].T
            for n in range(f0, f1 if f1 * size <= upto else f1 - 1):
                if s.received.pop(n, None) is not None:
                    s.recent.add(n)
            s.forget_before(f0)
        g.next_index = upto
        return _split_on_holes(g.name, i0, data)

    def _report_lost(self, s: _Stream, g: _Group, n0: int, n1: int) -> None:
        size = s.plan.samples_per_frame
        what = f"frame(s) of {s.plan.name} ({', '.join(s.plan.channels)})"
        self._gaps.add(g.name, what, n1 - n0, n0 * size / g.rate, n1 * size / g.rate)

    def _emit_edges(self, s: _Stream, final: bool) -> EdgeBlock | None:
        if s.next_frame is None:
            return None
        ch = s.plan.group
        parts = []
        n = s.next_frame
        lost = 0
        while n in s.received or n <= s.max_n - s.window or (final and n <= s.max_n):
            times = s.received.pop(n, None)
            if times is None:
                s.stats.lost += 1
                lost += 1
            else:
                s.recent.add(n)
                if lost:
                    t0 = self._edge_last[ch] if math.isfinite(self._edge_last[ch]) else times[0]
                    self._gaps.add(ch, "edge frame(s)", lost, float(t0), float(times[0]))
                    lost = 0
                if times[0] <= self._edge_last[ch]:
                    s.stats.bad_payload += (
                        1  # not after the previous edge: a corrupt but CRC-valid frame
                    )
                else:
                    parts.append(times)
                    self._edge_last[ch] = float(times[-1])
            n += 1
        if lost:
            t_last = self._edge_last[ch] if math.isfinite(self._edge_last[ch]) else 0.0
            self._gaps.add(ch, "edge frame(s)", lost, t_last, t_last)
        s.next_frame = n
        s.forget_before(n)
        if not parts:
            return None
        return EdgeBlock(ch, np.concatenate(parts))


def _split_on_holes(group: str, i0: int, data: np.ndarray) -> list[SampleBlock]:
    """Blocks of ``data`` without the samples every channel lost (those become index jumps)."""
    hole = np.all(np.isnan(data), axis=0)
    if not hole.any():
        return [SampleBlock(group, i0, data)]
    edges = np.flatnonzero(np.diff(np.concatenate([[1], hole.astype(np.int8), [1]])))
    out = []
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        out.append(SampleBlock(group, i0 + int(a), data[:, a:b]))
    return out


def decode_frames(
    plan: CanPlan, frames: Iterable[RawFrame], options: DecoderOptions | None = None
) -> tuple[list[StreamItem], DecoderStats]:
    """Pure twin of :class:`FrameDecoder`: every item of a finite frame sequence, and the counts."""
    dec = FrameDecoder(plan, options)
    items = dec.feed(list(frames))
    items += dec.finish()
    return items, dec.stats


# -- sources ---------------------------------------------------------------------------------------


class CanFrameSource(Source):
    """A source over batches of raw frames (a CAN log, raw frames replayed from a recording).

    Parameters
    ----------
    plan : CanPlan
    batches : iterable of sequences of RawFrame
    options : DecoderOptions
    metadata : extra layout metadata
    """

    def __init__(
        self,
        plan: CanPlan,
        batches: Iterable[Sequence[RawFrame]],
        options: DecoderOptions | None = None,
        metadata: dict[str, Any] | None = None,
    ) -> None:
        super().__init__()
        self.decoder = FrameDecoder(plan, options)
        self._batches = batches
        meta = dict(plan.layout.metadata)
        meta.update(metadata or {})
        self._layout = StreamLayout(plan.layout.groups, plan.layout.edge_channels, meta)

    @property
    def layout(self) -> StreamLayout:
        return self._layout

    @property
    def stats(self) -> DecoderStats:
        return self.decoder.stats

    def _iter_items(self) -> Iterator[StreamItem]:
        for batch in self._batches:
            yield from self.decoder.feed(batch)
        yield from self.decoder.finish()
        yield SourceEvent(
            "can_stats", self.decoder.stats.summary(), None, self.decoder.stats.total("lost")
        )


def message_to_frame(msg: Any) -> RawFrame:
    """A python-can ``Message`` as a :class:`RawFrame`."""
    return RawFrame(
        round(msg.timestamp * 1e9),
        msg.arbitration_id,
        bool(msg.is_extended_id),
        bytes(msg.data),
        bool(msg.is_fd),
    )


def bus_error_kind(msg: Any) -> str:
    """``bus_off``, ``error_passive`` or ``bus_error`` from an error frame (SocketCAN error classes)."""
    if msg.arbitration_id & 0x40:
        return "bus_off"
    if msg.arbitration_id & 0x04 and len(msg.data) > 1 and msg.data[1] & 0x30:
        return "error_passive"
    return "bus_error"


def open_bus(interface: str, channel: str, **kwargs: Any) -> Any:
    """``can.Bus`` with errors turned into one-line :class:`SourceError` messages."""
    import can

    if interface not in can.interfaces.VALID_INTERFACES:
        raise SourceError(
            f"unknown CAN interface {interface!r}; python-can knows: {', '.join(sorted(can.interfaces.VALID_INTERFACES))}"
        )
    try:
        return can.Bus(interface=interface, channel=channel, **kwargs)
    except (can.CanError, OSError, ImportError, ValueError, TypeError) as err:
        text = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise SourceError(f"cannot open CAN bus {interface}:{channel}: {text}") from None


_LOST = "lost"
_REOPENED = "reopened"
_STATE = "state"
_ERRORS = "errors"


class _Receiver(threading.Thread):
    """Reads the bus into a queue so that processing never stalls it; re-opens a bus that died."""

    def __init__(
        self,
        factory: Callable[[], Any],
        bus: Any,
        q: queue.SimpleQueue[Any],
        backoff: tuple[float, float],
        max_outage_s: float,
    ) -> None:
        super().__init__(name="can-rx", daemon=True)
        self.factory = factory
        self.bus = bus
        self.q = q
        self.backoff = backoff
        self.max_outage_s = max_outage_s
        self.stop = threading.Event()

    def run(self) -> None:
        import can

        last_state = None
        next_poll = 0.0
        while not self.stop.is_set():
            try:
                msg = self.bus.recv(0.05)
                now = time.monotonic()
                if now >= next_poll:
                    next_poll = now + 0.5
                    state = _bus_state(self.bus)
                    if state != last_state and state is not None:
                        if last_state is not None or state != "ACTIVE":
                            self.q.put((_STATE, state, time.time()))
                        last_state = state
            except (can.CanError, OSError, ValueError) as err:
                if self.stop.is_set():
                    return
                self.q.put(
                    (
                        _LOST,
                        str(err).strip().splitlines()[0]
                        if str(err).strip()
                        else type(err).__name__,
                        time.time(),
                    )
                )
                if not self._reopen():
                    return
                continue
            if msg is None:
                continue
            if msg.is_error_frame:
                self.q.put((_ERRORS, bus_error_kind(msg), msg.timestamp))
            elif not msg.is_remote_frame:
                self.q.put(msg)

    def _reopen(self) -> bool:
        t0 = time.monotonic()
        delay = self.backoff[0]
        try:
            self.bus.shutdown()
        except Exception:  # a dead bus may fail to shut down; we are replacing it anyway
            pass
        while not self.stop.is_set():
            if time.monotonic() - t0 > self.max_outage_s:
                self.q.put((_LOST, f"gave up re-opening after {self.max_outage_s:g} s", None))
                self.q.put(None)
                return False
            self.stop.wait(delay)
            try:
                self.bus = self.factory()
            except Exception:  # any driver error means "not back yet": keep trying with back-off
                delay = min(self.backoff[1], 2 * delay)
                continue
            self.q.put((_REOPENED, time.monotonic() - t0, time.time()))
            return True
        return False


def _bus_state(bus: Any) -> str | None:
    try:
        return str(bus.state.name)
    except (NotImplementedError, AttributeError):
        return None


class CanBusSource(Source):
    """Live CAN(-FD) source on any python-can interface.

    A receive thread moves frames to a queue; iteration decodes them in batches.
    The stream ends at the DAQ's stop frame (after ``stop_grace_s``), after
    ``idle_timeout_s`` without frames once data flowed, or at :meth:`close`.

    Parameters
    ----------
    plan : CanPlan
    interface, channel : python-can bus
    bus_kwargs : extra ``can.Bus`` arguments (bitrate, data_bitrate, fd, ...)
    bus_factory : builds the bus (default ``can.Bus``), also to re-open it
    options : DecoderOptions
    idle_timeout_s : end after this long without frames (None: never)
    stop_grace_s : keep reading this long after the stop frame (late frames)
    backoff_s : (first, longest) delay between re-open attempts
    max_outage_s : give up re-opening after this long
    frame_listener : called with every batch of raw frames (the recorder)
    """

    def __init__(
        self,
        plan: CanPlan,
        *,
        interface: str,
        channel: str,
        bus_kwargs: dict[str, Any] | None = None,
        bus_factory: Callable[[], Any] | None = None,
        options: DecoderOptions | None = None,
        idle_timeout_s: float | None = 10.0,
        stop_grace_s: float = 0.2,
        backoff_s: tuple[float, float] = (0.1, 5.0),
        max_outage_s: float = 60.0,
        frame_listener: Callable[[list[RawFrame]], None] | None = None,
        poll_s: float = 0.05,
    ) -> None:
        super().__init__()
        kwargs = dict(bus_kwargs or {})
        self._factory = bus_factory or (lambda: open_bus(interface, channel, **kwargs))
        self.decoder = FrameDecoder(plan, options)
        self.idle_timeout_s = idle_timeout_s
        self.stop_grace_s = stop_grace_s
        self.frame_listener = frame_listener
        self.poll_s = poll_s
        meta = dict(plan.layout.metadata)
        meta.update({"interface": interface, "channel": channel})
        self._layout = StreamLayout(plan.layout.groups, plan.layout.edge_channels, meta)
        self._q: queue.SimpleQueue[Any] = queue.SimpleQueue()
        bus = self._factory()
        self._rx = _Receiver(self._factory, bus, self._q, backoff_s, max_outage_s)
        self._rx.start()

    @property
    def layout(self) -> StreamLayout:
        return self._layout

    @property
    def stats(self) -> DecoderStats:
        return self.decoder.stats

    def _drain(self, timeout: float) -> tuple[list[RawFrame], list[SourceEvent], bool]:
        frames: list[RawFrame] = []
        events: list[SourceEvent] = []
        ended = False
        try:
            first = self._q.get(timeout=timeout)
        except queue.Empty:
            return frames, events, ended
        item = first
        while True:
            if item is None:
                ended = True
            elif isinstance(item, tuple):
                events.append(self._control(item))
            else:
                frames.append(message_to_frame(item))
            if len(frames) >= 20000:
                break
            try:
                item = self._q.get_nowait()
            except queue.Empty:
                break
        return frames, events, ended

    def _control(self, item: tuple[str, Any, float | None]) -> SourceEvent:
        kind, value, _ = item  # (kind, value, wall time)
        if kind == _ERRORS:
            self.decoder.stats.bus_errors += 1
            return SourceEvent(value, f"CAN {value.replace('_', ' ')} frame received", None)
        if kind == _STATE:
            what = {"PASSIVE": "error_passive", "ERROR": "bus_off", "ACTIVE": "bus_active"}.get(
                value, value.lower()
            )
            return SourceEvent(what, f"CAN controller state: {value.lower()}", None)
        if kind == _LOST:
            return SourceEvent(
                "bus_lost", f"CAN bus lost ({value}); re-opening, the gap will be flagged", None
            )
        return SourceEvent(
            "bus_reopened",
            f"CAN bus re-opened after {value:.2f} s; frames sent meanwhile are lost",
            None,
        )

    def _iter_items(self) -> Iterator[StreamItem]:
        last_frame = None
        stop_seen = None
        warned = False
        t_open = time.monotonic()
        while True:
            if self._closed:  # closed from another thread while nothing arrives
                return
            frames, events, ended = self._drain(self.poll_s)
            yield from events
            now = time.monotonic()
            if frames:
                last_frame = now
                if self.frame_listener is not None:
                    self.frame_listener(frames)
                yield from self.decoder.feed(frames)
            if ended:
                break
            if self.decoder.stopped_s is not None and stop_seen is None:
                stop_seen = now
            if stop_seen is not None and now - stop_seen >= self.stop_grace_s:
                break
            if (
                self.idle_timeout_s is not None
                and last_frame is not None
                and now - last_frame > self.idle_timeout_s
            ):
                yield SourceEvent(
                    "idle", f"no CAN frame for {self.idle_timeout_s:g} s: ending the acquisition"
                )
                break
            if last_frame is None and not warned and now - t_open > 2.0:
                warned = True
                yield SourceEvent("waiting", "no CAN frame yet; waiting for the DAQ to start")
        yield from self.decoder.finish()
        yield SourceEvent(
            "can_stats", self.decoder.stats.summary(), None, self.decoder.stats.total("lost")
        )

    def _shutdown(self) -> None:
        self._rx.stop.set()
        self._rx.join(timeout=2.0)
        try:
            self._rx.bus.shutdown()
        except Exception:  # shutting down a dead bus must not hide the caller's own error
            pass


CAN_OPTIONS = (
    "dbc",
    "bitrate",
    "data_bitrate",
    "fd",
    "bus_kwargs",
    "reorder_window_s",
    "idle_timeout_s",
    "stop_grace_s",
    "max_outage_s",
    "frame_listener",
    "block_s",
)


def open_can(arg: str, bench: Bench, **overrides: Any) -> CanBusSource:
    """The live source of ``--source can:INTERFACE:CHANNEL`` (either part defaults to ``[can]``).

    Overrides: ``dbc``, ``bitrate``, ``data_bitrate``, ``fd``, ``bus_kwargs``,
    ``reorder_window_s``, ``idle_timeout_s``, ``stop_grace_s``, ``max_outage_s``,
    ``frame_listener``.
    """
    bad = sorted(set(overrides) - set(CAN_OPTIONS))
    if bad:
        raise SourceError(
            f"source 'can:{arg}': unknown option {bad[0]!r}; known: {', '.join(CAN_OPTIONS)}"
        )
    interface, _, channel = arg.partition(":")
    cfg = bench.can
    interface = interface or cfg.interface
    channel = channel or cfg.channel
    plan = load_plan(bench, overrides.get("dbc"))
    fd = bool(overrides.get("fd", cfg.fd))
    if not fd:
        fd_msgs = [m.name for m in plan.messages if m.is_fd]
        if fd_msgs:
            raise SourceError(
                f"the DBC's {fd_msgs[0]} is a CAN FD frame but the bus is classic CAN (fd = false)"
            )
    kwargs: dict[str, Any] = {"fd": fd, "bitrate": int(overrides.get("bitrate", cfg.bitrate))}
    if fd:
        kwargs["data_bitrate"] = int(overrides.get("data_bitrate", cfg.data_bitrate))
    kwargs.update(overrides.get("bus_kwargs") or {})
    opts = DecoderOptions(
        reorder_window_s=float(overrides.get("reorder_window_s", DecoderOptions.reorder_window_s))
    )
    return CanBusSource(
        plan,
        interface=interface,
        channel=channel,
        bus_kwargs=kwargs,
        options=opts,
        idle_timeout_s=overrides.get("idle_timeout_s", 10.0),
        stop_grace_s=float(overrides.get("stop_grace_s", 0.2)),
        max_outage_s=float(overrides.get("max_outage_s", 60.0)),
        frame_listener=overrides.get("frame_listener"),
    )
