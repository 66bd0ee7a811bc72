"""The bench file -> ``acquisition.can``'s settings: the bus, the DBC and the plan of a run.

``acquisition.can`` never sees :class:`~ptinertia.config.Bench`: it takes the bus
settings (:class:`~acquisition.can.source.CanSettings`) and the channels the run needs
(:func:`ptinertia.to_acquisition.channel_needs`), built here from ``[can]``,
``[tacho]`` and the sensors.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from acquisition.can.dbc import load_plan
from acquisition.can.plan import CanPlan
from acquisition.can.source import CanSettings
from ptinertia.config import Bench, Can
from ptinertia.errors import UsageError
from ptinertia.to_acquisition import channel_needs


def can_settings(can: Can) -> CanSettings:
    """``[can]`` as the CAN sources take it."""
    return CanSettings(
        dbc=can.dbc,
        interface=can.interface,
        channel=can.channel,
        bitrate=int(can.bitrate),
        data_bitrate=int(can.data_bitrate),
        fd=bool(can.fd),
        bus_options=dict(can.bus_options),
        start_timeout_s=can.start_timeout_s,
    )


def can_plan(bench: Bench, dbc: str | Path | None = None) -> CanPlan:
    """The DBC plan of the channels ``bench`` needs.

    Parameters
    ----------
    bench : Bench
    dbc : path or None
        The DBC file; None: the bench file's ``[can] dbc``.

    Raises
    ------
    SourceError
        No DBC named, an unreadable one, or one that lacks a channel the bench needs.
    """
    return load_plan(channel_needs(bench), bench.can.dbc if dbc is None else dbc)


def parse_bus_options(items: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` pairs as ``can.Bus`` arguments: integers, numbers, true/false, else text."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"--bus-option: expected KEY=VALUE, got {item!r}")
        value: Any = text
        if text.lower() in ("true", "false"):
            value = text.lower() == "true"
        else:
            for kind in (int, float):
                try:
                    value = kind(text)
                    break
                except ValueError:
                    continue
        out[key.strip()] = value
    return out
