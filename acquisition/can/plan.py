"""The DBC plan: what each CAN message carries, in the source's terms (:class:`CanPlan`).

Plain frozen dataclasses: the DBC reader (:mod:`acquisition.can.dbc`) builds them; the
field codecs, the encoder and the decoder only read them, so none of those needs to know
the DBC conventions. The status frame's ``STATE`` values live here because the encoder
and the decoder must agree on them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from acquisition.stream import StreamLayout

STATE_RUNNING = 1
STATE_STOPPED = 2


@dataclass(frozen=True)
class IntField:
    """A byte-aligned integer field of a frame."""

    name: str
    byte: int
    n_bytes: int
    signed: bool
    big_endian: bool = False

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(
            f"{'>' if self.big_endian else '<'}{'i' if self.signed else 'u'}{self.n_bytes}"
        )

    @property
    def bits(self) -> int:
        return 8 * self.n_bytes


@dataclass(frozen=True)
class ChannelScaling:
    """Physical value ``raw * scale + offset`` in ``unit``; ``invalid_raw`` decodes to NaN."""

    scale: float
    offset: float
    unit: str
    raw_min: int
    raw_max: int
    invalid_raw: int

    def in_unit(self, unit: str, factor: float) -> ChannelScaling:
        """The same scaling giving values in ``unit``, ``factor`` times the old ones."""
        return replace(self, scale=self.scale * factor, offset=self.offset * factor, unit=unit)


@dataclass(frozen=True)
class MessagePlan:
    """What one DBC message carries, in the source's terms.

    Attributes
    ----------
    kind : ``"samples"``, ``"edges"`` or ``"status"``
    group : sample group (``"accel"``, ``"pressure"``, ``"rpm"``) or edge channel name.
    channels : channels of this message the source uses, in group-row order.
    rows : (n_ch,) int, each channel's row in its group's blocks.
    samples_per_frame : S (samples kind), or the most edges per frame (edges kind).
    rate_hz : samples/s per channel (samples kind), 0 otherwise.
    counter, crc : the frame counter and the optional CRC-16 field.
    payload : the integer fields the fast path reads: samples ``k * n_ch + c``
        (or ``EDGE_N``, ``EDGE_T0``, the deltas; ``STATE``, ``DAQ_TIME``).
    scalings : per channel, raw -> physical.
    signal_names : the sample signals in payload order (the cantools fallback).
    fast : every sample signal is a byte-aligned integer (else cantools decodes).
    tick_s : seconds per tick of edge times / ``DAQ_TIME``.
    """

    name: str
    frame_id: int
    is_extended_id: bool
    length: int
    is_fd: bool
    kind: Literal["samples", "edges", "status"]
    group: str
    channels: tuple[str, ...] = ()
    rows: tuple[int, ...] = ()
    samples_per_frame: int = 1
    rate_hz: float = 0.0
    counter: IntField | None = None
    crc: IntField | None = None
    payload: tuple[IntField, ...] = ()
    scalings: tuple[ChannelScaling, ...] = ()
    tick_s: float = 0.0
    signal_names: tuple[str, ...] = ()
    fast: bool = True
    cantools_message: Any = field(default=None, compare=False, repr=False)

    @property
    def key(self) -> tuple[int, bool]:
        return (self.frame_id, self.is_extended_id)

    @property
    def frame_rate_hz(self) -> float:
        return self.rate_hz / self.samples_per_frame if self.kind == "samples" else 0.0

    @property
    def counter_modulus(self) -> int:
        return 1 << self.counter.bits if self.counter is not None else 0


@dataclass(frozen=True)
class CanPlan:
    """The DBC messages a bench needs and the stream layout they make."""

    dbc_path: str
    messages: tuple[MessagePlan, ...]
    layout: StreamLayout
    dbc_ids: frozenset[tuple[int, bool]] = frozenset()  # every (id, extended) the DBC defines

    def by_key(self) -> dict[tuple[int, bool], MessagePlan]:
        return {m.key: m for m in self.messages}

    def describe(self) -> list[str]:
        """One line per message (for ``can-sim`` and error messages)."""
        out = []
        for m in self.messages:
            what = (
                f"{m.samples_per_frame} x {', '.join(m.channels)} at {m.rate_hz:g} Hz"
                if m.kind == "samples"
                else (f"edges of {m.group}" if m.kind == "edges" else "DAQ status")
            )
            out.append(
                f"0x{m.frame_id:X} {m.name} ({m.length} B{' FD' if m.is_fd else ''}): {what}"
            )
        return out
