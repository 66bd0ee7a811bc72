"""The bench file -> ``acquisition``'s own settings: the tacho, the default sweep, the channels.

``acquisition`` never sees :class:`~ptinertia.config.Bench` (as ``dsp`` takes its
tracker settings from :mod:`ptinertia.to_dsp`); these translators are the only
place the bench's ``[tacho]``, ``[simulation]`` and sensors are read for it. The CAN
settings are built in :mod:`ptinertia.to_can`.
"""

from __future__ import annotations

from acquisition.channels import ChannelNeed
from acquisition.sim.sweep import RpmProfile
from acquisition.sim.tacho_synth import TachoSpec
from ptinertia.config import Bench, Simulation, Tacho


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
    return tuple(needs)
