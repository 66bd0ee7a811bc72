"""Order frames with and without a spectrum in a recording: the protobuf-built bytes,
a frame without one the bytes of a recording made before spectra existed, a spectrum of
the wrong length refused, a round trip through an MCAP file (split from
test_dsp_spectrum.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from support.mcap_logs import BENCH_TEXT, make_outcome
from support.spectrum_streams import (
    N_SPEC,
    SpectrumStream,
    frame_fields,
    pressure_like,
    spectrum_config,
    track_frames,
)

from dsp.frames import OrderFrame
from dsp.synthetic import Ramp
from replay import results_codec as codec
from replay import wire
from replay.reader import open_log
from replay.recorder import McapRecorder
from replay.recording_head import RecordingInfo
from replay.schemas import message_class

# -- recording -----------------------------------------------------------------------------------


def _frames_to_record() -> list[OrderFrame]:
    content = pressure_like(np.random.default_rng(9), powers=(0.0, 2.0))
    stream = SpectrumStream(Ramp(2000.0, 2600.0, 1.0), content)
    frames = track_frames(stream.layout, stream.items(1.0), spectrum_config())[:6]
    edge = np.linspace(-1, 1, N_SPEC) + 1j * np.linspace(1, -1, N_SPEC)
    edge[0], edge[1], edge[2] = complex(-0.0, 0.0), complex(np.nan, np.nan), complex(np.inf, -0.0)
    frames.append(replace(frames[0], spectrum=edge, spectrum_channel="é"))
    frames.append(replace(frames[0], spectrum=None, spectrum_channel=None))
    return frames


def test_frames_with_and_without_spectrum_encode_as_the_protobuf_built_ones():
    cls = message_class("OrderFrame")
    for f in _frames_to_record():
        fast, reference = codec.encode_frame(f), codec.encode_frame_reference(f)
        assert cls.FromString(fast).SerializeToString() == reference
        back = codec.decode_frame(fast)
        assert frame_fields(back) == frame_fields(f)
        if f.spectrum is None:
            assert back.spectrum is None and back.spectrum_channel is None
        else:
            assert back.spectrum.tobytes() == np.asarray(f.spectrum, complex).tobytes()
            assert back.spectrum_channel == f.spectrum_channel


def test_a_frame_without_spectrum_is_the_bytes_of_a_recording_made_before_it_existed():
    f = replace(_frames_to_record()[0], spectrum=None, spectrum_channel=None)
    fast = codec.encode_frame(f)
    msg = message_class("OrderFrame").FromString(fast)
    assert not msg.spectrum_re and not msg.spectrum_im and not msg.spectrum_channel
    # an old writer's message: no field past 12
    old = message_class("OrderFrame")()
    old.CopyFrom(msg)
    old.ClearField("spectrum_channel")
    assert old.SerializeToString() == fast
    assert codec.decode_frame(old.SerializeToString()).spectrum is None


def test_a_spectrum_of_the_wrong_length_is_refused():
    f = _frames_to_record()[0]
    codec.encode_frame(f)
    with pytest.raises(ValueError, match="spectrum of shape"):
        wire.frame_wire(f.orders, f.channels, "p", N_SPEC).encode(
            replace(f, spectrum=f.spectrum[:-1])
        )


def test_spectrum_round_trips_through_an_mcap_file(tmp_path):
    frames = _frames_to_record()
    stream = SpectrumStream(Ramp(2000.0, 2600.0, 1.0), pressure_like(np.random.default_rng(9)))
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path)
    rec.start(RecordingInfo(layout=stream.layout, bench_text=BENCH_TEXT))
    for item in stream.items(0.2):
        rec.on_item(item)
    for f in frames:
        rec.on_frame(f, make_outcome(f, used=True))
    rec.close(None)
    got = list(open_log(path).frames())
    assert len(got) == len(frames)
    for a, b in zip(got, frames, strict=True):
        assert frame_fields(a) == frame_fields(b)
        assert a.spectrum_channel == b.spectrum_channel
        if b.spectrum is None:
            assert a.spectrum is None
        else:
            assert a.spectrum.tobytes() == np.asarray(b.spectrum, complex).tobytes()
