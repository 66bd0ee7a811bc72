"""Protobuf wire bytes of the two messages the recorder writes most: order frames and sample blocks.

``OrderFrame`` is the message written once per frame with many numbers in
it: with 3 orders x 10 channels, building it through the protobuf classes
(30 nested ``ChannelAmplitude`` messages, one Python call per field) took
about 50 us, a third of the recorder's time in a live run. Its layout
depends only on the orders and the channel names, so :class:`FrameWire`
lays the bytes out once, noting where each number goes, and a frame is a
copy of that template with every float64 and bool scattered into place by
one numpy assignment each (about 10 us).

Every field is written, zeros and ``false`` included (the protobuf library
leaves proto3 defaults out): that keeps the layout fixed, and a parser reads
the same message either way. ``results_codec.encode_frame_reference`` builds the
message through the protobuf classes; a test checks that both parse to
messages that serialise identically.

A ``SampleBlock`` is a handful of small fields and one large packed array:
:func:`sample_block_head` writes the small fields, the float32 bytes are appended
once, where the protobuf class copies the array in and out again (three
copies of 0.5 MB for a 0.5 s block of 10 channels at 25.6 kHz).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from functools import lru_cache
from typing import Any

import numpy as np

# wire types
_I64, _LEN, _VARINT = 1, 2, 0
_ZERO8 = bytes(8)


def varint(n: int) -> bytes:
    """Base-128 varint of a non-negative integer."""
    out = bytearray()
    while n >= 0x80:
        out.append(n & 0x7F | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def key(number: int, wire_type: int) -> bytes:
    """A field's key: number and wire type."""
    return varint(number << 3 | wire_type)


# Single fields, left out when they hold the proto3 default (all-zero bits, 0, empty), as the
# protobuf library does: the bytes are then the library's own.


def string_field(number: int, text: str) -> bytes:
    return bytes_field(number, text.encode())


def bytes_field(number: int, data: bytes) -> bytes:
    return element(number, data) if data else b""


def element(number: int, data: bytes) -> bytes:
    """One element of a repeated string or bytes field (written even when empty)."""
    return key(number, _LEN) + varint(len(data)) + data


def double_field(number: int, x: float) -> bytes:
    data = struct.pack("<d", x)
    return key(number, _I64) + data if data != _ZERO8 else b""


def int_field(number: int, n: int) -> bytes:
    """An int64 or uint32 field (a negative int64 is ten bytes of two's complement)."""
    return key(number, _VARINT) + varint(n & 0xFFFF_FFFF_FFFF_FFFF) if n else b""


def sample_block_head(
    time_s: float,
    group: str,
    first_index: int,
    rate_hz: float,
    t0_s: float,
    channels: tuple[str, ...] | list[str],
    n_samples: int,
    n_bytes: int,
) -> bytes:
    """A serialised ``SampleBlock`` without its float32 bytes (``n_bytes`` of them): the
    message is this head followed by the array's (n_channels, n_samples) float32 bytes,
    which can be joined in later; the protobuf class's bytes, the array copied once. The
    group's own fields are laid out once (:func:`group_fields`)."""
    rates = struct.pack("<dd", rate_hz, t0_s)  # (bits, not floats: -0.0 is written, 0.0 not)
    group_field, layout_fields = group_fields(group, rates, tuple(channels))
    return b"".join(
        (
            double_field(1, time_s),
            group_field,
            int_field(3, first_index),
            layout_fields,
            int_field(7, n_samples),
            key(8, _LEN) + varint(n_bytes) if n_bytes else b"",
        )
    )


@lru_cache(maxsize=64)
def group_fields(group: str, rates: bytes, channels: tuple[str, ...]) -> tuple[bytes, bytes]:
    """A group's fields of ``SampleBlock``: ``group`` (2), then ``rate_hz``, ``t0_s`` (their
    float64 bytes) and ``channels`` (4-6), the same in every block (3.6 ms a minute built)."""
    rate_hz, t0_s = struct.unpack("<dd", rates)
    layout = double_field(4, rate_hz) + double_field(5, t0_s)
    return string_field(2, group), layout + b"".join(element(6, c.encode()) for c in channels)


class Unparsed(ValueError):
    """A message head :class:`replay.raw_decoder.RawDecoder` leaves to the protobuf library
    (which says what is wrong)."""


def read_varint(buf: bytes | memoryview, pos: int) -> tuple[int, int]:
    """``(value, next position)`` of the varint at ``pos`` (IndexError past the end)."""
    result = shift = 0
    while True:
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if b < 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise Unparsed("varint longer than 10 bytes")


class _Layout:
    """Bytes being laid out, with the offsets of the float64 and bool slots in fill order."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.f64: list[int] = []
        self.bools: list[int] = []

    def double(self, number: int) -> None:
        self.buf += key(number, _I64)
        self.f64.append(len(self.buf))
        self.buf += bytes(8)

    def bool(self, number: int) -> None:
        self.buf += key(number, _VARINT)
        self.bools.append(len(self.buf))
        self.buf += b"\0"

    def packed_doubles(self, number: int, n: int) -> None:
        self.buf += key(number, _LEN) + varint(8 * n)
        self.f64 += range(len(self.buf), len(self.buf) + 8 * n, 8)
        self.buf += bytes(8 * n)

    def packed_bools(self, number: int, n: int) -> None:
        self.buf += key(number, _LEN) + varint(n)
        self.bools += range(len(self.buf), len(self.buf) + n)
        self.buf += bytes(n)

    def constant(self, data: bytes) -> None:
        self.buf += data

    def message(self, number: int, inner: _Layout) -> None:
        self.buf += key(number, _LEN) + varint(len(inner.buf))
        shift = len(self.buf)
        self.f64 += [shift + p for p in inner.f64]
        self.bools += [shift + p for p in inner.bools]
        self.buf += inner.buf


class FrameWire:
    """The ``OrderFrame`` message (``replay.schemas``) of one set of orders and channels.

    Float64 slots, in order: ``time_s``, ``rpm``, ``crank_angle_rad``,
    ``amplitude_re`` (n_orders x n_channels, order-major), ``amplitude_im``,
    ``rpm_change``, ``leakage`` (n_channels), then ``amplitude`` and
    ``phase_deg`` of every ``by_order`` entry, then ``spectrum_re`` and
    ``spectrum_im`` (n_spectrum each; ``spectrum_channel`` before them is a
    constant). Bool slots: ``channel_ok``, then the ``ok`` of every entry.
    ``flags`` (field 11, variable) go between ``leakage`` and ``by_order``.
    ``n_spectrum = 0`` (a frame without spectrum) leaves the three spectrum
    fields out: the bytes of a recording made before they existed.
    """

    def __init__(
        self,
        orders: tuple[float, ...],
        channels: tuple[str, ...],
        spectrum_channel: str | None = None,
        n_spectrum: int = 0,
    ) -> None:
        self.orders, self.channels = tuple(orders), tuple(channels)
        self.spectrum_channel, self.n_spectrum = spectrum_channel, n_spectrum
        n_o, n_ch = len(self.orders), len(self.channels)
        self.shape = (n_o, n_ch)
        head = _Layout()
        head.double(1)  # time_s
        head.double(2)  # rpm
        head.double(3)  # crank_angle_rad
        head.constant(key(4, _LEN) + varint(8 * n_o) + np.asarray(orders, "<f8").tobytes())
        head.constant(b"".join(element(5, c.encode()) for c in channels))
        head.packed_doubles(6, n_o * n_ch)  # amplitude_re
        head.packed_doubles(7, n_o * n_ch)  # amplitude_im
        head.packed_bools(8, n_ch)  # channel_ok
        head.double(9)  # rpm_change
        head.packed_doubles(10, n_ch)  # leakage
        split = len(head.buf)  # flags (11) go here
        for order in orders:
            entry = _Layout()
            entry.constant(key(1, _I64) + np.float64(order).astype("<f8").tobytes())
            for channel in channels:
                amp = _Layout()
                amp.constant(string_field(1, channel))
                amp.double(2)  # amplitude
                amp.double(3)  # phase_deg
                amp.bool(4)  # ok
                entry.message(2, amp)
            head.message(12, entry)  # by_order
        if n_spectrum:
            head.constant(string_field(13, spectrum_channel or ""))
            head.packed_doubles(14, n_spectrum)  # spectrum_re
            head.packed_doubles(15, n_spectrum)  # spectrum_im
        self.split = split
        self.template = np.frombuffer(bytes(head.buf), np.uint8).copy()
        self.f64_index = (np.asarray(head.f64)[:, None] + np.arange(8)).ravel()
        # channel_ok, then the ok of each order's entries: (n_orders + 1, n_channels), so that
        # the (n_channels,) channel_ok broadcasts into all of them
        self.bool_index = np.asarray(head.bools, dtype=np.intp).reshape(n_o + 1, n_ch)
        self.n_f64 = len(head.f64)
        n = n_o * n_ch
        self._re = slice(3, 3 + n)
        self._im = slice(3 + n, 3 + 2 * n)
        self._rest = 3 + 2 * n  # rpm_change, then leakage
        self._pairs = self._rest + 1 + n_ch
        self._spectrum = self._pairs + 2 * n

    def encode(self, frame: Any) -> bytes:
        """The serialised message of a ``dsp.frames.OrderFrame`` with these orders and channels."""
        return self.encode_many([frame])[0]

    def encode_many(self, frames: Sequence[Any]) -> list[bytes]:
        """:meth:`encode` of each of ``frames`` (all with these orders and channels), the
        numbers of all of them scattered into copies of the template at once: a block's
        frames cost about what one did frame by frame (the same bytes)."""
        n_o, n_ch = self.shape
        k = len(frames)
        try:
            amp = np.array([f.amplitudes for f in frames], dtype=complex)
            ok = np.array([f.channel_ok for f in frames], dtype=bool)
            leakage = np.array([f.leakage for f in frames], dtype=float)
            spectra = [getattr(f, "spectrum", None) for f in frames]
            spectrum = np.array(spectra, dtype=complex) if self.n_spectrum else None
            fits = amp.shape == (k, n_o, n_ch) and ok.shape == leakage.shape == (k, n_ch)
            fits = fits and (
                spectrum.shape == (k, self.n_spectrum)
                if spectrum is not None
                else all(x is None for x in spectra)
            )
        except (ValueError, TypeError):  # ragged, or values numpy cannot convert
            for frame in frames:
                self._check(frame)  # names the frame that does not fit
            raise  # (the shapes fit: the values are what numpy could not convert)
        if not fits:
            for frame in frames:
                self._check(frame)  # names the frame that does not fit
        values = np.empty((k, self.n_f64))
        values[:, :3] = [(f.time_s, f.rpm, f.crank_angle_rad) for f in frames]
        values[:, self._rest] = [f.rpm_change for f in frames]
        values[:, self._rest + 1 : self._pairs] = leakage
        if spectrum is not None:
            values[:, self._spectrum : self._spectrum + self.n_spectrum] = spectrum.real
            values[:, self._spectrum + self.n_spectrum :] = spectrum.imag
        flat = amp.reshape(k, n_o * n_ch)
        values[:, self._re] = flat.real
        values[:, self._im] = flat.imag
        pairs = values[:, self._pairs : self._spectrum].reshape(k, n_o, n_ch, 2)
        pairs[..., 0] = np.abs(amp)
        pairs[..., 1] = np.degrees(np.angle(amp))
        buf = np.tile(self.template, (k, 1))
        buf[:, self.f64_index] = values.astype("<f8", copy=False).view(np.uint8)
        buf[:, self.bool_index] = ok[:, None, :]
        out = []
        for k, frame in enumerate(frames):
            if not frame.flags:
                out.append(buf[k].tobytes())
                continue
            flags = b"".join(element(11, f.encode()) for f in sorted(frame.flags))
            out.append(buf[k, : self.split].tobytes() + flags + buf[k, self.split :].tobytes())
        return out

    def _check(self, frame: Any) -> None:
        """A clear error for a frame that does not fit this layout."""
        n_ch = self.shape[1]
        shapes = np.shape(frame.amplitudes), np.shape(frame.channel_ok), np.shape(frame.leakage)
        if shapes != (self.shape, (n_ch,), (n_ch,)):
            raise ValueError(
                f"order frame at {frame.time_s} s: expected amplitudes of shape {self.shape} and "
                f"{n_ch} channel_ok and leakage values, got {shapes[0]}, {shapes[1]}, {shapes[2]}"
            )
        spectrum = getattr(frame, "spectrum", None)
        got = None if spectrum is None else np.shape(spectrum)
        want = (self.n_spectrum,) if self.n_spectrum else None
        if got != want:
            raise ValueError(
                f"order frame at {frame.time_s} s: expected a spectrum of shape {want}, got {got}"
            )


@lru_cache(maxsize=16)
def frame_wire(
    orders: tuple[float, ...],
    channels: tuple[str, ...],
    spectrum_channel: str | None = None,
    n_spectrum: int = 0,
) -> FrameWire:
    """The (cached) :class:`FrameWire` of these orders and channels (and spectrum, if any)."""
    return FrameWire(orders, channels, spectrum_channel, n_spectrum)
