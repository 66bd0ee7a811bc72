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
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from acquisition.can.message_plans import (
    dbc_attribute,
    edge_message,
    sample_message,
    sample_signals,
    status_message,
)
from acquisition.can.plan import CanPlan, MessagePlan
from acquisition.channels import ChannelNeed
from acquisition.signal_units import unit_factor
from acquisition.stream import ChannelSpec, SampleGroup, SourceError, StreamLayout

# the sample groups a CAN DAQ sends, in the simulated source's order
SAMPLE_GROUPS = ("accel", "pressure", "rpm")


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
        edge_channel = dbc_attribute(msg, "PtiEdgeChannel")
        if edge_channel:
            if edge_channel in edge_msgs:
                raise SourceError(
                    f"{where}: edges of {edge_channel!r} in two messages, {edge_msgs[edge_channel].name} and {msg.name}"
                )
            edge_msgs[edge_channel] = msg
            continue
        if dbc_attribute(msg, "PtiStatus"):
            status = msg
            continue
        carried = sample_signals(msg, wanted)
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
            gmsgs.append(sample_message(msg, gname, sub, rows))
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
        messages.append(edge_message(edge_msgs[ch], ch))
    if status is not None:
        messages.append(status_message(status))
    meta = {"source": "can", "dbc": dbc_path}
    layout = StreamLayout(tuple(sample_groups), tuple(edge_channels), meta)
    ids = frozenset((m.frame_id, bool(m.is_extended_frame)) for m in db.messages)
    return CanPlan(dbc_path, tuple(messages), layout, ids)


def load_plan(needs: Sequence[ChannelNeed], dbc: str | Path | None) -> CanPlan:
    """:func:`plan_for_channels` of the DBC file ``dbc``."""
    return plan_for_channels(load_dbc(dbc), needs, str(dbc))
