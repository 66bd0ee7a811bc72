"""Encode and decode the raw stream's messages and the recorded layout (no file I/O).

Symmetric pairs: every ``encode_*`` returns the serialised protobuf bytes of a
:mod:`replay.schemas` message (``/raw/<group>``, ``/raw/edges/<channel>``,
``/events``, ``/raw/can``), the matching ``decode_*`` gives back the item the
source handed to the pipeline. Raw samples travel as float32 (the pipeline has
already rounded them, see ``ptinertia.stage_threads.as_recorded``) and edge times as
float64, so a decoded item equals the original bit for bit. A message that does
not fit the recorded layout raises :class:`replay.errors.BadMessage`; the reader
skips it and reports it. What the live run computed (order frames, gating,
estimates) is :mod:`replay.results_codec`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence

import numpy as np

from acquisition.can.frames import RawFrame
from acquisition.files.csvwriter import json_default
from acquisition.stream import (
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SampleGroup,
    SourceEvent,
    StreamLayout,
)
from replay import wire
from replay.errors import BadMessage
from replay.mcap_output import LateBytes
from replay.schemas import wire_class

# -- raw items ---------------------------------------------------------------------------------


def sample_time(block: SampleBlock, group: SampleGroup) -> float:
    """Time of the block's first sample, s."""
    return group.t0_s + block.first_index / group.rate_hz


def encode_samples(block: SampleBlock, group: SampleGroup) -> bytes:
    """``/raw/<group>``: the block as float32, channel-major."""
    data = np.ascontiguousarray(block.data, dtype="<f4")
    return _sample_head(block, group, data) + data.tobytes()


def _sample_head(block: SampleBlock, group: SampleGroup, data: np.ndarray) -> bytes:
    """The ``/raw/<group>`` message before its float32 bytes (``wire.sample_block_head``),
    ``data`` (the block's samples, any dtype) checked against the group's channels."""
    if data.shape != (len(group.channels), block.n_samples):
        raise ValueError(
            f"sample block of group {group.name!r}: expected {len(group.channels)} channels, "
            f"got data of shape {block.data.shape}"
        )
    return wire.sample_block_head(
        sample_time(block, group),
        group.name,
        int(block.first_index),
        group.rate_hz,
        group.t0_s,
        [c.name for c in group.channels],
        block.n_samples,
        4 * data.size,
    )


class LateSamples(LateBytes):
    """``/raw/<group>`` as :func:`encode_samples` gives it, the float32 cast and the copy
    left to the writer thread (:class:`replay.mcap_output.LateBytes`).

    The block's array is kept, not copied, until its chunk is written: only a read-only
    array (the pipeline's, ``ptinertia.stage_threads.as_recorded``, and a replay's), which
    nobody can write to in between. A writable one may be a caller's buffer, refilled for
    the next block: it is encoded at once.
    Measured (rec_whole.py, 60 s of 9 channels at 25.6 kHz, 360 blocks): the cast and the
    two copies cost the processing thread 41 ms a minute; the head is about 4 ms.
    """

    __slots__ = ("data", "head")

    def __init__(self, head: bytes, data: np.ndarray) -> None:
        super().__init__(len(head) + 4 * data.size)
        self.head, self.data = head, data

    def write_into(self, view: memoryview) -> None:
        n = len(self.head)
        view[:n] = self.head
        if self.data.size:  # numpy's cast releases the GIL: it runs beside the processing thread
            out = np.frombuffer(view, dtype="<f4", count=self.data.size, offset=n)
            np.copyto(out.reshape(self.data.shape), self.data, casting="unsafe")


def encode_samples_late(block: SampleBlock, group: SampleGroup) -> bytes | LateSamples:
    """:func:`encode_samples` as :class:`LateSamples` for a read-only numeric array; plain
    bytes for any other (a writable array may be refilled by its owner before the writer
    thread reads it; a conversion of a non-numeric one may fail: here, on the caller's
    thread)."""
    data = block.data
    if not (
        isinstance(data, np.ndarray)
        and data.dtype.kind in "fiu"
        and data.ndim == 2
        and not data.flags.writeable
    ):
        return encode_samples(block, group)
    return LateSamples(_sample_head(block, group, data), data)


def encode_samples_reference(block: SampleBlock, group: SampleGroup) -> bytes:
    """:func:`encode_samples` through the protobuf class, for the tests to compare with."""
    data = np.ascontiguousarray(block.data, dtype="<f4")
    msg = wire_class("SampleBlock")(
        time_s=sample_time(block, group),
        group=group.name,
        first_index=int(block.first_index),
        rate_hz=group.rate_hz,
        t0_s=group.t0_s,
        channels=[c.name for c in group.channels],
        n_samples=block.n_samples,
        data=data.tobytes(),
    )
    return bytes(msg.SerializeToString())


# A sample index no recording reaches (2**53: where float64 times stop being exact).
MAX_INDEX = 2**53


def decode_samples(data: bytes | memoryview, layout: StreamLayout) -> SampleBlock:
    """A :class:`SampleBlock` with float64 data holding the recorded float32 values.

    Parsed by the protobuf class: the replay reads our writer's blocks with
    :class:`replay.raw_decoder.RawDecoder`, which hands every other layout of the bytes
    (another writer's, a damaged one) to this function.
    """
    msg = wire_class("SampleBlock").FromString(data)
    name, first_index, channels = msg.group, msg.first_index, list(msg.channels)
    samples, n = memoryview(msg.data), msg.n_samples
    try:
        group = layout.group(name)
    except KeyError:
        raise BadMessage(f"sample group {name!r} is not in the recorded layout") from None
    names = tuple(c.name for c in group.channels)
    if tuple(channels) != names:
        raise BadMessage(
            f"group {name!r}: channels {list(channels)} differ from the layout's {list(names)}"
        )
    n_ch, n = len(names), int(n)
    if len(samples) != 4 * n_ch * n:
        raise BadMessage(
            f"group {name!r}: {len(samples)} data bytes, expected {4 * n_ch * n} "
            f"({n_ch} channels x {n} samples x 4)"
        )
    if not 0 <= first_index < MAX_INDEX:
        raise BadMessage(f"group {name!r}: first sample index {first_index} out of range")
    with np.errstate(invalid="ignore"):  # a signalling NaN stays a NaN: a sample known bad
        values = np.frombuffer(samples, dtype="<f4").reshape(n_ch, n).astype(np.float64)
    values.flags.writeable = False  # (a re-recording may cast them late: encode_samples_late)
    return SampleBlock(group.name, int(first_index), values)


def encode_edges(block: EdgeBlock, time_s: float) -> bytes:
    """``/raw/edges/<channel>``: edge times as float64."""
    times = np.ascontiguousarray(block.times_s, dtype="<f8")
    msg = wire_class("EdgeBlock")(time_s=time_s, channel=block.channel, times_s=times.tobytes())
    return bytes(msg.SerializeToString())


def decode_edges(data: bytes | memoryview, layout: StreamLayout) -> EdgeBlock:
    msg = wire_class("EdgeBlock").FromString(data)
    if msg.channel not in layout.edge_channels:
        raise BadMessage(f"edge channel {msg.channel!r} is not in the recorded layout")
    if len(msg.times_s) % 8:
        raise BadMessage(f"edge channel {msg.channel!r}: {len(msg.times_s)} bytes is not n x 8")
    times = np.frombuffer(msg.times_s, dtype="<f8").copy()
    if not np.isfinite(times).all():
        raise BadMessage(f"edge channel {msg.channel!r}: edge times not finite")
    return EdgeBlock(msg.channel, times)


def encode_event(event: SourceEvent, origin: str, time_s: float) -> bytes:
    """``/events``: origin ``"source"`` (a raw stream item) or ``"dsp"``."""
    msg = wire_class("SourceEvent")(
        time_s=event.time_s if event.time_s is not None else time_s,
        kind=event.kind,
        message=event.message,
        has_time=event.time_s is not None,
        count=int(event.count),
        origin=origin,
    )
    return bytes(msg.SerializeToString())


def decode_event(data: bytes) -> tuple[str, SourceEvent]:
    """``(origin, event)``."""
    msg = wire_class("SourceEvent").FromString(data)
    event = SourceEvent(msg.kind, msg.message, msg.time_s if msg.has_time else None, int(msg.count))
    return msg.origin, event


def encode_can(frames: Sequence[RawFrame], time_s: float) -> bytes:
    """``/raw/can``: a batch of :class:`acquisition.can.frames.RawFrame` as columns."""
    msg = wire_class("CanFrames")(
        time_s=time_s,
        timestamp_ns=[int(f.timestamp_ns) for f in frames],
        arbitration_id=[int(f.arbitration_id) for f in frames],
        flags=[(1 if f.is_extended_id else 0) | (2 if f.is_fd else 0) for f in frames],
        length=[len(f.data) for f in frames],
        data=b"".join(bytes(f.data) for f in frames),
    )
    return bytes(msg.SerializeToString())


def decode_can(data: bytes) -> list[RawFrame]:
    """The batch of ``RawFrame`` as received."""
    msg = wire_class("CanFrames").FromString(data)
    n = len(msg.timestamp_ns)
    if not (len(msg.arbitration_id) == len(msg.flags) == len(msg.length) == n):
        raise BadMessage(f"CAN batch at {msg.time_s:.3f} s: columns of different lengths")
    if sum(msg.length) != len(msg.data):
        raise BadMessage(
            f"CAN batch at {msg.time_s:.3f} s: {len(msg.data)} data bytes, lengths say {sum(msg.length)}"
        )
    frames, pos = [], 0
    payload = bytes(msg.data)
    for t, can_id, flags, size in zip(
        msg.timestamp_ns, msg.arbitration_id, msg.flags, msg.length, strict=True
    ):
        frames.append(
            RawFrame(t, can_id, bool(flags & 1), payload[pos : pos + size], bool(flags & 2))
        )
        pos += size
    return frames


# -- layout ------------------------------------------------------------------------------------


def layout_to_json(layout: StreamLayout) -> str:
    """The layout (groups, edge channels, metadata) as JSON; floats round-trip exactly."""
    doc = {
        "groups": [
            {
                "name": g.name,
                "rate_hz": g.rate_hz,
                "t0_s": g.t0_s,
                "channels": [{"name": c.name, "unit": c.unit} for c in g.channels],
            }
            for g in layout.groups
        ],
        "edge_channels": list(layout.edge_channels),
        "metadata": layout.metadata,
    }
    return json.dumps(doc, default=json_default)


def layout_from_json(text: str) -> StreamLayout:
    """The layout :func:`layout_to_json` wrote."""
    doc = json.loads(text)
    groups = tuple(
        SampleGroup(
            name=str(g["name"]),
            rate_hz=float(g["rate_hz"]),
            channels=tuple(ChannelSpec(str(c["name"]), str(c["unit"])) for c in g["channels"]),
            t0_s=float(g.get("t0_s", 0.0)),
        )
        for g in doc["groups"]
    )
    return StreamLayout(
        groups,
        tuple(str(e) for e in doc.get("edge_channels", ())),
        dict(doc.get("metadata") or {}),
    )
