"""The raw stream's sample and edge blocks decoded for one recorded layout, fast for our writer's bytes.

A replay decodes every ``/raw/<group>`` and ``/raw/edges/<channel>`` message
of a recording on its source thread, which holds the GIL for whatever Python
that takes, beside the processing thread. Our writer's messages have a fixed
shape per group and per edge channel: the same bytes (the group's name, rate,
t0 and channel names; the edge channel's name) around a few numbers, then the
samples or the edge times. :class:`RawDecoder` matches a message's head
against those bytes and reads only the numbers; whatever does not match byte
for byte (another writer's field order, proto3 defaults left out otherwise, a
damaged head, a block that fails a check) goes to
:func:`replay.stream_codec.decode_samples` or
:func:`replay.stream_codec.decode_edges`, which read it field by field and say
what is wrong. A block it accepts is the one they give (tested on both kinds
of message, on every cut and bit flip of a head).

Measured on the 60 s log (/tmp/prof/live.mcap), GIL-held Python per block:
a sample block's head (its samples cut to two per channel, so that the head
is what counts) 7.3 us through decode_samples, 3.9 us here, 360 blocks a
minute; an edge block (the tacho's, 5.9 kB, 120 a minute) 10.3-11.5 us through
decode_edges (the protobuf class copies the times in, numpy copies them out), 3.7 us
here. The float32 -> float64 widening of the samples, which releases the GIL, is the
same either way.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

from acquisition.stream import EdgeBlock, SampleBlock, SampleGroup, StreamLayout
from replay import wire
from replay.stream_codec import MAX_INDEX, decode_edges, decode_samples

_TIME = b"\x09"  # time_s (field 1, float64), first in both messages: not needed
_NAME = b"\x12"  # group (SampleBlock) or channel (EdgeBlock): field 2, a string
_FIRST_INDEX, _N_SAMPLES, _SAMPLES = 0x18, 0x38, 0x42  # SampleBlock fields 3, 7, 8
_TIMES = 0x1A  # EdgeBlock field 3, float64 bytes
# What laying out a layout's name can raise: a lone surrogate is legal in the layout's JSON,
# not in UTF-8; a name that is not a string (a crafted layout)
_UNENCODABLE = (UnicodeEncodeError, AttributeError, TypeError, struct.error)


class RawDecoder:
    """The sample and edge blocks of one recorded layout (see the module docstring).

    Parameters
    ----------
    layout : the recording's layout.
    """

    def __init__(self, layout: StreamLayout) -> None:
        self.layout = layout
        # group field bytes (``group``, field 2) -> (group, bytes of fields 4-6, channels)
        self._groups: dict[bytes, tuple[SampleGroup, bytes, int]] = {}
        longest = 0
        seen: set[str] = set()
        for group in layout.groups:
            if group.name in seen:  # the first group of a name, as StreamLayout.group finds it
                continue
            seen.add(group.name)
            names = tuple(c.name for c in group.channels)
            try:
                rates = struct.pack("<dd", group.rate_hz, group.t0_s)
                name_field, fixed = wire.group_fields(group.name, rates, names)
            except _UNENCODABLE:  # a name our writer cannot have written: the slow path reads it
                continue
            self._groups.setdefault(name_field, (group, fixed, len(names)))
            longest = max(longest, len(name_field) + len(fixed))
        # time_s (9 bytes), three varints (10 bytes each) with their keys
        self._sample_head = 9 + longest + 3 * 11
        # channel field bytes (``channel``, field 2) -> the edge channel
        self._edges: dict[bytes, str] = {}
        for name in layout.edge_channels:
            try:
                self._edges.setdefault(wire.string_field(2, name), name)
            except _UNENCODABLE:
                continue
        self._edge_head = 9 + max((len(k) for k in self._edges), default=0) + 11

    def samples(self, data: bytes | memoryview) -> SampleBlock:
        """The :class:`SampleBlock` of a ``/raw/<group>`` message (as ``decode_samples``)."""
        head = bytes(data[: self._sample_head])
        try:
            entry, end = self._named(head, self._groups)
            if entry is None:
                return decode_samples(data, self.layout)
            group, fixed, n_ch = entry
            first_index = n = 0
            if end < len(data) and head[end] == _FIRST_INDEX:
                first_index, end = wire.read_varint(head, end + 1)
            if not head.startswith(fixed, end):
                return decode_samples(data, self.layout)
            end += len(fixed)
            if end < len(data) and head[end] == _N_SAMPLES:
                n, end = wire.read_varint(head, end + 1)
            n_bytes = 0  # no data field: an empty block
            if end < len(data):
                if head[end] != _SAMPLES:
                    return decode_samples(data, self.layout)
                n_bytes, end = wire.read_varint(head, end + 1)
        except (IndexError, wire.Unparsed):
            return decode_samples(data, self.layout)
        if not (
            end + n_bytes == len(data)
            and n_bytes == 4 * n_ch * n
            and n < 2**32
            and 0 <= first_index < MAX_INDEX
        ):
            return decode_samples(data, self.layout)  # (it says what is wrong)
        with np.errstate(invalid="ignore"):  # a signalling NaN stays a NaN: a sample known bad
            values = (
                np.frombuffer(data, dtype="<f4", count=n_ch * n, offset=end)
                .reshape(n_ch, n)
                .astype(np.float64)
            )
        values.flags.writeable = False  # (as decode_samples)
        return SampleBlock(group.name, first_index, values)

    def edges(self, data: bytes | memoryview) -> EdgeBlock:
        """The :class:`EdgeBlock` of a ``/raw/edges/<channel>`` message (as ``decode_edges``)."""
        head = bytes(data[: self._edge_head])
        try:
            channel, end = self._named(head, self._edges)
            n_bytes = 0  # no times field: no edges
            if end < len(data):
                if channel is None or head[end] != _TIMES:
                    return decode_edges(data, self.layout)
                n_bytes, end = wire.read_varint(head, end + 1)
        except (IndexError, wire.Unparsed):
            return decode_edges(data, self.layout)
        if channel is None or end + n_bytes != len(data) or n_bytes % 8:
            return decode_edges(data, self.layout)
        times = np.frombuffer(data, dtype="<f8", count=n_bytes // 8, offset=end).copy()
        if not np.isfinite(times).all():
            return decode_edges(data, self.layout)  # (it says which channel)
        return EdgeBlock(channel, times)

    @staticmethod
    def _named(head: bytes, known: dict[bytes, Any]) -> tuple[Any, int]:
        """``(what the name field at the head's start names in known, or None; the
        position after it)``, an optional time_s before it skipped; IndexError or
        Unparsed on a cut or damaged head."""
        pos = 9 if head[:1] == _TIME else 0  # (slices: an empty message is all defaults)
        end = pos
        if head[pos : pos + 1] == _NAME:
            size, end = wire.read_varint(head, pos + 1)
            end += size
        return known.get(head[pos:end]), end
