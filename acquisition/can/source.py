"""CAN sources: the log/replay source over raw frames and the ``can:`` registry entry.

:class:`CanFrameSource` decodes batches of raw frames (a CAN log, raw frames replayed from
a recording); :func:`open_can` builds the live :class:`~acquisition.can.bus.CanBusSource`
for ``--source can:INTERFACE:CHANNEL`` (``ptinertia.registry`` names it here) from the
bus settings (:class:`CanSettings`) and the channels the run needs. The decoding itself
is in :mod:`acquisition.can.decoder`, the live bus in :mod:`acquisition.can.bus`.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from acquisition.can.bus import CanBusSource
from acquisition.can.dbc import load_plan
from acquisition.can.decoder import FrameDecoder
from acquisition.can.frames import RawFrame
from acquisition.can.plan import CanPlan
from acquisition.can.reorder import DecoderOptions
from acquisition.can.stats import DecoderStats
from acquisition.channels import ChannelNeed
from acquisition.stream import Source, SourceError, SourceEvent, StreamItem, StreamLayout


@dataclass(frozen=True)
class CanSettings:
    """The bus a CAN acquisition listens on, and the DBC that maps its frames to channels.

    Attributes
    ----------
    dbc : str or None
        DBC file (None: none named, :func:`~acquisition.can.dbc.load_dbc` says so).
    interface, channel : str
        python-can interface and channel.
    bitrate, data_bitrate : int
        Arbitration and CAN FD data bit rates, bit/s.
    fd : bool
        CAN FD.
    bus_options : dict
        Interface-specific ``can.Bus`` arguments (as python-can's own tools pass them).
    start_timeout_s : float or None
        A live run that receives no frame this long after opening ends and says what to check.
    """

    dbc: str | None
    interface: str
    channel: str
    bitrate: int
    data_bitrate: int
    fd: bool
    bus_options: dict[str, Any] = field(default_factory=dict)
    start_timeout_s: float | None = 30.0


class CanFrameSource(Source):
    """A source over batches of raw frames (a CAN log, raw frames replayed from a recording).

    Parameters
    ----------
    plan : CanPlan
    batches : iterable of sequences of RawFrame
    options : DecoderOptions
    metadata : extra layout metadata
    """

    def __init__(
        self,
        plan: CanPlan,
        batches: Iterable[Sequence[RawFrame]],
        options: DecoderOptions | None = None,
        metadata: dict[str, Any] | None = None,
    ) -> None:
        super().__init__()
        self.decoder = FrameDecoder(plan, options)
        self._batches = batches
        meta = dict(plan.layout.metadata)
        meta.update(metadata or {})
        self._layout = StreamLayout(plan.layout.groups, plan.layout.edge_channels, meta)

    @property
    def layout(self) -> StreamLayout:
        return self._layout

    @property
    def stats(self) -> DecoderStats:
        return self.decoder.stats

    def _iter_items(self) -> Iterator[StreamItem]:
        for batch in self._batches:
            yield from self.decoder.feed(batch)
        yield from self.decoder.finish()
        yield SourceEvent(
            "can_stats", self.decoder.stats.summary(), None, self.decoder.stats.total("lost")
        )


CAN_OPTIONS = (
    "dbc",
    "bitrate",
    "data_bitrate",
    "fd",
    "bus_kwargs",
    "reorder_window_s",
    "idle_timeout_s",
    "stop_grace_s",
    "max_outage_s",
    "frame_listener",
    "block_s",
    "start_timeout_s",
    "clock",
)


def open_can(
    arg: str, settings: CanSettings, needs: Sequence[ChannelNeed], **overrides: Any
) -> CanBusSource:
    """The live source of ``--source can:INTERFACE:CHANNEL`` reading the channels ``needs``.

    Either part of ``arg`` defaults to ``settings`` (the bench file's ``[can]``).

    Overrides: ``dbc``, ``bitrate``, ``data_bitrate``, ``fd``, ``bus_kwargs`` (added to
    ``settings.bus_options``), ``reorder_window_s``, ``idle_timeout_s``, ``stop_grace_s``,
    ``max_outage_s``, ``frame_listener``, ``start_timeout_s``, ``clock``.
    """
    bad = sorted(set(overrides) - set(CAN_OPTIONS))
    if bad:
        raise SourceError(
            f"source 'can:{arg}': unknown option {bad[0]!r}; known: {', '.join(CAN_OPTIONS)}"
        )
    interface, _, channel = arg.partition(":")
    cfg = settings
    interface = interface or cfg.interface
    channel = channel or cfg.channel
    dbc = overrides.get("dbc")
    plan = load_plan(needs, cfg.dbc if dbc is None else dbc)
    fd = bool(overrides.get("fd", cfg.fd))
    if not fd:
        fd_msgs = [m.name for m in plan.messages if m.is_fd]
        if fd_msgs:
            raise SourceError(
                f"the DBC's {fd_msgs[0]} is a CAN FD frame but the bus is classic CAN (fd = false)"
            )
    kwargs: dict[str, Any] = {"fd": fd, "bitrate": int(overrides.get("bitrate", cfg.bitrate))}
    if fd:
        kwargs["data_bitrate"] = int(overrides.get("data_bitrate", cfg.data_bitrate))
    kwargs.update(cfg.bus_options)
    kwargs.update(overrides.get("bus_kwargs") or {})
    opts = DecoderOptions(
        reorder_window_s=float(overrides.get("reorder_window_s", DecoderOptions.reorder_window_s))
    )
    return CanBusSource(
        plan,
        interface=interface,
        channel=channel,
        bus_kwargs=kwargs,
        options=opts,
        idle_timeout_s=overrides.get("idle_timeout_s", 10.0),
        stop_grace_s=float(overrides.get("stop_grace_s", 0.2)),
        max_outage_s=float(overrides.get("max_outage_s", 60.0)),
        frame_listener=overrides.get("frame_listener"),
        start_timeout_s=overrides.get("start_timeout_s", cfg.start_timeout_s),
        clock=overrides.get("clock"),
    )
