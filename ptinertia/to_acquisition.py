"""The bench file -> ``acquisition``'s own settings: the tacho, the default sweep, the channels.

``acquisition`` never sees :class:`~ptinertia.config.Bench` (as ``dsp`` takes its
tracker settings from :mod:`ptinertia.to_dsp`); these translators are the only
place the bench's ``[tacho]``, ``[simulation]`` and sensors are read for it. The CAN
settings are built in :mod:`ptinertia.to_can`.
"""

from __future__ import annotations

import dataclasses

from acquisition.channels import ChannelNeed
from acquisition.sim.sweep import RpmProfile
from acquisition.sim.tacho_synth import TachoSpec
from ptinertia.config import Bench, ChannelMap, Simulation, Tacho


def tacho_spec(tacho: Tacho) -> TachoSpec:
    """The simulated bench's view of ``[tacho]``."""
    return TachoSpec(
        kind=tacho.kind,
        teeth=tacho.teeth,
        missing=tacho.missing,
        delivery=tacho.delivery,
        sample_rate_hz=float(tacho.sample_rate_hz),
        channel=tacho.channel,
        tdc_after_gap_deg=tacho.tdc_after_gap_deg,
        tdc_offset_deg=tacho.tdc_offset_deg,
        rpm_channel=tacho.rpm_channel,
        rpm_rate_hz=float(tacho.rpm_rate_hz),
        phase_reference=tacho.phase_reference,
        cam_channel=tacho.cam_channel,
        cam_angle_deg=tacho.cam_angle_deg,
        pressure_channel=tacho.pressure_channel,
    )


def sweep_profile(sim: Simulation) -> RpmProfile:
    """The default sweep of ``[simulation]``: an optional hold, then the ramp."""
    return RpmProfile.sweep(sim.rpm_start, sim.rpm_end, sim.duration_s, sim.hold_s)


def channel_needs(bench: Bench) -> tuple[ChannelNeed, ...]:
    """Every channel a run of ``bench`` reads, in the order a missing one is reported.

    The sensors' accelerometer channels, the tacho, the rpm channel (required only by
    a ``kind = "rpm"`` tacho), the cam and the cylinder pressure of a phase reference.
    """
    t = bench.tacho
    edges = t.delivery == "edges"
    # a sampled tacho (and cam) is a square wave in the "tacho" group
    tacho_group, tacho_unit = ("edges", "") if edges else ("tacho", "V")
    rate = None if edges else float(t.sample_rate_hz)
    needs = [
        ChannelNeed(c, "accel", "m/s^2", f"sensor {s.name}")
        for s in bench.sensors
        for c in s.channels
        if c
    ]
    needs.append(
        ChannelNeed(
            t.channel, tacho_group, tacho_unit, f"tacho, delivery {t.delivery!r}", edges, True, rate
        )
    )
    needs.append(
        ChannelNeed(
            t.rpm_channel,
            "rpm",
            "rpm",
            "rpm channel of a kind='rpm' tacho",
            required=t.kind == "rpm",
        )
    )
    if t.phase_reference == "cam":
        needs.append(
            ChannelNeed(
                t.cam_channel, tacho_group, tacho_unit, "cam phase reference", edges, True, rate
            )
        )
    if t.phase_reference == "pressure":
        needs.append(
            ChannelNeed(t.pressure_channel, "pressure", "bar", "cylinder-pressure phase reference")
        )
    return tuple(_mapped(n, bench.channels.get(n.name)) for n in needs)


def recorded_channel_needs(bench: Bench) -> tuple[ChannelNeed, ...]:
    """What a run reads from a CSV or MF4 recording: :func:`channel_needs`, and the
    cylinder pressure when the gas torque may come from it (``[estimator] gas_torque``
    ``auto`` or ``pressure``), since the file source passes on only what is asked for.
    """
    needs = channel_needs(bench)
    t = bench.tacho
    if bench.estimator.gas_torque != "model" and t.pressure_channel not in {n.name for n in needs}:
        need = ChannelNeed(
            t.pressure_channel,
            "pressure",
            "bar",
            f"cylinder pressure, gas_torque {bench.estimator.gas_torque!r}",
            required=bench.estimator.gas_torque == "pressure",
        )
        needs = (*needs, _mapped(need, bench.channels.get(need.name)))
    return needs


def _mapped(need: ChannelNeed, where: str | ChannelMap | None) -> ChannelNeed:
    """``need`` with its recorded name, group and unit from the bench's ``[channels]``."""
    if where is None:
        return need
    if isinstance(where, str):
        return dataclasses.replace(need, recorded_name=where)
    return dataclasses.replace(
        need,
        recorded_name=where.name or "",
        recorded_group=where.group or "",
        declared_unit=where.unit or "",
    )
