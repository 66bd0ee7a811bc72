"""The bench description: a validated TOML file (see ``docs/bench-file.md``).

One schema serves simulation (``[powertrain]`` is the truth) and estimation
(``[powertrain]`` holds nominal or weighed values). The tables that describe the
powertrain are in :mod:`ptinertia.config_powertrain`, the field types they share in
:mod:`ptinertia.config_fields`; this module holds the acquisition, processing and
simulation settings and the file as a whole. Keys are SI or carry their
unit (``stroke_mm``); :mod:`acquisition.units` converts. Every error names the
key path and what was expected, on one line (:class:`ConfigError`).
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from acquisition.tables import format_validation_error
from ptinertia.config_fields import (
    MAX_ACCEL_RATE_HZ,
    MAX_TACHO_RATE_HZ,
    NonNegative,
    Positive,
    Section,
    Seed,
    rate_at_most,
)
from ptinertia.config_powertrain import (
    Engine,
    GasOrders,
    GasParametric,
    GasTrace,
    Mount,
    Powertrain,
    Sensor,
)

# discriminator tags pydantic puts in error locations of the [gas] union
GAS_MODELS = ("parametric", "trace", "orders")


class ConfigError(ValueError):
    """A bench file that cannot be used; the message is one line naming the key."""


class Meta(Section):
    name: str = "bench"
    description: str = ""


class Tacho(Section):
    """How crank angle reaches us.

    ``kind``: ``wheel`` (N-M tooth wheel), ``pulses`` (N per rev), ``rpm``
    (rpm channel integrated, anchored by a once-per-rev TDC pulse on ``channel``).
    ``delivery``: ``edges`` (counter input timestamps) or ``sampled`` (square
    wave at ``sample_rate_hz``). ``tdc_after_gap_deg``: crank angle from the
    first tooth edge after the gap (or the pulse) to cylinder-1 TDC.
    """

    kind: Literal["wheel", "pulses", "rpm"] = "wheel"
    teeth: Annotated[int, Field(ge=1)] = 60
    missing: Annotated[int, Field(ge=0)] = 2
    delivery: Literal["edges", "sampled"] = "edges"
    sample_rate_hz: Positive = 200_000.0
    channel: str = "tacho"
    tdc_after_gap_deg: float = 90.0
    tdc_offset_deg: float = 0.0
    rpm_channel: str = "rpm"
    rpm_rate_hz: Positive = 100.0
    phase_reference: Literal["none", "cam", "pressure"] = "none"
    cam_channel: str = "cam"
    cam_angle_deg: float = 0.0
    pressure_channel: str = "p_cyl1"

    @field_validator("sample_rate_hz", "rpm_rate_hz")
    @classmethod
    def _rate(cls, v: float) -> float:
        return rate_at_most(v, MAX_TACHO_RATE_HZ, "tacho or rpm rate")

    @model_validator(mode="after")
    def _wheel(self) -> Tacho:
        if self.kind == "wheel" and self.missing >= self.teeth:
            raise ValueError(f"missing: a wheel of {self.teeth} teeth cannot miss {self.missing}")
        return self


class Sampling(Section):
    accel_rate_hz: Positive = 5120.0

    @field_validator("accel_rate_hz")
    @classmethod
    def _rate(cls, v: float) -> float:
        return rate_at_most(v, MAX_ACCEL_RATE_HZ, "accelerometer rate")


class ElasticMode(Section):
    """First elastic mode of the simulated powertrain (see ``powertrain/model.py``)."""

    frequency_hz: Positive
    damping_ratio: Positive = 0.02
    participation: Positive = 1.0
    rigid_share: Annotated[float, Field(ge=0, le=1)] = 0.5


class Simulation(Section):
    rpm_start: Positive = 1500.0
    rpm_end: Positive = 4500.0
    duration_s: Positive = 60.0
    hold_s: NonNegative = 0.0
    noise_snr_db: float | None = None
    seed: Seed = 0
    gain_error_pct: NonNegative = 0.0
    misalignment_deg: NonNegative = 0.0
    position_error_m: NonNegative = 0.0
    residual_unbalance_kgm: NonNegative = 0.0
    residual_unbalance_deg: float = 0.0
    residual_unbalance_axial_m: float = 0.0
    elastic_mode: ElasticMode | None = None
    max_order: Annotated[float, Field(ge=1, le=12)] = 6.0
    # the engine burns this much more (or less) than [gas] says: a gas model that is off
    heat_release_error_pct: Annotated[float, Field(gt=-100)] = 0.0
    # the engine and mounts built differently from the bench file (the model inputs the
    # estimator takes as known, with the tolerances of [estimator]): relative errors in %
    spin_inertia_error_pct: Annotated[float, Field(gt=-100)] = 0.0
    piston_mass_error_pct: Annotated[float, Field(gt=-100)] = 0.0
    conrod_mass_error_pct: Annotated[float, Field(gt=-100)] = 0.0
    # every mount's stiffness by one value, or one value per mount ([[mounts]] order)
    mount_stiffness_error_pct: float | list[float] = 0.0
    crankcase_pressure_error_pa: float = 0.0
    # accelerometer channels that read NaN all run (a broken cable, an open input)
    dead_channels: list[str] = Field(default_factory=list)


class Dsp(Section):
    """Order tracking settings (see ``dsp/``)."""

    orders: Annotated[list[float], Field(min_length=1)] = Field(
        default_factory=lambda: [1.0, 1.5, 2.0]
    )
    frames_per_rev: Positive = 1.0
    rpm_min: Positive = 300.0
    rpm_max: Positive = 9000.0

    @field_validator("orders")
    @classmethod
    def _half_orders(cls, v: list[float]) -> list[float]:
        for h in v:
            if h <= 0 or abs(2 * h - round(2 * h)) > 1e-9:
                raise ValueError(f"orders must be positive multiples of 0.5, got {h}")
        return v


class EstimatorSettings(Section):
    """Estimator corrections, gates and declared sensor tolerances (see ``estimator/``)."""

    suspension: bool = True
    gyroscopic: bool = True
    unbalance: bool = True
    # estimate the unbalance's location along the crank (and any couple unbalance) too:
    # for a residual unbalance away from [engine] reference_point_m
    unbalance_location: bool = False
    crank_offset: bool = True
    # estimate one stiffness scale per mount (uncertain mount data); needs mass_known
    mount_scale: bool = False
    # gas torque from [gas] ("model"), from the cylinder-pressure channel [tacho]
    # pressure_channel ("pressure"), or from the channel when the source has it ("auto")
    gas_torque: Literal["auto", "model", "pressure"] = "auto"
    # estimate each channel's gain and each sensor's alignment with the rest (needs more
    # than six accelerometer channels: the rigid fit's redundancy, estimator/redundancy.py)
    self_calibration: bool = False
    # the channels' weights in the rigid fit: "measured" (each by its noise, measured
    # along the sweep from the scatter of its order amplitudes, estimator/channel_noise.py),
    # "equal", or "auto": measured with self_calibration, equal without. Without
    # self-calibration the sensors' systematic errors dominate, and equal weights keep
    # the low-noise channels' errors from dominating (measured on the simulated i3: cog
    # interval 2.9 -> 5.2 mm with measured weights).
    channel_weights: Literal["auto", "measured", "equal"] = "auto"
    pressure_max_order: Annotated[float, Field(gt=0, le=20)] = 6.0
    forgetting: Annotated[float, Field(gt=0, le=1)] = 1.0
    gain_tolerance_pct: NonNegative = 1.0
    alignment_tolerance_deg: NonNegative = 1.0
    position_tolerance_m: NonNegative = 0.002
    # declared 1-sigma uncertainty of the model inputs taken as known, propagated into the
    # intervals (ptinertia/to_model_inputs.py); 0: known exactly. Gas: a parametric model's
    # heat release, a trace's or torque table's gas torque (not used with a pressure channel)
    gas_tolerance_pct: NonNegative = 5.0
    spin_inertia_tolerance_pct: NonNegative = 5.0  # [engine] crank_spin_inertia_kgm2
    piston_mass_tolerance_pct: NonNegative = 2.0  # [engine] piston_mass_kg (reciprocating)
    conrod_mass_tolerance_pct: NonNegative = 1.0  # [engine] conrod_mass_kg
    # each mount's stiffness, independently (not used with mount_scale: estimated then)
    mount_stiffness_tolerance_pct: NonNegative = 15.0
    crankcase_pressure_tolerance_pa: NonNegative = 2000.0  # [gas] crankcase_pressure_pa
    max_relative_residual: Positive = 0.05
    max_rpm_change: Positive = 0.03
    min_mode_ratio: NonNegative = 1.25
    rpm_min: NonNegative = 0.0
    rpm_max: Positive = 1e6


class Can(Section):
    """CAN acquisition: the DBC that maps frames to channels, and the bus."""

    dbc: str | None = None
    # python-can-remote: a bus that crosses processes over loopback (docs/can.md)
    interface: str = "remote"
    channel: str = "ws://127.0.0.1:54701/"
    bitrate: Annotated[int, Field(gt=0)] = 500_000
    data_bitrate: Annotated[int, Field(gt=0)] = 2_000_000
    fd: bool = True
    bus_options: dict[str, str | int | float | bool] = Field(default_factory=dict)
    start_timeout_s: Annotated[float, Field(gt=0)] | None = 30.0


class ChannelMap(Section):
    """Where a recording keeps one of the bench's channels (``[channels]``).

    ``name``: the channel's name in the file (default: the bench's name); ``group``:
    the MDF4 channel group (acquisition name or index) or CSV group holding it, where
    names repeat; ``unit``: its unit, overriding the file's (a file without units,
    or with one no unit library knows).
    """

    name: str | None = None
    group: str | None = None
    unit: str | None = None


class Bench(Section):
    meta: Meta = Field(default_factory=Meta)
    powertrain: Powertrain
    mounts: list[Mount] = Field(default_factory=list)
    engine: Engine
    gas: Annotated[GasParametric | GasTrace | GasOrders, Field(discriminator="model")] = Field(
        default_factory=GasParametric
    )
    sensors: list[Sensor]
    tacho: Tacho = Field(default_factory=Tacho)
    sampling: Sampling = Field(default_factory=Sampling)
    simulation: Simulation = Field(default_factory=Simulation)
    dsp: Dsp = Field(default_factory=Dsp)
    estimator: EstimatorSettings = Field(default_factory=EstimatorSettings)
    can: Can = Field(default_factory=Can)
    # bench channel name -> its name in recordings (a string) or a ChannelMap
    channels: dict[str, str | ChannelMap] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _channel_map(self) -> Bench:
        t = self.tacho
        known = [c for s in self.sensors for c in s.channels if c]
        known += [t.channel, t.rpm_channel, t.cam_channel, t.pressure_channel]
        for name in self.channels:
            if name not in known:
                raise ValueError(
                    f"channels: {name!r} is not a channel of this bench; its channels: "
                    + ", ".join(known)
                )
        return self

    @model_validator(mode="after")
    def _sensors(self) -> Bench:
        names = [s.name for s in self.sensors]
        if len(set(names)) != len(names):
            raise ValueError(f"sensors: names must be unique, got {names}")
        channels = [c for s in self.sensors for c in s.channels if c]
        dup = {c for c in channels if channels.count(c) > 1}
        if dup:
            raise ValueError(f"sensors: channel names used twice: {sorted(dup)}")
        # Two sensors (or all on one line) leave the rotation about their line unseen:
        # the estimator fits it per frame (estimator/partial.py) at the cost of wider
        # intervals. One position cannot see any rotation.
        positions = np.array([s.position_m for s in self.sensors])
        if len(positions) < 2 or np.linalg.matrix_rank(positions[1:] - positions[0], tol=1e-3) < 1:
            raise ValueError(
                f"sensors: need at least two sensors at distinct positions, got {len(positions)} "
                "(rigid-body rotation is unobservable otherwise; three non-collinear are best)"
            )
        return self


def parse_bench(data: dict[str, Any], where: str = "bench") -> Bench:
    """Validate a bench mapping; raise :class:`ConfigError` with a one-line message."""
    try:
        return Bench.model_validate(data)
    except ValidationError as err:
        raise ConfigError(format_validation_error(err, where, hidden=GAS_MODELS)) from None


def load_bench(path: str | Path) -> Bench:
    """Read and validate a bench TOML file."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise ConfigError(f"{path}: cannot read bench file ({err.strerror})") from None
    return loads_bench(decode_toml(raw, str(path)), str(path), base_dir=path.parent)


def decode_toml(raw: bytes, where: str) -> str:
    """The text of a TOML file: UTF-8 (TOML's only encoding), with or without the byte
    order mark some Windows editors write."""
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise ConfigError(
            f"{where}: not UTF-8 text (byte 0x{raw[err.start]:02x} at offset {err.start}); "
            "save the file as UTF-8"
        ) from None


def loads_bench(text: str, where: str = "bench", base_dir: Path | None = None) -> Bench:
    try:
        data = tomllib.loads(text.removeprefix("\ufeff"))
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{where}: not valid TOML ({err})") from None
    bench = parse_bench(data, where)
    if base_dir is not None:  # relative paths are relative to the bench file
        paths = bench_file_paths(bench)
        bench = with_bench_paths(
            bench, {k: p if Path(p).is_absolute() else str(base_dir / p) for k, p in paths.items()}
        )
    return bench


# The keys of a bench file that name other files (relative to the bench file).
DBC_KEY, GAS_FILE_KEY = "[can] dbc", "[gas] file"


def bench_file_paths(bench: Bench) -> dict[str, str]:
    """The files ``bench`` names, by key (``DBC_KEY``, ``GAS_FILE_KEY``)."""
    paths = {}
    if bench.can.dbc:
        paths[DBC_KEY] = bench.can.dbc
    if isinstance(bench.gas, GasTrace):
        paths[GAS_FILE_KEY] = bench.gas.file
    return paths


def with_bench_paths(bench: Bench, paths: dict[str, str | None]) -> Bench:
    """``bench`` with the file paths of ``paths`` (keys of :func:`bench_file_paths`)
    replaced; None drops a DBC (a pressure trace cannot be dropped)."""
    if DBC_KEY in paths:
        can = bench.can.model_copy(update={"dbc": paths[DBC_KEY]})
        bench = bench.model_copy(update={"can": can})
    if GAS_FILE_KEY in paths and isinstance(bench.gas, GasTrace):
        gas = bench.gas.model_copy(update={"file": paths[GAS_FILE_KEY]})
        bench = bench.model_copy(update={"gas": gas})
    return bench
