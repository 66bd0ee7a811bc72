"""One DBC message -> its :class:`~acquisition.can.plan.MessagePlan`.

The sample, edge and status messages of the ptinertia DAQ convention (fields, scaling,
rate, counter and CRC), each checked as it is read; :mod:`acquisition.can.dbc` picks the
messages a bench needs and assembles the plan.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import Any

from acquisition.can.plan import ChannelScaling, IntField, MessagePlan
from acquisition.stream import SourceError

# DBC signal names of the convention: CHANNEL_s<k> (k-th sample of a frame), EDGE_D<k>
_SAMPLE_NAME = re.compile(r"^(?P<channel>.+)_s(?P<k>\d+)$")
_DELTA_NAME = re.compile(r"^EDGE_D(?P<k>\d+)$")


def dbc_attribute(obj: Any, name: str, default: Any = None) -> Any:
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


def sample_signals(msg: Any, wanted: set[str]) -> dict[str, dict[int, Any]]:
    """channel -> {sample index k -> signal} for the wanted channels in ``msg``."""
    out: dict[str, dict[int, Any]] = {}
    for sig in msg.signals:
        channel = dbc_attribute(sig, "PtiChannel") or None
        k = dbc_attribute(sig, "PtiSample", 0)
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
    rate = dbc_attribute(msg, "PtiSampleRate")
    if rate:
        return float(rate)
    cycle = dbc_attribute(msg, "GenMsgCycleTime") or msg.cycle_time
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
    name = dbc_attribute(msg, "PtiCounter") or "SEQ"
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
    crc_name = dbc_attribute(msg, "PtiCrc") or "CRC"
    if any(s.name == crc_name for s in msg.signals):
        crc = _int_field(msg.get_signal_by_name(crc_name))
        if crc is None or crc.n_bytes != 2 or crc.signed:
            raise SourceError(
                f"DBC message {msg.name}: {crc_name} must be an unsigned byte-aligned 16-bit signal"
            )
    return counter, crc


def sample_message(
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
        **_identity(msg),
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
    )


def edge_message(msg: Any, channel: str) -> MessagePlan:
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
        **_identity(msg),
        kind="edges",
        group=channel,
        channels=(channel,),
        samples_per_frame=len(deltas) + 1,
        counter=counter,
        crc=crc,
        payload=tuple(f for f in fields if f),
        tick_s=tick,
    )


def _identity(msg: Any) -> dict[str, Any]:
    """The fields of a :class:`MessagePlan` that come from the DBC message as they are."""
    return {
        "name": msg.name,
        "frame_id": msg.frame_id,
        "is_extended_id": bool(msg.is_extended_frame),
        "length": msg.length,
        "is_fd": bool(msg.is_fd),
        "cantools_message": msg,
    }


def status_message(msg: Any) -> MessagePlan:
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
        **_identity(msg),
        kind="status",
        group="status",
        counter=counter,
        crc=crc,
        payload=tuple(f for f in fields if f),
        tick_s=float(names["DAQ_TIME"].scale),
    )
