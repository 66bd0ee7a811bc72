"""CAN frames <-> channel samples: the DBC conventions, batch codecs and the frame encoder.

A DBC names the frames; a few custom attributes (``docs/can.md``) say what they carry:

* **sample frames**: signals ``CHANNEL_sK`` (sample ``K`` of ``CHANNEL`` in the frame;
  or the signal attributes ``PtiChannel``/``PtiSample``), a frame counter ``SEQ``
  (message attribute ``PtiCounter`` names another) counting frames from the start of
  the acquisition, an optional ``CRC`` (CRC-16/CCITT-FALSE over every other byte of
  the frame), the rate from ``PtiSampleRate`` (samples/s per channel) or
  ``GenMsgCycleTime``. Frame ``n`` holds samples ``n S .. n S + S - 1`` of its group.
  The most negative raw value of a signed sample (all ones if unsigned) means
  "no valid sample" and decodes to NaN.
* **edge frames** (message attribute ``PtiEdgeChannel``): ``EDGE_N`` edges, the first
  at ``EDGE_T0`` and the others at ``EDGE_T0 + EDGE_Dk`` (DAQ clock, ticks of the
  signals' factor), plus ``SEQ`` and ``CRC``.
* **status frame** (``PtiStatus = 1``): ``STATE`` (1 running, 2 stopped) and
  ``DAQ_TIME``; a stop frame's ``DAQ_TIME`` is the end of the acquisition.

Byte-aligned integer signals are decoded for a whole batch of frames with one numpy
gather (cantools takes ~14 us per 64-byte accelerometer frame, 2-3 times the whole
per-frame cost of the decoder); any other signal falls back to cantools, frame by
frame. Both give raw integers, scaled the same way.
"""

from __future__ import annotations

import binascii
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, NamedTuple

import numpy as np

from acquisition.stream import (
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SampleGroup,
    SourceError,
    StreamItem,
    StreamLayout,
)

if TYPE_CHECKING:
    from ptinertia.config import Bench

CRC_INIT = 0xFFFF  # CRC-16/CCITT-FALSE: binascii.crc_hqx is its table-driven C implementation
STATE_RUNNING = 1
STATE_STOPPED = 2
_SAMPLE_NAME = re.compile(r"^(?P<channel>.+)_s(?P<k>\d+)$")
_DELTA_NAME = re.compile(r"^EDGE_D(?P<k>\d+)$")


class RawFrame(NamedTuple):
    """One CAN frame as received (or logged); the record raw-frame logs store.

    ``timestamp_ns`` is the receive time (host clock or log time, integer ns); it
    only helps to unwrap short counters: samples are placed by their counters.
    """

    timestamp_ns: int
    arbitration_id: int
    is_extended_id: bool
    data: bytes
    is_fd: bool = True


# -- a raw frame log record (symmetric pack / unpack) --------------------------------------------

_HEADER = np.dtype([("t", "<i8"), ("id", "<u4"), ("flags", "u1"), ("len", "u1")])


def pack_frames(frames: Sequence[RawFrame]) -> bytes:
    """Frames as one binary record: per frame ``<i8 t_ns, <u4 id, u1 flags, u1 len, data``.

    ``flags`` bit 0: extended id, bit 1: CAN FD. :func:`unpack_frames` inverts it.
    """
    out = bytearray()
    for f in frames:
        flags = (1 if f.is_extended_id else 0) | (2 if f.is_fd else 0)
        out += np.array((f.timestamp_ns, f.arbitration_id, flags, len(f.data)), _HEADER).tobytes()
        out += f.data
    return bytes(out)


def unpack_frames(buf: bytes) -> list[RawFrame]:
    """The frames of a :func:`pack_frames` record."""
    frames = []
    pos = 0
    size = _HEADER.itemsize
    while pos < len(buf):
        if pos + size > len(buf):
            raise SourceError(f"raw CAN record: truncated frame header at byte {pos} of {len(buf)}")
        h = np.frombuffer(buf, _HEADER, count=1, offset=pos)[0]
        end = pos + size + int(h["len"])
        if end > len(buf):
            raise SourceError(
                f"raw CAN record: frame at byte {pos} needs {end - pos} bytes, has {len(buf) - pos}"
            )
        flags = int(h["flags"])
        frames.append(
            RawFrame(
                int(h["t"]),
                int(h["id"]),
                bool(flags & 1),
                bytes(buf[pos + size : end]),
                bool(flags & 2),
            )
        )
        pos = end
    return frames


# -- bus load --------------------------------------------------------------------------------------


def frame_time_s(
    n_bytes: int,
    *,
    fd: bool,
    bitrate: float,
    data_bitrate: float,
    extended: bool = False,
    stuffing: bool = True,
) -> float:
    """Time (s) one data frame occupies the bus, inter-frame space included.

    ``stuffing`` adds the worst-case dynamic stuff bits (one per four bits of the
    stuffed region); without it the result is the unstuffed minimum. CAN FD: the
    arbitration phase, CRC delimiter, ACK and EOF run at ``bitrate``, the rest at
    ``data_bitrate`` (bit rate switch on).
    """
    tail = 1 + 1 + 1 + 7 + 3  # CRC delimiter, ACK, ACK delimiter, EOF, IFS (at the nominal rate)
    if not fd:
        # SOF, 11-bit id, RTR, IDE, r0, DLC (an extended id adds SRR, 18 id bits and r1)
        head = 19 + (20 if extended else 0)
        stuffed = head + 8 * n_bytes + 15  # SOF .. CRC
        extra = (stuffed - 1) // 4 if stuffing else 0
        return (stuffed + tail + extra) / bitrate
    # SOF, 11-bit id, RRS, IDE, FDF, res, BRS (an extended id adds SRR and 18 id bits)
    arb = 17 + (19 if extended else 0)
    crc = 17 if n_bytes <= 16 else 21
    # ESI, DLC, data, stuff count, CRC and its fixed stuff bits, all at the data rate
    data = 1 + 4 + 8 * n_bytes + 4 + crc + math.ceil((4 + crc) / 4)
    extra_arb = (arb - 1) // 4 if stuffing else 0
    extra_data = (1 + 4 + 8 * n_bytes) // 4 if stuffing else 0
    return (arb + extra_arb + tail) / bitrate + (data + extra_data) / data_bitrate


# -- the DBC plan ----------------------------------------------------------------------------------


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


def load_dbc(path: str | Path | None) -> Any:
    """cantools database of ``path``; :class:`SourceError` if none is named, missing or unreadable."""
    import cantools

    if not path:
        raise SourceError(
            'no DBC: name it in the bench file ([can] dbc = "bench.dbc") or pass --dbc '
            "(examples/bench.dbc fits the example benches)"
        )
    p = Path(path)
    if not p.is_file():
        raise SourceError(f"DBC file {str(p)!r} not found")
    try:
        return cantools.database.load_file(str(p), database_format="dbc", strict=True)
    except (
        Exception
    ) as err:  # cantools raises many types (ParseError, UnsupportedDatabaseFormatError, ...)
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise SourceError(f"DBC file {str(p)!r} cannot be read: {first}") from None


def _attr(obj: Any, name: str, default: Any = None) -> Any:
    dbc = getattr(obj, "dbc", None)
    if dbc is None or name not in dbc.attributes:
        return default
    return dbc.attributes[name].value


def _int_field(sig: Any) -> IntField | None:
    """The signal as a byte-aligned integer field, or None if the fast path cannot read it."""
    if sig.is_float or sig.length not in (8, 16, 32, 64) or sig.multiplexer_ids:
        return None
    n = sig.length // 8
    if sig.byte_order == "little_endian":
        if sig.start % 8:
            return None
        return IntField(sig.name, sig.start // 8, n, bool(sig.is_signed))
    if sig.start % 8 != 7:  # big endian: cantools' start is the MSB in sawtooth numbering
        return None
    return IntField(sig.name, sig.start // 8, n, bool(sig.is_signed), big_endian=True)


def _scaling(sig: Any) -> ChannelScaling:
    if sig.is_signed:
        lo, hi = -(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1
        return ChannelScaling(float(sig.scale), float(sig.offset), sig.unit or "", lo + 1, hi, lo)
    hi = (1 << sig.length) - 1
    return ChannelScaling(float(sig.scale), float(sig.offset), sig.unit or "", 0, hi - 1, hi)


def _sample_signals(msg: Any, wanted: set[str]) -> dict[str, dict[int, Any]]:
    """channel -> {sample index k -> signal} for the wanted channels in ``msg``."""
    out: dict[str, dict[int, Any]] = {}
    for sig in msg.signals:
        channel = _attr(sig, "PtiChannel") or None
        k = _attr(sig, "PtiSample", 0)
        if not channel:
            m = _SAMPLE_NAME.match(sig.name)
            if m and m["channel"] in wanted:
                channel, k = m["channel"], int(m["k"])
            elif sig.name in wanted:
                channel, k = sig.name, 0
        if channel in wanted:
            if int(k) in out.setdefault(channel, {}):
                raise SourceError(
                    f"DBC message {msg.name}: sample {k} of channel {channel!r} appears twice"
                )
            out[channel][int(k)] = sig
    return out


def _rate(msg: Any, samples: int) -> float:
    rate = _attr(msg, "PtiSampleRate")
    if rate:
        return float(rate)
    cycle = _attr(msg, "GenMsgCycleTime") or msg.cycle_time
    if cycle:
        return samples * 1000.0 / float(cycle)
    raise SourceError(
        f"DBC message {msg.name}: no sample rate (set the message attribute PtiSampleRate, "
        "samples/s per channel, or GenMsgCycleTime)"
    )


def _check_fields(msg: Any, fields: Sequence[IntField]) -> None:
    for f in fields:
        if f.byte + f.n_bytes > msg.length:
            raise SourceError(
                f"DBC message {msg.name}: signal {f.name} ends past the {msg.length}-byte frame"
            )


def _counter_and_crc(msg: Any, need_counter: bool) -> tuple[IntField | None, IntField | None]:
    name = _attr(msg, "PtiCounter") or "SEQ"
    counter = None
    try:
        sig = msg.get_signal_by_name(name)
    except KeyError:
        if need_counter:
            raise SourceError(
                f"DBC message {msg.name}: no counter signal {name!r}; samples are placed by frame "
                "counters (name it SEQ or set the message attribute PtiCounter)"
            ) from None
    else:
        counter = _int_field(sig)
        if counter is None or counter.signed:
            raise SourceError(
                f"DBC message {msg.name}: counter {name} must be an unsigned, byte-aligned 8/16/32/64-bit integer"
            )
    crc = None
    crc_name = _attr(msg, "PtiCrc") or "CRC"
    if any(s.name == crc_name for s in msg.signals):
        crc = _int_field(msg.get_signal_by_name(crc_name))
        if crc is None or crc.n_bytes != 2 or crc.signed:
            raise SourceError(
                f"DBC message {msg.name}: {crc_name} must be an unsigned byte-aligned 16-bit signal"
            )
    return counter, crc


def _sample_message(
    msg: Any, group: str, found: dict[str, dict[int, Any]], rows: dict[str, int]
) -> MessagePlan:
    channels = tuple(sorted(found, key=lambda c: rows[c]))
    counts = {c: sorted(found[c]) for c in channels}
    s = len(counts[channels[0]])
    for c in channels:
        if counts[c] != list(range(s)):
            raise SourceError(
                f"DBC message {msg.name}: channel {c!r} has samples {counts[c]}, expected 0..{s - 1} "
                f"like {channels[0]!r}"
            )
    scalings = []
    for c in channels:
        sc = {_scaling(found[c][k]) for k in range(s)}
        if len(sc) != 1:
            raise SourceError(
                f"DBC message {msg.name}: the samples of {c!r} differ in scale, offset, unit or size"
            )
        scalings.append(sc.pop())
    counter, crc = _counter_and_crc(msg, need_counter=True)
    sigs = [found[c][k] for k in range(s) for c in channels]
    payload = [_int_field(g) for g in sigs]
    fast = all(p is not None for p in payload)
    fields = [f for f in payload if f is not None]
    _check_fields(msg, [f for f in (counter, crc) if f] + fields)
    return MessagePlan(
        name=msg.name,
        frame_id=msg.frame_id,
        is_extended_id=bool(msg.is_extended_frame),
        length=msg.length,
        is_fd=bool(msg.is_fd),
        kind="samples",
        group=group,
        channels=channels,
        rows=tuple(rows[c] for c in channels),
        samples_per_frame=s,
        rate_hz=_rate(msg, s),
        counter=counter,
        crc=crc,
        payload=tuple(fields) if fast else (),
        scalings=tuple(scalings),
        signal_names=tuple(g.name for g in sigs),
        fast=fast,
        cantools_message=msg,
    )


def _edge_message(msg: Any, channel: str) -> MessagePlan:
    names = {s.name: s for s in msg.signals}
    for need in ("EDGE_N", "EDGE_T0"):
        if need not in names:
            raise SourceError(f"DBC message {msg.name} (edges of {channel!r}): no signal {need}")
    deltas = sorted((int(m["k"]), n) for n in names if (m := _DELTA_NAME.match(n)))
    if [k for k, _ in deltas] != list(range(1, len(deltas) + 1)):
        raise SourceError(
            f"DBC message {msg.name}: edge deltas must be EDGE_D1..EDGE_Dk without holes"
        )
    sigs = [names["EDGE_N"], names["EDGE_T0"], *(names[n] for _, n in deltas)]
    fields = [_int_field(g) for g in sigs]
    if any(f is None or f.signed for f in fields):
        raise SourceError(
            f"DBC message {msg.name}: edge signals must be unsigned byte-aligned integers"
        )
    tick = float(names["EDGE_T0"].scale)
    if any(float(names[n].scale) != tick for _, n in deltas):
        raise SourceError(
            f"DBC message {msg.name}: EDGE_T0 and the EDGE_Dk must share one factor (the tick)"
        )
    counter, crc = _counter_and_crc(msg, need_counter=True)
    _check_fields(msg, [f for f in (counter, crc, *fields) if f])
    return MessagePlan(
        name=msg.name,
        frame_id=msg.frame_id,
        is_extended_id=bool(msg.is_extended_frame),
        length=msg.length,
        is_fd=bool(msg.is_fd),
        kind="edges",
        group=channel,
        channels=(channel,),
        samples_per_frame=len(deltas) + 1,
        counter=counter,
        crc=crc,
        payload=tuple(f for f in fields if f),
        tick_s=tick,
        cantools_message=msg,
    )


def _status_message(msg: Any) -> MessagePlan:
    names = {s.name: s for s in msg.signals}
    if "STATE" not in names or "DAQ_TIME" not in names:
        raise SourceError(f"DBC message {msg.name} (PtiStatus): needs signals STATE and DAQ_TIME")
    fields = [_int_field(names["STATE"]), _int_field(names["DAQ_TIME"])]
    if any(f is None or f.signed for f in fields):
        raise SourceError(
            f"DBC message {msg.name}: STATE and DAQ_TIME must be unsigned byte-aligned integers"
        )
    counter, crc = _counter_and_crc(msg, need_counter=False)
    _check_fields(msg, [f for f in (counter, crc, *fields) if f])
    return MessagePlan(
        name=msg.name,
        frame_id=msg.frame_id,
        is_extended_id=bool(msg.is_extended_frame),
        length=msg.length,
        is_fd=bool(msg.is_fd),
        kind="status",
        group="status",
        counter=counter,
        crc=crc,
        payload=tuple(f for f in fields if f),
        tick_s=float(names["DAQ_TIME"].scale),
        cantools_message=msg,
    )


def bench_groups(bench: Bench) -> list[tuple[str, str, list[tuple[str, str, bool]]]]:
    """``(group, default unit, [(channel, why, required)])`` in the simulated source's order."""
    t = bench.tacho
    accel = [(c, f"sensor {s.name}", True) for s in bench.sensors for c in s.channels if c]
    groups = [("accel", "m/s^2", accel)]
    if t.phase_reference == "pressure":
        groups.append(
            ("pressure", "bar", [(t.pressure_channel, "cylinder-pressure phase reference", True)])
        )
    groups.append(
        ("rpm", "rpm", [(t.rpm_channel, "rpm channel of a kind='rpm' tacho", t.kind == "rpm")])
    )
    return groups


def plan_for_bench(db: Any, bench: Bench, dbc_path: str = "") -> CanPlan:
    """The messages of ``db`` that carry what ``bench`` needs, and the layout they make.

    Raises
    ------
    SourceError
        A channel the bench needs that no message carries, a tacho delivered as a
        sampled square wave (far beyond any CAN bus), channels of one group at
        different rates, a message without counter, a malformed edge message.
    """
    where = f"DBC {dbc_path}" if dbc_path else "DBC"
    t = bench.tacho
    if t.delivery != "edges":
        raise SourceError(
            f"[tacho] delivery = 'sampled' at {t.sample_rate_hz:g} Hz cannot travel over CAN; "
            "CAN DAQ modules timestamp the edges: set delivery = 'edges'"
        )
    groups = bench_groups(bench)
    wanted = {c for _, _, chans in groups for c, _, _ in chans}
    found: dict[str, dict[str, dict[int, Any]]] = {}  # message name -> channel -> k -> signal
    owner: dict[str, str] = {}
    edge_msgs: dict[str, Any] = {}
    status = None
    for msg in db.messages:
        edge_channel = _attr(msg, "PtiEdgeChannel")
        if edge_channel:
            if edge_channel in edge_msgs:
                raise SourceError(
                    f"{where}: edges of {edge_channel!r} in two messages, {edge_msgs[edge_channel].name} and {msg.name}"
                )
            edge_msgs[edge_channel] = msg
            continue
        if _attr(msg, "PtiStatus"):
            status = msg
            continue
        carried = _sample_signals(msg, wanted)
        for c in carried:
            if c in owner:
                raise SourceError(
                    f"{where}: channel {c!r} is in two messages, {owner[c]} and {msg.name}"
                )
            owner[c] = msg.name
        if carried:
            found[msg.name] = carried
    messages: list[MessagePlan] = []
    sample_groups: list[SampleGroup] = []
    for gname, unit, chans in groups:
        present = [(c, why) for c, why, _ in chans if c in owner]
        missing = [(c, why) for c, why, req in chans if req and c not in owner]
        if missing:
            c, why = missing[0]
            have = sorted(owner) or ["none"]
            raise SourceError(
                f"{where}: no signal carries channel {c!r} ({why}); channels found: {', '.join(have)} "
                f"(signals are named CHANNEL_sK or carry the attribute PtiChannel)"
            )
        if not present:
            continue
        rows = {c: i for i, (c, _) in enumerate(present)}
        gmsgs = []
        for mname in dict.fromkeys(owner[c] for c, _ in present):
            msg = db.get_message_by_name(mname)
            sub = {c: v for c, v in found[mname].items() if c in rows}
            other = [c for c in found[mname] if c not in rows]
            if other:
                raise SourceError(
                    f"{where}: message {mname} mixes channels of two groups ({other[0]!r} and {next(iter(sub))!r})"
                )
            gmsgs.append(_sample_message(msg, gname, sub, rows))
        rates = {m.rate_hz for m in gmsgs}
        if len(rates) > 1:
            desc = ", ".join(f"{m.name} {m.rate_hz:g} Hz" for m in gmsgs)
            raise SourceError(
                f"{where}: the {gname} channels must share one sample rate, got {desc}"
            )
        units = [
            next(
                sc.unit
                for m in gmsgs
                for ch, sc in zip(m.channels, m.scalings, strict=True)
                if ch == c
            )
            for c, _ in present
        ]
        specs = tuple(ChannelSpec(c, u or unit) for (c, _), u in zip(present, units, strict=True))
        sample_groups.append(SampleGroup(gname, gmsgs[0].rate_hz, specs))
        messages.extend(gmsgs)
    edge_channels = [t.channel] + ([t.cam_channel] if t.phase_reference == "cam" else [])
    for ch in edge_channels:
        if ch not in edge_msgs:
            known = ", ".join(sorted(edge_msgs)) or "none"
            raise SourceError(
                f"{where}: no edge message for tacho channel {ch!r} (message attribute PtiEdgeChannel); "
                f"edge channels found: {known}"
            )
        messages.append(_edge_message(edge_msgs[ch], ch))
    if status is not None:
        messages.append(_status_message(status))
    meta = {"source": "can", "dbc": dbc_path}
    layout = StreamLayout(tuple(sample_groups), tuple(edge_channels), meta)
    ids = frozenset((m.frame_id, bool(m.is_extended_frame)) for m in db.messages)
    return CanPlan(dbc_path, tuple(messages), layout, ids)


def load_plan(bench: Bench, dbc: str | Path | None = None) -> CanPlan:
    """:func:`plan_for_bench` of ``dbc`` (default: the bench file's ``[can] dbc``)."""
    path = dbc if dbc is not None else bench.can.dbc
    return plan_for_bench(load_dbc(path), bench, str(path))


# -- batch decoding --------------------------------------------------------------------------------


def frame_crc(data: bytes, crc: IntField) -> int:
    """CRC-16/CCITT-FALSE of every byte of ``data`` except the CRC field itself."""
    a, b = crc.byte, crc.byte + crc.n_bytes
    return binascii.crc_hqx(data[b:], binascii.crc_hqx(data[:a], CRC_INIT))


def read_fields(rows: np.ndarray, fields: Sequence[IntField]) -> np.ndarray:
    """Integer fields of many frames: ``rows`` (n, length) uint8 -> (n, n_fields) int64.

    One fancy-index gather per field size and byte order (the frames' bytes are
    copied once, whatever the number of fields).
    """
    n = rows.shape[0]
    out = np.empty((n, len(fields)), dtype=np.int64)
    by_type: dict[np.dtype, list[int]] = {}
    for i, f in enumerate(fields):
        by_type.setdefault(f.dtype, []).append(i)
    for dt, idx in by_type.items():
        start = np.array([fields[i].byte for i in idx])
        cols = (start[:, None] + np.arange(dt.itemsize)[None, :]).ravel()
        raw = np.ascontiguousarray(rows[:, cols]).view(dt).reshape(n, len(idx))
        out[:, idx] = raw
    return out


def raw_fields_slow(plan: MessagePlan, datas: Sequence[bytes]) -> np.ndarray:
    """The sample signals' raw integers through cantools, frame by frame: (n, S * n_ch) int64."""
    msg = plan.cantools_message
    out = np.empty((len(datas), len(plan.signal_names)), dtype=np.int64)
    for i, d in enumerate(datas):
        values = msg.decode(d, decode_choices=False, scaling=False)
        out[i] = [values[name] for name in plan.signal_names]
    return out


def scale_samples(plan: MessagePlan, raw: np.ndarray) -> np.ndarray:
    """Raw sample integers (n, S * n_ch) -> physical values (n, S, n_ch) float64, NaN if invalid."""
    n_ch = len(plan.channels)
    raw = raw.reshape(raw.shape[0], plan.samples_per_frame, n_ch)
    scale = np.array([s.scale for s in plan.scalings])
    offset = np.array([s.offset for s in plan.scalings])
    invalid = np.array([s.invalid_raw for s in plan.scalings])
    values = raw * scale + offset
    values[raw == invalid] = np.nan
    return values


def as_rows(datas: Sequence[bytes], length: int) -> np.ndarray:
    """Equal-length payloads as one (n, length) uint8 array."""
    return np.frombuffer(b"".join(datas), dtype=np.uint8).reshape(len(datas), length)


# -- encoding: the simulated DAQ -------------------------------------------------------------------


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


def bus_load(
    plan: CanPlan,
    *,
    bitrate: float,
    data_bitrate: float,
    edge_rate_hz: float = 0.0,
    stuffing: bool = True,
) -> float:
    """Fraction of the bus time the plan's periodic frames take (edge frames at ``edge_rate_hz`` edges/s)."""
    total = 0.0
    for m in plan.messages:
        ft = frame_time_s(
            m.length,
            fd=m.is_fd,
            bitrate=bitrate,
            data_bitrate=data_bitrate,
            extended=m.is_extended_id,
            stuffing=stuffing,
        )
        if m.kind == "samples":
            total += m.frame_rate_hz * ft
        elif m.kind == "edges" and edge_rate_hz > 0:
            total += edge_rate_hz / m.samples_per_frame * ft
    return total
