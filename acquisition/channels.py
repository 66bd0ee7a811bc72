"""The channels a run reads, and the check that a recording carries them.

A bench says which channels the estimate needs (its sensors, the tacho, an rpm, cam
or cylinder-pressure channel); the application's translator
(``ptinertia.to_acquisition.channel_needs``) turns it into a tuple of
:class:`ChannelNeed`, derived once. A CSV, MF4 or MCAP recording is checked with
:func:`check_channels`; the CAN plan (:mod:`acquisition.can.dbc`) looks for the same
channels in a DBC.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from acquisition.stream import SourceError, StreamLayout


@dataclass(frozen=True)
class ChannelNeed:
    """One channel a run reads.

    Attributes
    ----------
    name : str
        The channel's name in the recording, the DBC or the simulated source.
    group : str
        The sample group the simulated source puts it in (``"accel"``,
        ``"pressure"``, ``"rpm"``, ``"tacho"``), or ``"edges"`` for an edge channel.
    unit : str
        The unit the pipeline takes it in (``"m/s^2"``, ``"rpm"``, ``"bar"``, ``"V"``;
        ``""`` for an edge channel): a recording's own unit is converted to it
        (:mod:`acquisition.signal_units`).
    why : str
        What needs it, for messages (``"sensor A_engine"``, ``"cam phase reference"``).
    edges : bool
        Delivered as edge timestamps (a counter input) rather than sampled.
    required : bool
        False: read when present, not missed when absent (the rpm channel of a
        wheel tacho).
    rate_hz : float or None
        The rate the bench declares for it (a sampled tacho), for messages.
    recorded_name : str
        Its name in a recording when that differs (the bench's ``[channels]`` table);
        ``""``: the same as ``name``.
    recorded_group : str
        The recording's group (an MDF4 channel group's acquisition name or index, a
        CSV file's group) that holds it, where names repeat; ``""``: any group.
    declared_unit : str
        The unit the bench declares for it, overriding the recording's own (for a
        recording that gives none or one no unit library knows); ``""``: the recording's.
    """

    name: str
    group: str
    unit: str
    why: str
    edges: bool = False
    required: bool = True
    rate_hz: float | None = None
    recorded_name: str = ""
    recorded_group: str = ""
    declared_unit: str = ""

    @property
    def file_name(self) -> str:
        """Its name in the recording."""
        return self.recorded_name or self.name


def check_channels(layout: StreamLayout, needs: Sequence[ChannelNeed], where: str) -> None:
    """Raise :class:`SourceError` naming the first required channel that ``layout`` lacks."""
    sampled = set(layout.channel_names)
    edges = set(layout.edge_channels)
    for need in needs:
        if not need.required:
            continue
        name, why = need.name, need.why
        if need.edges and name not in edges:
            hint = (
                " (it is a sampled channel there: set [tacho] delivery = 'sampled')"
                if name in sampled
                else ""
            )
            raise SourceError(
                f"{where}: edge channel {name!r} ({why}) not found{hint}; edge channels: "
                f"{', '.join(sorted(edges)) or 'none'}"
            )
        if not need.edges and name not in sampled:
            hint = (
                " (it is an edge channel there: set [tacho] delivery = 'edges')"
                if name in edges
                else ""
            )
            raise SourceError(
                f"{where}: channel {name!r} ({why}) not found{hint}; "
                f"channels: {', '.join(layout.channel_names)}"
            )
