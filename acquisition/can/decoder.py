"""CAN frames -> stream items: :class:`FrameDecoder` and its pure twin :func:`decode_frames`.

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
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from acquisition.can.fields import as_rows, frame_crc, raw_fields_slow, read_fields, scale_samples
from acquisition.can.frames import RawFrame
from acquisition.can.item_cuts import cut_edges, cut_samples, split_on_holes
from acquisition.can.plan import STATE_STOPPED, CanPlan, MessagePlan
from acquisition.can.reorder import DecoderOptions, GapReport, GroupAssembler, MessageStream
from acquisition.can.spans import next_received, received_spans
from acquisition.can.stats import DecoderStats, StreamStats
from acquisition.stream import EdgeBlock, SampleBlock, StreamItem, StreamLayout


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
        self._streams: dict[str, MessageStream] = {}
        self._groups: dict[str, GroupAssembler] = {}
        self._group_of: dict[str, GroupAssembler] = {}
        self._edge_last: dict[str, float] = {}
        self._gaps = GapReport(self.options.event_interval_s)
        self._clock: float | None = None  # min (receive time - DAQ time), s
        self._data_time = 0.0
        for g in plan.layout.groups:
            self._groups[g.name] = GroupAssembler(
                g.name, g.rate_hz, len(g.channels), self.options.reorder_window_s
            )
        for m in plan.messages:
            stats = self.stats.streams.setdefault(m.name, StreamStats())
            if m.kind == "samples":
                grp = self._groups[m.group]
                window = math.ceil(grp.window / m.samples_per_frame)
                s = MessageStream(m, window, stats)
                grp.members.append(s)
                self._group_of[m.name] = grp
            else:
                s = MessageStream(
                    m, self.options.edge_window_frames if m.kind == "edges" else 1, stats
                )
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
                    if f.is_extended_id:
                        self.stats.unknown_extended.add(f.arbitration_id)
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

    def _accept(self, s: MessageStream, n: int, t: float, payload: Any) -> None:
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
        _keep(s, n, payload)
        g.high = max(g.high, b)
        if s.modulus >= 1 << 32:  # an absolute DAQ counter dates the receive clock
            daq_t = b / g.rate
            self._clock = t - daq_t if self._clock is None else min(self._clock, t - daq_t)

    def _accept_edges(self, s: MessageStream, n: int, times: np.ndarray) -> None:
        if s.next_frame is None:
            s.next_frame = 0 if n <= s.window else n
        if n in s.received or n in s.recent:
            s.stats.duplicate += 1
            return
        if n < s.next_frame or n <= s.max_n - s.window:
            s.stats.late += 1
            return
        _keep(s, n, times)

    # -- output --------------------------------------------------------------------------------

    def _collect(self, final: bool) -> list[StreamItem]:
        # Items are cut on a grid of ``emit_chunk_s`` of data time and given out chunk by
        # chunk, every group's samples and every edge channel's edges of one chunk together:
        # a big batch (a CAN log read 5000 frames at a time) must not hand over seconds of
        # samples before the edges that give them their crank angle.
        chunk = self.options.emit_chunk_s
        items: list[tuple[int, int, StreamItem]] = []
        for gi, g in enumerate(self._groups.values()):
            step = max(1, round(chunk * g.rate))
            for blk in self._emit_group(g, final):
                for piece in cut_samples(blk, step):
                    items.append((piece.first_index // step, gi, piece))
        for s in self._streams.values():
            if s.plan.kind == "edges":
                eb = self._emit_edges(s, final)
                if eb is not None:
                    for k, edges in cut_edges(eb, chunk):
                        items.append((k, 100, edges))
        items.sort(key=lambda it: (it[0], it[1]))
        out: list[StreamItem] = [it[2] for it in items]
        if items:
            self._data_time = max(self._data_time, items[-1][0] * chunk)
        if not final:
            out += self._gaps.due(self._data_time)
        return out

    def _emit_group(self, g: GroupAssembler, final: bool) -> list[SampleBlock]:
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
            # frames up to ``stop`` are resolved: received, or lost if still missing
            stop = -(-limit // size) if final else limit // size
            while n in s.received or n < stop:
                if n not in s.received:
                    # a run of missing frames is counted at once, not frame by frame: after
                    # a receive time far ahead (a corrupt log timestamp) it can be 1e13 long
                    m = min(next_received(s, n), stop)
                    s.stats.lost += m - n
                    lost_from = n if lost_from is None else lost_from
                    n = m
                    continue
                if lost_from is not None:
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
        # Built per run of received frames: a span no member received (an outage, or
        # frames dated far ahead by a corrupt log timestamp) is never allocated.
        blocks: list[SampleBlock] = []
        for a, b in received_spans(g, i0, upto):
            data = np.empty((g.n_ch, b - a))
            for s in g.members:
                size = s.plan.samples_per_frame
                f0, f1 = a // size, -(-b // size)
                hole = np.full((size, len(s.plan.rows)), np.nan)
                # one copy per member: the frames (received or NaN) end to end, then the window
                run = np.concatenate([s.received.get(n, hole) for n in range(f0, f1)])
                data[list(s.plan.rows)] = run[a - f0 * size : b - f0 * size].T
            blocks += split_on_holes(g.name, a, data)
        for s in g.members:
            size = s.plan.samples_per_frame
            f0 = i0 // size
            for n in [k for k in s.received if f0 <= k and (k + 1) * size <= upto]:
                del s.received[n]
                s.recent.add(n)
            s.forget_before(f0)
        g.next_index = upto
        return blocks

    def _report_lost(self, s: MessageStream, g: GroupAssembler, n0: int, n1: int) -> None:
        size = s.plan.samples_per_frame
        what = f"frame(s) of {s.plan.name} ({', '.join(s.plan.channels)})"
        self._gaps.add(g.name, what, n1 - n0, n0 * size / g.rate, n1 * size / g.rate)

    def _emit_edges(self, s: MessageStream, final: bool) -> EdgeBlock | None:
        if s.next_frame is None:
            return None
        ch = s.plan.group
        parts = []
        n = s.next_frame
        lost = 0
        stop = s.max_n + 1 if final else s.max_n - s.window + 1
        while n in s.received or n < stop:
            times = s.received.pop(n, None)
            if times is None:
                m = min(next_received(s, n), stop)  # the whole missing run at once
                s.stats.lost += m - n
                lost += m - n
                n = m
                continue
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


def decode_frames(
    plan: CanPlan, frames: Iterable[RawFrame], options: DecoderOptions | None = None
) -> tuple[list[StreamItem], DecoderStats]:
    """Pure twin of :class:`FrameDecoder`: every item of a finite frame sequence, and the counts."""
    dec = FrameDecoder(plan, options)
    items = dec.feed(list(frames))
    items += dec.finish()
    return items, dec.stats


def _keep(s: MessageStream, n: int, payload: Any) -> None:
    """Store frame ``n`` of a message stream (accepted: neither duplicate nor late)."""
    s.received[n] = payload
    s.stats.frames += 1
    if n < s.max_n:
        s.stats.out_of_order += 1
    s.max_n = max(s.max_n, n)
