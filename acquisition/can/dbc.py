"""DBC -> :class:`~acquisition.can.plan.CanPlan`: the conventions that say what a frame carries.

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

Every check of a DBC against the channels a run needs
(:class:`~acquisition.channels.ChannelNeed`) happens here, once, so that a bad DBC fails before
any frame is read, with a message naming the message and signal; the codecs only touch
cantools for signals the fast path cannot read.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from acquisition.can.plan import CanPlan, ChannelScaling, IntField, MessagePlan
from acquisition.channels import ChannelNeed
from acquisition.signal_units import unit_factor
from acquisition.stream import ChannelSpec, SampleGroup, SourceError, StreamLayout

# the sample groups a CAN DAQ sends, in the simulated source's order
SAMPLE_GROUPS = ("accel", "pressure", "rpm")

_SAMPLE_NAME = re.compile(r"^(?P<channel>.+)_s(?P<k>\d+)$")
_DELTA_NAME = re.compile(r"^EDGE_D(?P<k>\d+)$")


def load_dbc(path: str | Path | None) -> Any:
    """cantools database of ``path``; :class:`SourceError` if none is named, missing or unreadable."""
    import cantools  # on use: a replay or a CSV run never needs it

    if not path:
        raise SourceError(
            'no DBC: name it in the bench file ([can] dbc = "bench.dbc") or pass --dbc '
            "(examples/bench.dbc fits the example benches)"
        )
    p = Path(path)
    if not p.is_file():
        raise SourceError(f"DBC file {str(p)!r} not found")
    # cantools logs its warnings (a duplicate id) to stderr: they are checked below instead
    log = logging.getLogger("cantools")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        db = cantools.database.load_file(str(p), database_format="dbc", strict=True)
    except (
        Exception
    ) as err:  # cantools raises many types (ParseError, UnsupportedDatabaseFormatError, ...)
        first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise SourceError(f"DBC file {str(p)!r} cannot be read: {first}") from None
    finally:
        log.setLevel(level)
    _refuse_duplicate_ids(db, p)
    return db


def _refuse_duplicate_ids(db: Any, path: Path) -> None:
    """cantools keeps the last of two messages sharing an id (with a log warning only):
    the frames would then be decoded with the wrong layout, so two are refused here."""
    seen: dict[tuple[int, bool], str] = {}
    for msg in db.messages:
        key = (msg.frame_id, bool(msg.is_extended_frame))
        if key in seen:
            raise SourceError(
                f"DBC file {str(path)!r}: messages {seen[key]} and {msg.name} share the id "
                f"0x{msg.frame_id:X}; each frame id may be defined once"
            )
        seen[key] = msg.name


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
        **_identity(msg),
        kind="status",
        group="status",
        counter=counter,
        crc=crc,
        payload=tuple(f for f in fields if f),
        tick_s=float(names["DAQ_TIME"].scale),
    )


def _sample_groups(
    needs: Sequence[ChannelNeed],
) -> list[tuple[str, str, list[tuple[str, str, bool]]]]:
    """``(group, default unit, [(channel, why, required)])`` of the sampled channels needed."""
    groups = []
    for gname in SAMPLE_GROUPS:
        chans = [(n.name, n.why, n.required) for n in needs if n.group == gname and not n.edges]
        if chans:
            unit = next(n.unit for n in needs if n.group == gname)
            groups.append((gname, unit, chans))
    return groups


def _in_pipeline_units(m: MessagePlan, needs: Sequence[ChannelNeed], where: str) -> MessagePlan:
    """``m`` with each scaling taken from its DBC unit to the pipeline's (decode and encode)."""
    need, scalings = {n.name: n for n in needs}, []
    for c, sc in zip(m.channels, m.scalings, strict=True):
        at = f"{where}: message {m.name} channel {c!r} ({need[c].why})"
        f = unit_factor(need[c].declared_unit or sc.unit, need[c].unit, at)
        scalings.append(sc.in_unit(need[c].unit, f))
    return dataclasses.replace(m, scalings=tuple(scalings))


def plan_for_channels(db: Any, needs: Sequence[ChannelNeed], dbc_path: str = "") -> CanPlan:
    """The messages of ``db`` that carry the channels ``needs``, and the layout they make.

    Raises
    ------
    SourceError
        A channel the bench needs that no message carries, a tacho delivered as a
        sampled square wave (far beyond any CAN bus), channels of one group at
        different rates, a message without counter, a malformed edge message.
    """
    where = f"DBC {dbc_path}" if dbc_path else "DBC"
    sampled_tacho = next((n for n in needs if n.group == "tacho"), None)
    if sampled_tacho is not None:
        raise SourceError(
            f"[tacho] delivery = 'sampled' at {sampled_tacho.rate_hz or 0:g} Hz cannot travel over CAN; "
            "CAN DAQ modules timestamp the edges: set delivery = 'edges'"
        )
    groups = _sample_groups(needs)
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
        gmsgs = [_in_pipeline_units(m, needs, where) for m in gmsgs]
        specs = tuple(ChannelSpec(c, unit) for c, _ in present)
        sample_groups.append(SampleGroup(gname, gmsgs[0].rate_hz, specs))
        messages.extend(gmsgs)
    edge_channels = [n.name for n in needs if n.edges]
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


def load_plan(needs: Sequence[ChannelNeed], dbc: str | Path | None) -> CanPlan:
    """:func:`plan_for_channels` of the DBC file ``dbc``."""
    return plan_for_channels(load_dbc(dbc), needs, str(dbc))
