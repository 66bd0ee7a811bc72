"""Encode and decode what the live run computed: order frames, gating, estimates (no file I/O).

Symmetric pairs, as in :mod:`replay.stream_codec`: every ``encode_*`` returns
the serialised protobuf bytes of a :mod:`replay.schemas` message (``/orders``,
``/gating``, ``/estimate``), the matching ``decode_*`` gives back the object
the pipeline handed to the recorder. Every number travels as float64, so a
decoded frame or estimate equals the original bit for bit. A message that does
not fit raises :class:`replay.errors.BadMessage`; the reader skips it and
reports it.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Sequence
from typing import Any

import numpy as np

from dsp.frames import OrderFrame
from estimator.outcome import FrameOutcome
from estimator.result import Estimate
from replay import wire
from replay.errors import BadMessage
from replay.schemas import PARAMETERS, wire_class


def encode_frame(frame: OrderFrame) -> bytes:
    """``/orders``: a ``dsp.frames.OrderFrame`` (from a byte template, see :mod:`replay.wire`)."""
    return encode_frames([frame])[0]


def encode_frames(frames: Sequence[OrderFrame]) -> list[bytes]:
    """:func:`encode_frame` of each frame; consecutive frames of one layout (a block's)
    encoded together (:meth:`replay.wire.FrameWire.encode_many`)."""
    out: list[bytes] = []
    start = 0
    while start < len(frames):
        layout = _wire_of(frames[start])
        end = start + 1
        while end < len(frames) and _wire_of(frames[end]) is layout:
            end += 1
        out += layout.encode_many(frames[start:end])
        start = end
    return out


def _wire_of(frame: OrderFrame) -> wire.FrameWire:
    spectrum = getattr(frame, "spectrum", None)
    if spectrum is None:
        return wire.frame_wire(tuple(frame.orders), tuple(frame.channels))
    return wire.frame_wire(
        tuple(frame.orders), tuple(frame.channels), frame.spectrum_channel, len(spectrum)
    )


def encode_frame_reference(frame: OrderFrame) -> bytes:
    """:func:`encode_frame` through the protobuf classes: slower, for the tests to compare with."""
    amp = np.asarray(frame.amplitudes, dtype=complex)
    ok = np.asarray(frame.channel_ok, dtype=bool)
    cls = wire_class("OrderFrame")
    msg = cls(
        time_s=frame.time_s,
        rpm=frame.rpm,
        crank_angle_rad=frame.crank_angle_rad,
        orders=list(frame.orders),
        channels=list(frame.channels),
        amplitude_re=amp.real.ravel().tolist(),
        amplitude_im=amp.imag.ravel().tolist(),
        channel_ok=ok.tolist(),
        rpm_change=frame.rpm_change,
        leakage=np.asarray(frame.leakage, dtype=float).tolist(),
        flags=sorted(frame.flags),
    )
    spectrum = getattr(frame, "spectrum", None)
    if spectrum is not None:
        spec = np.asarray(spectrum, dtype=complex)
        msg.spectrum_channel = frame.spectrum_channel or ""
        msg.spectrum_re.extend(spec.real.tolist())
        msg.spectrum_im.extend(spec.imag.tolist())
    magnitude, phase = np.abs(amp), np.degrees(np.angle(amp))
    for k, order in enumerate(frame.orders):
        entry = msg.by_order.add(order=order)
        for j, channel in enumerate(frame.channels):
            entry.channels.add(
                channel=channel,
                amplitude=float(magnitude[k, j]),
                phase_deg=float(phase[k, j]),
                ok=bool(ok[j]),
            )
    return bytes(msg.SerializeToString())


def decode_frame(data: bytes) -> OrderFrame:
    """The ``dsp.frames.OrderFrame``, amplitudes exact."""
    msg = wire_class("OrderFrame").FromString(data)
    n_o, n_ch = len(msg.orders), len(msg.channels)
    re = np.array(msg.amplitude_re, dtype=float)
    im = np.array(msg.amplitude_im, dtype=float)
    if re.size != n_o * n_ch or im.size != n_o * n_ch or len(msg.channel_ok) != n_ch:
        raise BadMessage(
            f"order frame at {msg.time_s:.3f} s: {re.size} amplitudes for {n_o} orders x {n_ch} channels"
        )
    amplitudes = np.empty((n_o, n_ch), complex)  # not re + 1j * im: that turns -0.0 into 0.0
    amplitudes.real = re.reshape(n_o, n_ch)
    amplitudes.imag = im.reshape(n_o, n_ch)
    # a frame without spectrum (or a recording made before it existed) has neither array
    spectrum, spectrum_channel = None, None
    if len(msg.spectrum_re) or len(msg.spectrum_im):
        if len(msg.spectrum_re) != len(msg.spectrum_im):
            raise BadMessage(
                f"order frame at {msg.time_s:.3f} s: {len(msg.spectrum_re)} real and "
                f"{len(msg.spectrum_im)} imaginary spectrum values"
            )
        spectrum = np.empty(len(msg.spectrum_re), complex)
        spectrum.real = np.array(msg.spectrum_re, dtype=float)
        spectrum.imag = np.array(msg.spectrum_im, dtype=float)
        spectrum_channel = msg.spectrum_channel
    return OrderFrame(
        time_s=msg.time_s,
        rpm=msg.rpm,
        crank_angle_rad=msg.crank_angle_rad,
        orders=tuple(msg.orders),
        channels=tuple(msg.channels),
        amplitudes=amplitudes,
        channel_ok=np.array(msg.channel_ok, dtype=bool),
        rpm_change=msg.rpm_change,
        leakage=np.array(msg.leakage, dtype=float),
        flags=frozenset(msg.flags),
        spectrum=spectrum,
        spectrum_channel=spectrum_channel,
    )


def encode_outcome(outcome: FrameOutcome) -> bytes:
    """``/gating``: an ``estimator.streaming.FrameOutcome`` (without the fitted motion).

    The bytes :func:`encode_outcome_reference` gets from the protobuf class (a test
    compares them), from a layout per structure (:class:`_GatingLayout`: the reason, the
    orders and what was said of each), the doubles packed into it by one ``struct`` call:
    1.0 us a frame against 2.9 us through the class (9 ms a minute of the recorder's
    caller). A double that is zero, which proto3 leaves out, goes through the class.
    """
    residual = outcome.relative_residual
    key = (
        outcome.reason,
        tuple(outcome.used_orders),
        tuple(residual),
        tuple(outcome.rejected.items()),
    )
    layout = _GATING.get(key)
    if layout is None:
        if len(_GATING) >= 256:  # a bound, for a run whose rejections keep changing
            _GATING.clear()
        layout = _GATING[key] = _GatingLayout(outcome)
    values = [outcome.time_s, outcome.rpm, *[residual.get(h, math.nan) for h in layout.orders]]
    if 0.0 in values:
        return encode_outcome_reference(outcome)
    args: list[Any] = [None] * (2 * len(values) + 1)
    args[0::2] = layout.constants
    args[1::2] = values
    return layout.pack(*args)


class _GatingLayout:
    """The ``Gating`` message of one structure, as constant bytes around its doubles:
    ``time_s``, ``rpm`` and each order's ``relative_residual`` (NaN without one), all
    taken as non-zero (written)."""

    def __init__(self, outcome: FrameOutcome) -> None:
        used = set(outcome.used_orders)
        residual, rejected = outcome.relative_residual, outcome.rejected
        self.orders = list(residual) + [h for h in rejected if h not in residual]
        head = wire.string_field(4, outcome.reason) if outcome.reason is not None else b""
        head = (wire.key(3, 0) + b"\x01" if outcome.reason is None else b"") + head
        if outcome.used_orders:
            packed = np.asarray(outcome.used_orders, "<f8").tobytes()
            head += wire.key(5, 2) + wire.varint(len(packed)) + packed
        constants = [wire.key(1, 1), wire.key(2, 1), head]  # then each entry around its slot
        for h in self.orders:
            before = wire.double_field(1, h) + (wire.key(2, 0) + b"\x01" if h in used else b"")
            before += wire.string_field(3, rejected.get(h, "")) + wire.key(4, 1)
            after = wire.key(5, 0) + b"\x01" if h in residual else b""
            size = len(before) + 8 + len(after)
            constants[-1] += wire.key(6, 2) + wire.varint(size) + before
            constants.append(after)
        self.constants = constants
        self.pack = struct.Struct("<" + "d".join(f"{len(c)}s" for c in constants)).pack


_GATING: dict[tuple[Any, ...], _GatingLayout] = {}


def encode_outcome_reference(outcome: FrameOutcome) -> bytes:
    """:func:`encode_outcome` through the protobuf class, for the tests to compare with."""
    msg = wire_class("Gating")(
        time_s=outcome.time_s,
        rpm=outcome.rpm,
        used=outcome.reason is None,
        reason=outcome.reason or "",
        used_orders=list(outcome.used_orders),
    )
    used = set(outcome.used_orders)
    orders = list(outcome.relative_residual)
    orders += [h for h in outcome.rejected if h not in outcome.relative_residual]
    for h in orders:
        msg.orders.add(
            order=h,
            used=h in used,
            rejected=outcome.rejected.get(h, ""),
            relative_residual=outcome.relative_residual.get(h, math.nan),
            has_residual=h in outcome.relative_residual,
        )
    return bytes(msg.SerializeToString())


def decode_outcome(data: bytes) -> FrameOutcome:
    """The ``estimator.streaming.FrameOutcome`` (``motion`` is None: it is not recorded)."""
    msg = wire_class("Gating").FromString(data)
    return FrameOutcome(
        time_s=msg.time_s,
        rpm=msg.rpm,
        used_orders=tuple(msg.used_orders),
        rejected={g.order: g.rejected for g in msg.orders if g.rejected},
        reason=None if msg.used else msg.reason,
        relative_residual={g.order: g.relative_residual for g in msg.orders if g.has_residual},
    )


def encode_estimate(time_s: float, rpm: float, estimate: Estimate, final: bool = False) -> bytes:
    """``/estimate``: an ``estimator.result.Estimate`` in full (covariances included).

    ``cov`` is left empty when it is exactly ``cov_random + cov_systematic``
    (as ``estimator.result.build_estimate`` makes it): a third of the size of a
    message, and the decoder rebuilds the same bits.
    """
    cov = np.asarray(estimate.cov, float)
    cov_random = np.asarray(estimate.cov_random, float)
    cov_systematic = np.asarray(estimate.cov_systematic, float)
    implied = bool(np.array_equal(cov, cov_random + cov_systematic))
    msg = wire_class("Estimate")(
        time_s=time_s,
        rpm=rpm,
        frames_used=int(estimate.frames_used),
        frames_skipped=int(estimate.frames_skipped),
        variance_factor=float(estimate.variance_factor),
        names=list(estimate.names),
        theta=np.asarray(estimate.theta, float).tolist(),
        cov=[] if implied else cov.ravel().tolist(),
        cov_random=cov_random.ravel().tolist(),
        cov_systematic=cov_systematic.ravel().tolist(),
        observable=np.asarray(estimate.observable, bool).tolist(),
        mass_known=bool(estimate.mass_known),
        mass_nominal=float(estimate.mass_nominal),
        unbalance_point=np.asarray(estimate.unbalance_point, float).tolist(),
        crank_axis=[] if estimate.crank_axis is None else np.asarray(estimate.crank_axis).tolist(),
        rpm_range=list(estimate.rpm_range) if estimate.rpm_range else [],
        half_order_json=json.dumps(estimate.half_order) if estimate.half_order else "",
        final=final,
    )
    for name in estimate.names:
        if name in PARAMETERS:
            setattr(msg, name, estimate.value(name))
            setattr(msg, f"{name}_std", estimate.std(name))
    mass = estimate.mass()
    if mass is not None:
        msg.mass_kg, msg.mass_kg_std = mass
    else:
        msg.mass_kg = float(estimate.mass_nominal)
        msg.mass_kg_std = 0.0 if estimate.mass_known else math.inf
    for key, count in estimate.frames_rejected.items():
        msg.frames_rejected.add(key=key, count=int(count))
    for key, count in estimate.orders_rejected.items():
        msg.orders_rejected.add(key=key, count=int(count))
    return bytes(msg.SerializeToString())


def decode_estimate(data: bytes) -> tuple[float, float, Estimate, bool]:
    """``(time_s, rpm, estimator.result.Estimate, final)``, every number as recorded."""
    msg = wire_class("Estimate").FromString(data)
    n = len(msg.names)

    def square(values: Any, what: str) -> np.ndarray:
        arr = np.array(values, dtype=float)
        if arr.size != n * n:
            raise BadMessage(
                f"estimate at {msg.time_s:.3f} s: {what} has {arr.size} values for {n} parameters"
            )
        return arr.reshape(n, n)

    if len(msg.theta) != n or len(msg.observable) != n:
        raise BadMessage(f"estimate at {msg.time_s:.3f} s: {len(msg.theta)} values for {n} names")
    cov_random = square(msg.cov_random, "cov_random")
    cov_systematic = square(msg.cov_systematic, "cov_systematic")
    cov = square(msg.cov, "cov") if len(msg.cov) else cov_random + cov_systematic
    estimate = Estimate(
        names=tuple(msg.names),
        theta=np.array(msg.theta, dtype=float),
        cov=cov,
        cov_random=cov_random,
        cov_systematic=cov_systematic,
        observable=np.array(msg.observable, dtype=bool),
        mass_known=msg.mass_known,
        mass_nominal=msg.mass_nominal,
        unbalance_point=np.array(msg.unbalance_point, dtype=float),
        crank_axis=np.array(msg.crank_axis, dtype=float) if len(msg.crank_axis) == 3 else None,
        frames_used=int(msg.frames_used),
        frames_skipped=int(msg.frames_skipped),
        frames_rejected={c.key: int(c.count) for c in msg.frames_rejected},
        orders_rejected={c.key: int(c.count) for c in msg.orders_rejected},
        rpm_range=(msg.rpm_range[0], msg.rpm_range[1]) if len(msg.rpm_range) == 2 else None,
        half_order=json.loads(msg.half_order_json) if msg.half_order_json else None,
        variance_factor=msg.variance_factor,
    )
    return msg.time_s, msg.rpm, estimate, msg.final
