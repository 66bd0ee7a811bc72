"""The bench file -> dsp translator (ptinertia/to_dsp.py)."""

from __future__ import annotations

import dataclasses

from dsp.tacho import TachoConfig
from ptinertia.config import Bench, Tacho
from ptinertia.to_dsp import tacho_config, tracker_config


def test_every_tacho_key_the_tracker_shares_reaches_it() -> None:
    table = Tacho(
        kind="pulses", teeth=36, missing=0, delivery="sampled", channel="crank",
        tdc_after_gap_deg=12.0, tdc_offset_deg=-1.5, rpm_channel="n", phase_reference="cam",
        cam_channel="cam1", cam_angle_deg=400.0, pressure_channel="p1",
    )  # fmt: skip
    got = tacho_config(table)
    shared = {f.name for f in dataclasses.fields(TachoConfig)} & set(Tacho.model_fields)
    assert {k: getattr(got, k) for k in shared} == {k: getattr(table, k) for k in shared}
    # the tracker's own settings keep their defaults
    default = TachoConfig()
    only_dsp = {f.name for f in dataclasses.fields(TachoConfig)} - shared
    assert {k: getattr(got, k) for k in only_dsp} == {k: getattr(default, k) for k in only_dsp}
    assert only_dsp == {"threshold_low", "threshold_high", "tolerance"}


def test_tracker_config_takes_the_bench_tacho(i3: Bench) -> None:
    assert tracker_config(i3).tacho == tacho_config(i3.tacho)
