"""Which channels of a recording a run reads: found by name, in the bench's units.

A file holds groups of channels (an MDF4 channel group, a CSV file), each with a
time (master) channel. A bench needs some of them
(:class:`acquisition.channels.ChannelNeed`, names mapped by the bench's
``[channels]`` table): :func:`select` finds each by its recorded name, in the
group the bench names where names repeat, and converts its unit to the one the
pipeline takes (:mod:`acquisition.signal_units`). The rest of the file is never
read, so a group nobody needs may hold anything (events, another rate, a
non-uniform time).

An edge channel is read from an *event group*: one record per edge, the edge time
in the group's master channel, the channel a constant marker (a DAQ's ``1`` at each
edge); ptinertia's own edge groups and single-column CSV edge files hold the times
themselves (an *edge list*). Kept apart from the readers because it knows no file
format: :mod:`acquisition.files.csvfile` and :mod:`acquisition.files.mdf` describe
their groups and supply the chunks.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from acquisition.channels import ChannelNeed
from acquisition.files.windowed import Chunk
from acquisition.signal_units import UnitError, unit_factor
from acquisition.stream import ChannelSpec, SourceError


@dataclass(frozen=True)
class FileGroup:
    """One group of a recording as its header describes it.

    ``key`` is the reader's handle (an MDF group index, a CSV file's position);
    ``label`` names it in messages and in the layout, ``aliases`` are the other
    names a ``[channels]`` group may give it; ``edge_list`` is a group whose rows
    are edge times (no sampled channel in it).
    """

    key: int
    label: str
    channels: tuple[ChannelSpec, ...]
    aliases: tuple[str, ...] = ()
    edge_list: bool = False


@dataclass(frozen=True)
class SampledPick:
    """The channels read from one group: file columns, bench names and units, factors."""

    group: FileGroup
    columns: tuple[int, ...]
    specs: tuple[ChannelSpec, ...]
    factors: tuple[float, ...]


@dataclass(frozen=True)
class EdgePick:
    """An edge channel: its group's times, from an edge list or an event group's column."""

    group: FileGroup
    column: int
    channel: str


def select_all(groups: Sequence[FileGroup]) -> tuple[list[SampledPick], list[EdgePick]]:
    """Every channel as the file has it (no bench: names and units unchecked)."""
    sampled = [
        SampledPick(g, tuple(range(len(g.channels))), g.channels, (1.0,) * len(g.channels))
        for g in groups
        if not g.edge_list
    ]
    edges = [EdgePick(g, 0, g.channels[0].name) for g in groups if g.edge_list]
    return sampled, edges


def _locate(
    groups: Sequence[FileGroup], need: ChannelNeed, where: str
) -> tuple[FileGroup, int] | None:
    wanted = need.file_name
    hits = [(g, i) for g in groups for i, c in enumerate(g.channels) if c.name == wanted]
    if need.recorded_group:
        named = [(g, i) for g, i in hits if need.recorded_group in (g.label, *g.aliases)]
        if not named and hits:
            raise SourceError(
                f"{where}: channel {wanted!r} ({need.why}) is not in group "
                f"{need.recorded_group!r} (the bench's [channels]); it is in group "
                + ", ".join(repr(g.label) for g, _ in hits)
            )
        hits = named
    if len(hits) > 1:
        raise SourceError(
            f"{where}: channel {wanted!r} ({need.why}) is in groups "
            + ", ".join(repr(g.label) for g, _ in hits)
            + f": name its group in the bench's [channels] ({need.name} = "
            f"{{ name = {wanted!r}, group = ... }})"
        )
    if hits:
        return hits[0]
    if not need.required:
        return None
    edge_names = [c.name for g in groups if g.edge_list for c in g.channels]
    sampled_names = [c.name for g in groups if not g.edge_list for c in g.channels]
    hint = ""
    if need.recorded_group:
        hint = f" in group {need.recorded_group!r}"
    if need.edges:
        raise SourceError(
            f"{where}: edge channel {wanted!r} ({need.why}) not found{hint}; channels: "
            f"{', '.join(edge_names + sampled_names) or 'none'}"
        )
    raise SourceError(
        f"{where}: channel {wanted!r} ({need.why}) not found{hint}; "
        f"channels: {', '.join(sampled_names + edge_names) or 'none'}"
    )


def _factor(need: ChannelNeed, spec: ChannelSpec, where: str) -> float:
    unit = need.declared_unit or spec.unit
    try:
        return unit_factor(unit, need.unit)
    except UnitError as err:
        raise SourceError(
            f"{where}: channel {spec.name!r} ({need.why}): {err}; declare its unit in the "
            f'bench\'s [channels] ({need.name} = {{ name = {spec.name!r}, unit = "..." }})'
        ) from None


def select(
    groups: Sequence[FileGroup], needs: Sequence[ChannelNeed], where: str
) -> tuple[list[SampledPick], list[EdgePick]]:
    """The channels ``needs`` asks for, found in ``groups``, with their unit factors.

    Raises
    ------
    SourceError
        A required channel missing (or not in the group the bench names), a name in
        several groups with no group named, a unit unknown or of another quantity, a
        sampled channel found as edges or edges in a group that also holds sampled
        channels the run reads.
    """
    found: dict[int, list[tuple[int, ChannelNeed]]] = {}
    edges: list[EdgePick] = []
    by_key = {g.key: g for g in groups}
    for need in needs:
        hit = _locate(groups, need, where)
        if hit is None:
            continue
        g, col = hit
        if need.edges:
            edges.append(EdgePick(g, col, need.name))
            continue
        if g.edge_list:
            raise SourceError(
                f"{where}: channel {need.file_name!r} ({need.why}) not found (it is an edge "
                "channel there: set [tacho] delivery = 'edges')"
            )
        found.setdefault(g.key, []).append((col, need))
    for e in edges:
        others = [n.name for _, n in found.get(e.group.key, [])] + [
            x.channel for x in edges if x.group.key == e.group.key and x is not e
        ]
        if others:
            raise SourceError(
                f"{where}: group {e.group.label!r} holds edge channel {e.channel!r} and "
                f"channel {others[0]!r}: an event group holds the edges of one channel only"
            )
    picks = []
    for key, cols in found.items():
        g = by_key[key]
        cols.sort(key=lambda cn: cn[0])
        picks.append(
            SampledPick(
                g,
                tuple(c for c, _ in cols),
                tuple(ChannelSpec(n.name, n.unit) for _, n in cols),
                tuple(_factor(n, g.channels[c], where) for c, n in cols),
            )
        )
    picks.sort(key=lambda p: p.group.key)
    return picks, edges


def scaled(
    chunks: Iterator[Chunk], rows: Sequence[int] | None, factors: Sequence[float]
) -> Iterator[Chunk]:
    """``chunks`` with only ``rows`` of their data (all when None), each times its factor."""
    f = np.asarray(factors, dtype=float)[:, None]
    identity = bool(np.all(f == 1.0))
    for row0, times, data in chunks:
        if data is not None:
            if rows is not None:
                data = data[list(rows)]
            if not identity:
                data = data * f
        yield row0, times, data


def event_times(chunks: Iterator[Chunk], row: int, channel: str, where: str) -> Iterator[Chunk]:
    """The master times of an event group, checking its marker channel stays constant.

    A channel that changes value is a sampled wave, not one record per edge: taking
    every sample time as an edge would hand the dsp nonsense.
    """
    marker: float | None = None
    for row0, times, data in chunks:
        if data is not None and data.shape[1]:
            values = data[row]
            if marker is None:
                marker = float(values[0])
            moved = np.flatnonzero(values != marker)
            if moved.size:
                i = int(moved[0])
                raise SourceError(
                    f"{where}: edge channel {channel!r} changes value ({marker:g} then "
                    f"{float(values[i]):g} at record {row0 + i}): expected an event group "
                    "(one record per edge, a constant marker); a sampled tacho wave needs "
                    "[tacho] delivery = 'sampled'"
                )
        yield row0, times, None


def unique_labels(groups: Sequence[FileGroup]) -> list[str]:
    """The groups' labels, a repeated one suffixed with its key (``accel#3``)."""
    labels = [g.label for g in groups]
    return [g.label if labels.count(g.label) == 1 else f"{g.label}#{g.key}" for g in groups]
