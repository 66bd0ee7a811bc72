"""``replay.raw_decoder.RawDecoder`` (heads matched against the layout's bytes) reads what
``stream_codec.decode_samples`` and ``decode_edges`` read, block or error, on every message."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from google.protobuf.message import DecodeError

from acquisition.stream import ChannelSpec, EdgeBlock, SampleBlock, SampleGroup, StreamLayout
from replay import raw_decoder, stream_codec, wire
from replay.errors import BadMessage

CHANNELS = (ChannelSpec("x", "V"), ChannelSpec("y", "V"))
GROUPS = (
    SampleGroup("acc", 100.0, CHANNELS, 0.5),
    SampleGroup("p", 25600.0, CHANNELS[:1], 0.0),  # t0 = 0.0: left out of the head
    SampleGroup("z" * 130, 10.0, CHANNELS, -0.0),  # a name past one varint byte
)
EDGES = ("tacho", "cam", "")  # "": the name left out of the message
# a second group named "acc" (a crafted layout): decode_samples checks against the first
SHADOWED = SampleGroup("acc", 50.0, CHANNELS[:1])
LAYOUT = StreamLayout((*GROUPS, SHADOWED), EDGES)


def damaged(message: bytes, head: int) -> list[bytes]:
    """Every cut of ``message``, and two bit flips of each of its first ``head`` bytes."""
    out = [message[:cut] for cut in range(len(message))]
    for pos in range(head):
        for bit in (1, 0x80):
            flipped = bytearray(message)
            flipped[pos] ^= bit
            out.append(bytes(flipped))
    return out


def outcome(decode: Any, message: bytes) -> tuple[Any, ...]:
    try:
        block = decode(memoryview(message))
    except (BadMessage, DecodeError, ValueError) as err:
        return (type(err), str(err))
    data = block.data if isinstance(block, SampleBlock) else block.times_s
    name = block.group if isinstance(block, SampleBlock) else block.channel
    index = block.first_index if isinstance(block, SampleBlock) else None
    return (type(block), name, index, data.dtype, data.shape, data.tobytes(), data.flags.writeable)


def test_sample_blocks_read_as_decode_samples_reads_them(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(5)
    ours = []
    for group in GROUPS:
        for first, n in ((0, 3), (7, 1), (2**40, 200), (5, 0)):
            data = rng.standard_normal((len(group.channels), n)).astype("<f4")
            if data.size:
                data.flat[0] = np.float32(np.nan)
            block = SampleBlock(group.name, first, data)
            ours.append(stream_codec.encode_samples(block, group))
            ours.append(stream_codec.encode_samples_reference(block, group))
    base = ours[0]
    other = SampleGroup("acc", 100.0, CHANNELS[:1], 0.5)  # not this layout's channels
    odd = [
        base + wire.int_field(3, 9),  # index twice
        base + wire.int_field(3, -5),  # negative index
        base + wire.int_field(7, 2**32 + 3),  # n_samples wraps
        base + wire.int_field(9, 1),  # unknown field
        stream_codec.encode_samples(SampleBlock("acc", 1, np.ones((1, 2))), other),
        stream_codec.encode_samples(SampleBlock("acc", 1, np.ones((1, 2))), SHADOWED),
        stream_codec.encode_samples(  # a group not in the layout
            SampleBlock("q", 1, np.ones((2, 2))), dataclasses.replace(GROUPS[0], name="q")
        ),
        b"",
    ]
    decoder = raw_decoder.RawDecoder(LAYOUT)
    for message in ours + odd + damaged(base, len(base) - 24):
        expected = outcome(lambda m: stream_codec.decode_samples(m, LAYOUT), message)
        assert outcome(decoder.samples, message) == expected, message[:40]
    calls: list[Any] = []
    monkeypatch.setattr(raw_decoder, "decode_samples", lambda *a: calls.append(a))
    for message in ours[::2]:  # our writer's: the head matched, no field-by-field read
        decoder.samples(message)
    assert calls == [] and len(ours) == 24


def test_edge_blocks_read_as_decode_edges_reads_them(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(6)
    ours = []
    for channel in EDGES:
        for n, time_s in ((0, 0.0), (1, 0.25), (40, -0.0), (2000, 7.5)):
            times = np.sort(rng.uniform(0.0, 9.0, n))
            ours.append(stream_codec.encode_edges(EdgeBlock(channel, times), time_s))
    base = ours[2]
    cls = wire.bytes_field  # fields written by hand: duplicates, order, bad values
    odd = [
        base + wire.string_field(2, "cam"),  # the channel twice: the last wins
        cls(3, np.ones(2).tobytes()) + wire.string_field(2, "tacho"),  # fields reversed
        base + cls(3, np.ones(2).tobytes()),  # times twice: the last wins
        stream_codec.encode_edges(EdgeBlock("crank", np.ones(3)), 1.0),  # not in the layout
        stream_codec.encode_edges(EdgeBlock("tacho", np.array([1.0, np.inf])), 1.0),
        wire.string_field(2, "tacho") + cls(3, bytes(12)),  # not n x 8 bytes
        base + wire.int_field(9, 1),  # unknown field
        b"",
    ]
    decoder = raw_decoder.RawDecoder(LAYOUT)
    for message in ours + odd + damaged(base, 20):
        expected = outcome(lambda m: stream_codec.decode_edges(m, LAYOUT), message)
        assert outcome(decoder.edges, message) == expected, message[:40]
    calls: list[Any] = []
    monkeypatch.setattr(raw_decoder, "decode_edges", lambda *a: calls.append(a))
    for message in ours:  # our writer's: the head matched, no protobuf parse
        decoder.edges(message)
    assert calls == [] and len(ours) == 12


def test_names_that_do_not_encode_are_left_to_the_field_by_field_decoders() -> None:
    """A crafted layout: a lone surrogate (legal JSON, not UTF-8) in a group's name and in
    a channel's, a non-string edge channel; the other names keep the fast path."""
    odd_groups = (
        SampleGroup("\ud800", 10.0, CHANNELS),
        SampleGroup("q", 10.0, (ChannelSpec("\ud800", "V"),)),
    )
    layout = StreamLayout((*GROUPS, *odd_groups), (*EDGES, 5))  # type: ignore[arg-type]
    decoder = raw_decoder.RawDecoder(layout)
    block = SampleBlock("acc", 3, np.ones((2, 4)))
    message = stream_codec.encode_samples(block, GROUPS[0])
    assert outcome(decoder.samples, message) == outcome(
        lambda m: stream_codec.decode_samples(m, layout), message
    )
    edges = stream_codec.encode_edges(EdgeBlock("tacho", np.arange(3.0)), 0.0)
    assert outcome(decoder.edges, edges)[:2] == (EdgeBlock, "tacho")
    assert set(decoder._groups) == {wire.string_field(2, g.name) for g in GROUPS}
    assert set(decoder._edges.values()) == set(EDGES)
