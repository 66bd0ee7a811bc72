"""The simulated DAQ: stream items -> CAN frames (:class:`FrameEncoder` and its pure encoders).

The inverse of the decoder, used by ``can-sim`` and the tests to put a simulated
acquisition on a (virtual) bus. It writes the fields the decoder reads with
:func:`~acquisition.can.fields.read_fields`, and falls back to cantools for DBCs the
fast path cannot read, like the decoder does.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from acquisition.can.fields import frame_crc
from acquisition.can.plan import STATE_RUNNING, STATE_STOPPED, CanPlan, IntField, MessagePlan
from acquisition.stream import EdgeBlock, SampleBlock, SourceError, StreamItem, StreamLayout


def _write_fields(rows: np.ndarray, fields: Sequence[IntField], values: np.ndarray) -> None:
    """Inverse of :func:`read_fields`: ``values`` (n, n_fields) into ``rows`` (n, length) uint8."""
    for i, f in enumerate(fields):
        v = values[:, i].astype(f.dtype)
        rows[:, f.byte : f.byte + f.n_bytes] = v.view(np.uint8).reshape(-1, f.n_bytes)


def _finish_rows(plan: MessagePlan, rows: np.ndarray) -> list[bytes]:
    if plan.crc is not None:
        crc = np.array([frame_crc(r.tobytes(), plan.crc) for r in rows], dtype=np.int64)
        _write_fields(rows, [plan.crc], crc[:, None])
    buf = rows.tobytes()
    n = plan.length
    return [buf[i * n : (i + 1) * n] for i in range(rows.shape[0])]


def encode_sample_frames(
    plan: MessagePlan, first_frame: int, values: np.ndarray
) -> tuple[list[bytes], int]:
    """Frames ``first_frame ..`` holding ``values`` (n_frames, S, n_ch), physical units.

    NaN becomes the invalid raw value; values beyond the signal's range are clipped
    to it. Returns the payloads and the number of clipped samples.
    """
    n = values.shape[0]
    raw = np.empty(values.shape, dtype=np.int64)
    clipped = 0
    for c, sc in enumerate(plan.scalings):
        x = (values[:, :, c] - sc.offset) / sc.scale
        bad = ~np.isfinite(x)
        r = np.rint(np.where(bad, 0.0, x))
        beyond = (r < sc.raw_min) | (r > sc.raw_max)
        clipped += int(np.count_nonzero(beyond & ~bad))
        r = np.clip(r, sc.raw_min, sc.raw_max).astype(np.int64)
        r[bad] = sc.invalid_raw
        raw[:, :, c] = r
    rows = np.zeros((n, plan.length), dtype=np.uint8)
    assert plan.counter is not None
    seq = (np.arange(first_frame, first_frame + n) % plan.counter_modulus)[:, None]
    _write_fields(rows, [plan.counter], seq)
    if plan.fast:
        _write_fields(rows, plan.payload, raw.reshape(n, -1))
        return _finish_rows(plan, rows), clipped
    # a DBC the fast path cannot read: cantools encodes, signal by signal
    msg = plan.cantools_message
    flat = raw.reshape(n, -1)
    out: list[bytes] = []
    for i in range(n):
        sigs = {name: int(flat[i, j]) for j, name in enumerate(plan.signal_names)}
        for s in msg.signals:
            sigs.setdefault(s.name, 0)
        sigs[plan.counter.name] = int(seq[i, 0])
        data = bytearray(msg.encode(sigs, scaling=False, padding=False, strict=False))
        if plan.crc is not None:
            c = frame_crc(bytes(data), plan.crc)
            data[plan.crc.byte : plan.crc.byte + 2] = np.array([c], plan.crc.dtype).tobytes()
        out.append(bytes(data))
    return out, clipped


def encode_edge_frames(
    plan: MessagePlan, first_frame: int, frames: Sequence[np.ndarray]
) -> list[bytes]:
    """Edge frames ``first_frame ..``, one per array of edge times in ticks (int64, increasing)."""
    n = len(frames)
    k = plan.samples_per_frame
    values = np.zeros((n, len(plan.payload)), dtype=np.int64)
    for i, ticks in enumerate(frames):
        if not 1 <= ticks.size <= k:
            raise SourceError(f"{plan.name}: an edge frame holds 1..{k} edges, got {ticks.size}")
        values[i, 0] = ticks.size
        values[i, 1] = ticks[0]
        values[i, 2 : 1 + ticks.size] = ticks[1:] - ticks[0]
    rows = np.zeros((n, plan.length), dtype=np.uint8)
    assert plan.counter is not None
    seq = (np.arange(first_frame, first_frame + n) % plan.counter_modulus)[:, None]
    _write_fields(rows, [plan.counter], seq)
    _write_fields(rows, plan.payload, values)
    return _finish_rows(plan, rows)


def encode_status_frame(plan: MessagePlan, state: int, daq_time_s: float, seq: int = 0) -> bytes:
    rows = np.zeros((1, plan.length), dtype=np.uint8)
    _write_fields(
        rows, plan.payload, np.array([[state, round(daq_time_s / plan.tick_s)]], dtype=np.int64)
    )
    if plan.counter is not None:
        _write_fields(rows, [plan.counter], np.array([[seq % plan.counter_modulus]]))
    return _finish_rows(plan, rows)[0]


class TxFrame(NamedTuple):
    """A frame the simulated DAQ transmits at DAQ time ``time_s``."""

    time_s: float
    message: MessagePlan
    frame_no: int
    data: bytes


class FrameEncoder:
    """The simulated DAQ: stream items in, CAN frames out (with their DAQ transmit times).

    A sample frame leaves when its last sample is taken (``(k + 1) / rate`` after
    the start, for its last sample ``k``). Edges are packed into frames of at most
    ``S`` edges that never span an ``edge_slot_s`` slot, so a frame waits at most
    one slot: it leaves at its last edge when full, at the slot end otherwise.
    Frame counters start at 0 with the acquisition. Sample streams must start at
    index 0 (the simulator's do).
    """

    def __init__(
        self,
        plan: CanPlan,
        layout: StreamLayout,
        *,
        edge_slot_s: float = 0.01,
        status_period_s: float = 1.0,
    ) -> None:
        self.plan = plan
        self.edge_slot_s = edge_slot_s
        self.status_period_s = status_period_s
        self.clipped = 0
        self._sample: dict[str, list[tuple[MessagePlan, np.ndarray]]] = {}
        self._pending: dict[str, np.ndarray] = {}  # message -> (n_ch, k) samples not yet framed
        self._next_index: dict[str, int] = {}
        self._frame_no: dict[str, int] = {}
        for m in plan.messages:
            if m.kind == "samples":
                try:
                    g = layout.group(m.group)
                except KeyError:
                    raise SourceError(
                        f"the source has no group {m.group!r} for DBC message {m.name}"
                    ) from None
                if abs(g.rate_hz - m.rate_hz) > 1e-9 * m.rate_hz:
                    raise SourceError(
                        f"DBC message {m.name} carries {m.group} at {m.rate_hz:g} Hz but the source samples it "
                        f"at {g.rate_hz:g} Hz (set the bench's rate or the DBC's PtiSampleRate)"
                    )
                rows = np.array([g.index_of(c) for c in m.channels])
                self._sample.setdefault(m.group, []).append((m, rows))
                self._pending[m.name] = np.zeros((len(m.channels), 0))
                self._next_index[m.name] = 0
            if m.kind == "edges" and m.group not in layout.edge_channels:
                raise SourceError(
                    f"the source has no edge channel {m.group!r} for DBC message {m.name}"
                )
            self._frame_no[m.name] = 0
        self._edges = {m.group: m for m in plan.messages if m.kind == "edges"}
        self._edge_buf: dict[str, list[int]] = {c: [] for c in self._edges}
        self._edge_slot: dict[str, int] = {c: -1 for c in self._edges}
        self._status = next((m for m in plan.messages if m.kind == "status"), None)
        self._next_status = 0.0

    def encode(self, item: StreamItem) -> list[TxFrame]:
        """Frames completed by one stream item (any other item kind gives none)."""
        if isinstance(item, SampleBlock):
            return self._samples(item)
        if isinstance(item, EdgeBlock) and item.channel in self._edges:
            return self._edge_times(item.channel, item.times_s)
        return []

    def status(self, t_s: float) -> list[TxFrame]:
        """The periodic "running" status frames due up to DAQ time ``t_s``."""
        out = []
        while self._status is not None and self._next_status <= t_s:
            t = self._next_status
            out.append(self._status_frame(STATE_RUNNING, t, t))
            self._next_status += self.status_period_s
        return out

    def finish(self, end_s: float) -> list[TxFrame]:
        """Flush partial frames (the last sample frame padded with invalid samples) and send the stop."""
        out: list[TxFrame] = []
        for members in self._sample.values():
            for m, _ in members:
                buf = self._pending[m.name]
                if buf.shape[1]:
                    pad = m.samples_per_frame - buf.shape[1]
                    self._pending[m.name] = np.concatenate(
                        [buf, np.full((buf.shape[0], pad), np.nan)], axis=1
                    )
                    out += self._emit_samples(m, end_s)
        for c in self._edges:
            out += self._close_edges(c, last_time=None)
        out += self.status(end_s)
        if self._status is not None:
            out.append(self._status_frame(STATE_STOPPED, end_s, end_s))
        return out

    def _status_frame(self, state: int, daq_t: float, tx_t: float) -> TxFrame:
        assert self._status is not None
        n = self._frame_no[self._status.name]
        self._frame_no[self._status.name] = n + 1
        return TxFrame(tx_t, self._status, n, encode_status_frame(self._status, state, daq_t, n))

    def _samples(self, block: SampleBlock) -> list[TxFrame]:
        out: list[TxFrame] = []
        for m, rows in self._sample.get(block.group, []):
            if block.first_index != self._next_index[m.name]:
                raise SourceError(
                    f"{block.group}: the DAQ encoder needs consecutive samples from index 0, got index "
                    f"{block.first_index} after {self._next_index[m.name]}"
                )
            self._next_index[m.name] += block.n_samples
            self._pending[m.name] = np.concatenate(
                [self._pending[m.name], block.data[rows]], axis=1
            )
            out += self._emit_samples(m, None)
        return out

    def _emit_samples(self, m: MessagePlan, end_s: float | None) -> list[TxFrame]:
        buf = self._pending[m.name]
        s = m.samples_per_frame
        n = buf.shape[1] // s
        if n == 0:
            return []
        values = buf[:, : n * s].reshape(len(m.channels), n, s).transpose(1, 2, 0)
        self._pending[m.name] = buf[:, n * s :]
        first = self._frame_no[m.name]
        self._frame_no[m.name] = first + n
        datas, clipped = encode_sample_frames(m, first, values)
        self.clipped += clipped
        times = (np.arange(first, first + n) + 1) * s / m.rate_hz
        if end_s is not None:
            times = np.minimum(times, end_s)
        return [
            TxFrame(float(t), m, first + i, d)
            for i, (t, d) in enumerate(zip(times, datas, strict=True))
        ]

    def _edge_times(self, channel: str, times_s: np.ndarray) -> list[TxFrame]:
        m = self._edges[channel]
        ticks = np.rint(np.asarray(times_s) / m.tick_s).astype(np.int64)
        slots = np.floor(np.asarray(times_s) / self.edge_slot_s).astype(np.int64)
        out: list[TxFrame] = []
        buf = self._edge_buf[channel]
        for tick, slot in zip(ticks.tolist(), slots.tolist(), strict=True):
            if buf and slot != self._edge_slot[channel]:
                out += self._close_edges(channel, last_time=None)
            self._edge_slot[channel] = slot
            buf.append(tick)
            if len(buf) == m.samples_per_frame:
                out += self._close_edges(channel, last_time=tick * m.tick_s)
        return out

    def _close_edges(self, channel: str, last_time: float | None) -> list[TxFrame]:
        buf = self._edge_buf[channel]
        if not buf:
            return []
        m = self._edges[channel]
        n = self._frame_no[m.name]
        self._frame_no[m.name] = n + 1
        data = encode_edge_frames(m, n, [np.array(buf, dtype=np.int64)])[0]
        t = (
            last_time
            if last_time is not None
            else (self._edge_slot[channel] + 1) * self.edge_slot_s
        )
        buf.clear()
        return [TxFrame(t, m, n, data)]
