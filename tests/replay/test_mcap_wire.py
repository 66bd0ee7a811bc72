"""The hand-laid protobuf bytes of order frames and sample blocks against the protobuf classes.

``replay.wire`` writes the two most frequent messages without the protobuf
library; ``stream_codec.encode_samples_reference`` and
``results_codec.encode_frame_reference`` build them through it. A third-party
reader (the public classes of ``replay.schemas``) must read the same message
from both, bit for bit.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from google.protobuf.message import DecodeError
from support.mcap_logs import make_frame

from acquisition.stream import ChannelSpec, SampleBlock, SampleGroup, StreamLayout
from dsp.frames import OrderFrame
from estimator.outcome import FrameOutcome
from replay import results_codec, stream_codec, wire
from replay.errors import BadMessage
from replay.schemas import message_class, wire_class


def frame(
    orders: tuple[float, ...],
    channels: tuple[str, ...],
    amplitudes: np.ndarray,
    flags: frozenset[str] = frozenset(),
    ok: np.ndarray | None = None,
) -> OrderFrame:
    n_ch = len(channels)
    return OrderFrame(
        time_s=0.0,
        rpm=3000.0,
        crank_angle_rad=-0.0,
        orders=orders,
        channels=channels,
        amplitudes=amplitudes,
        channel_ok=np.ones(n_ch, bool) if ok is None else ok,
        rpm_change=0.0,
        leakage=np.linspace(0.0, 1e-3, n_ch),
        flags=flags,
    )


def corner_frames() -> list[OrderFrame]:
    rng = np.random.default_rng(11)
    frames = [make_frame(t, rng) for t in (0.0, 0.25, 0.75)]  # NaN amplitude, ok False, a flag
    channels = tuple(f"s{i // 3}_{'xyz'[i % 3]}" for i in range(10))
    amp = rng.standard_normal((3, 10)) + 1j * rng.standard_normal((3, 10))
    amp[0, 0] = 0.0  # magnitude and phase 0: fields the protobuf library leaves out
    amp[0, 1] = complex(-0.0, -0.0)
    amp[1, 2] = complex(-1.0, 0.0)  # phase 180 deg
    amp[2, 3] = complex(math.inf, 1.0)
    ok = np.arange(10) % 4 != 0
    frames += [
        frame((1.0, 1.5, 3.0), channels, amp, frozenset({"nan", "clipped", "cycle_ambiguous"}), ok),
        frame((), channels, np.zeros((0, 10), complex)),
        frame((2.0,), ("x" * 200,), np.array([[1 + 2j]])),  # lengths past one varint byte
        frame((0.5, 1.0), ("é", ""), np.ones((2, 2), complex)),  # non-ASCII and empty names
    ]
    return frames


@pytest.mark.parametrize("k", range(len(corner_frames())))
def test_order_frame_reads_as_the_protobuf_built_one(k: int) -> None:
    f = corner_frames()[k]
    fast, reference = results_codec.encode_frame(f), results_codec.encode_frame_reference(f)
    cls = message_class("OrderFrame")
    assert cls.FromString(fast).SerializeToString() == reference
    back = results_codec.decode_frame(fast)
    assert back.amplitudes.tobytes() == np.asarray(f.amplitudes, complex).tobytes()
    assert back.leakage.tobytes() == np.asarray(f.leakage, float).tobytes()
    np.testing.assert_array_equal(back.channel_ok, f.channel_ok)
    assert (back.orders, back.channels, back.flags) == (f.orders, f.channels, f.flags)
    for name in ("time_s", "rpm", "crank_angle_rad", "rpm_change"):
        assert np.float64(getattr(back, name)).tobytes() == np.float64(getattr(f, name)).tobytes()


def test_order_frame_of_the_wrong_shape_is_refused() -> None:
    f = make_frame(0.1, np.random.default_rng(0))
    results_codec.encode_frame(f)  # caches the layout of 3 orders x 4 channels
    bad = frame(f.orders, f.channels, np.ones((3, 3), complex))
    with pytest.raises(ValueError, match=r"expected amplitudes of shape \(3, 4\)"):
        results_codec.encode_frame(bad)


def test_a_block_of_frames_is_encoded_as_each_frame_alone() -> None:
    # runs of one layout (the recorder's blocks) and changes of layout between them;
    # each frame alone is checked against the protobuf classes above
    rng = np.random.default_rng(5)
    frames = [make_frame(0.1 * k, rng) for k in range(6)] + corner_frames() * 2
    frames += [make_frame(9.0 + k, rng) for k in range(3)]
    alone = [results_codec.encode_frame(f) for f in frames]
    assert results_codec.encode_frames(frames) == alone
    assert results_codec.encode_frames(frames[:1]) == alone[:1]
    assert results_codec.encode_frames([]) == []


def test_a_frame_of_the_wrong_shape_in_a_block_is_named() -> None:
    rng = np.random.default_rng(1)
    good = [make_frame(t, rng) for t in (0.1, 0.2)]
    bad = dataclasses.replace(good[1], time_s=0.15, leakage=np.zeros(3))
    with pytest.raises(ValueError, match=r"order frame at 0.15 s: .* got \(3, 4\), \(4,\), \(3,\)"):
        results_codec.encode_frames([good[0], bad, good[1]])


def test_amplitudes_numpy_cannot_convert_get_numpys_error() -> None:
    # the right shapes, values that are no numbers: numpy's own error, not one of ours
    # about shapes (nor a failure further on)
    rng = np.random.default_rng(2)
    good = [make_frame(t, rng) for t in (0.1, 0.2)]
    text = np.full(np.shape(good[1].amplitudes), "x", dtype=object)
    bad = dataclasses.replace(good[1], time_s=0.15, amplitudes=text)
    for frames in ([bad], [good[0], bad, good[1]]):
        with pytest.raises(ValueError, match="complex"):
            results_codec.encode_frames(frames)


@pytest.mark.parametrize(
    ("n_ch", "n", "first_index", "t0_s"),
    [(10, 2560, 0, 0.0), (1, 1, -5, 0.25), (3, 0, 7, -0.0), (2, 3, 2**40, 1e-300)],
)
def test_sample_block_is_the_protobuf_libraries_bytes(
    n_ch: int, n: int, first_index: int, t0_s: float
) -> None:
    group = SampleGroup("acc", 25600.0, tuple(ChannelSpec(f"c{i}", "V") for i in range(n_ch)), t0_s)
    data = np.random.default_rng(n).standard_normal((n_ch, n))
    if data.size:
        data.flat[0] = np.nan
    data.flags.writeable = False  # (the pipeline's arrays are read-only: cast late)
    block = SampleBlock("acc", first_index, data)
    fast = stream_codec.encode_samples(block, group)
    assert fast == stream_codec.encode_samples_reference(block, group)
    late = stream_codec.encode_samples_late(block, group)  # joined on the writer thread
    assert isinstance(late, stream_codec.LateSamples) and len(late) == len(fast)
    made = bytearray(len(late))
    late.write_into(memoryview(made))
    assert made == fast
    public = message_class("SampleBlock").FromString(fast)
    assert np.array(public.data, np.float32).tobytes() == data.astype("<f4").tobytes()
    assert wire_class("SampleBlock").FromString(fast).first_index == first_index


def test_sample_blocks_read_as_the_protobuf_library_reads_them() -> None:
    """``stream_codec.decode_samples`` (what the replay falls back to for a block
    RawDecoder does not take) on our writer's bytes and on valid messages laid out
    otherwise: the protobuf class's fields; what the class refuses, refused."""
    group = SampleGroup("acc", 100.0, (ChannelSpec("x", "V"), ChannelSpec("y", "V")), 0.5)
    layout = group_layout(group)
    data = np.arange(6, dtype="<f4").reshape(2, 3) - 2.5
    fast = stream_codec.encode_samples(SampleBlock("acc", 7, data), group)
    fields = [
        wire.double_field(1, 0.57),
        wire.string_field(2, "acc"),
        wire.int_field(3, 7),
        wire.double_field(4, 100.0),
        wire.double_field(5, 0.5),
        wire.element(6, b"x"),
        wire.element(6, b"y"),
        wire.int_field(7, 3),
        wire.bytes_field(8, data.tobytes()),
    ]
    read = {
        "ours": (fast, 7),
        "reversed": (b"".join(fields[:6:-1] + fields[5:7] + fields[4::-1]), 7),
        "index twice": (fast + wire.int_field(3, 9), 9),  # the last one wins
        "unknown field": (fast + wire.int_field(9, 1), 7),  # kept by the class, ignored
        "n_samples past 32 bits": (fast + wire.int_field(7, 2**32 + 3), 7),  # uint32: 3
    }
    for name, (message, first_index) in read.items():
        block = stream_codec.decode_samples(message, layout)
        assert block.first_index == first_index, name
        assert block.data.tobytes() == data.astype(float).tobytes(), name
    with pytest.raises(BadMessage, match="out of range"):
        stream_codec.decode_samples(fast + wire.int_field(3, -5), layout)
    for message in (fast + wire.element(2, b"\xff"), fast[:-3]):  # bad UTF-8, truncated
        with pytest.raises(DecodeError):
            stream_codec.decode_samples(message, layout)


def group_layout(group: SampleGroup) -> StreamLayout:
    return StreamLayout((group,), ())


def test_gating_is_the_protobuf_libraries_bytes() -> None:
    """``results_codec.encode_outcome`` lays ``/gating`` out from a layout per structure:
    the protobuf class's bytes, on the cases where proto3 leaves fields out (zeros, false,
    empty strings) and where it does not (-0.0, NaN), each structure twice (the layout
    made, then reused with other values)."""
    nan = math.nan
    outcomes = [
        FrameOutcome(1.25, 3000.0, (1.0, 2.0), {}, None, {1.0: 0.01, 2.0: 0.2}),
        FrameOutcome(0.0, -0.0, (), {1.0: "weak", 1.5: "residual"}, "no used order", {1.5: nan}),
        FrameOutcome(2.5, 900.0, (0.0, 1.5), {2.0: ""}, None, {0.0: 0.0, 1.5: -0.0}),
        FrameOutcome(3.0, 1e300, (3.0,), {2.0: "é" * 200}, "", {}),  # long, non-ASCII, empty
        FrameOutcome(4.0, 1.0, (1.0,), {}, None, {}),
        FrameOutcome(5.0, 2.0, (1.0, 1.5), {2.0: "weak"}, None, {1.0: 1e-3, 1.5: nan, 2.0: 4.0}),
    ]
    for outcome in outcomes:
        again = dataclasses.replace(outcome, time_s=outcome.time_s + 0.5, rpm=outcome.rpm * 2)
        for case in (outcome, again):
            fast = results_codec.encode_outcome(case)
            assert fast == results_codec.encode_outcome_reference(case), case
            back = results_codec.decode_outcome(fast)
            assert (back.time_s, back.reason, back.used_orders) == (
                case.time_s,
                case.reason,
                case.used_orders,
            )


def test_a_groups_fields_laid_out_once_keep_the_sign_of_zero() -> None:
    """``wire.sample_block_head`` keeps a group's constant fields; t0 = 0.0 (left out) and
    -0.0 (written) are different bytes, whichever came first."""
    data = np.ones((1, 4))
    for t0_s in (0.0, -0.0, 0.0):
        group = SampleGroup("g", 10.0, (ChannelSpec("c", "V"),), t0_s)
        block = SampleBlock("g", 3, data)
        fast = stream_codec.encode_samples(block, group)
        assert fast == stream_codec.encode_samples_reference(block, group), t0_s
