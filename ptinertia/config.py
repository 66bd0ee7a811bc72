"""The bench description: a validated TOML file (see ``docs/bench-file.md``).

One schema serves simulation (``[powertrain]`` is the truth) and estimation
(``[powertrain]`` holds nominal or weighed values). Keys are SI or carry their
unit (``stroke_mm``); :mod:`acquisition.units` converts. Every error names the
key path and what was expected, on one line (:class:`ConfigError`).
"""

from __future__ import annotations

import math
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

from acquisition.tables import TomlTable, format_validation_error

# discriminator tags pydantic puts in error locations of the [gas] union
GAS_MODELS = ("parametric", "trace", "orders")

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Matrix3 = Annotated[list[Vec3], Field(min_length=3, max_length=3)]
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]

IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


class ConfigError(ValueError):
    """A bench file that cannot be used; the message is one line naming the key."""


Section = TomlTable  # base of every bench-file table


def _orthonormal_rows(axes: list[list[float]], what: str) -> list[list[float]]:
    a = np.asarray(axes, dtype=float)
    err = np.abs(a @ a.T - np.eye(3)).max()
    if err > 1e-3:
        raise ValueError(f"{what} rows must be orthonormal unit vectors (|A A^T - 1| = {err:.3g})")
    if np.linalg.det(a) < 0:
        raise ValueError(f"{what} must be a right-handed frame (determinant is -1)")
    return axes


def _unit(v: list[float], what: str) -> list[float]:
    n = float(np.linalg.norm(v))
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError(f"{what} must be a non-zero vector")
    return [x / n for x in v]


class Meta(Section):
    name: str = "bench"
    description: str = ""


class InertiaTerms(Section):
    """Inertia about the cog in the bench frame; products ``Ixy = integral(x y dm)``."""

    Ixx: Positive
    Iyy: Positive
    Izz: Positive
    Ixy: float = 0.0
    Ixz: float = 0.0
    Iyz: float = 0.0

    def matrix(self) -> np.ndarray:
        return np.array(
            [
                [self.Ixx, -self.Ixy, -self.Ixz],
                [-self.Ixy, self.Iyy, -self.Iyz],
                [-self.Ixz, -self.Iyz, self.Izz],
            ]
        )

    @model_validator(mode="after")
    def _physical(self) -> InertiaTerms:
        eig = np.linalg.eigvalsh(self.matrix())
        if eig[0] <= 0:
            raise ValueError(
                f"inertia tensor is not positive definite (principal moments {np.round(eig, 4)} kg m^2)"
            )
        a, b, c = eig
        if a + b < c * (1 - 1e-9):
            raise ValueError(
                f"principal moments {np.round(eig, 4)} kg m^2 violate the triangle "
                "inequality I1 + I2 >= I3: no real body has them"
            )
        return self


class Powertrain(Section):
    mass_kg: Positive
    cog_m: Vec3
    inertia_kgm2: InertiaTerms
    mass_known: bool = True


class Mount(Section):
    name: str
    position_m: Vec3
    axes: Matrix3 = Field(default_factory=lambda: [row[:] for row in IDENTITY])
    stiffness_n_per_m: Annotated[list[NonNegative], Field(min_length=3, max_length=3)]
    loss_factor: NonNegative = 0.0

    @field_validator("axes")
    @classmethod
    def _axes(cls, v: list[list[float]]) -> list[list[float]]:
        return _orthonormal_rows(v, "axes")


class Unbalance(Section):
    """A mass rotating with the crank: ``mr_kgm`` at ``angle_deg`` (measured like throw angles)."""

    mr_kgm: NonNegative
    angle_deg: float = 0.0
    axial_m: float = 0.0


class BalanceShaft(Section):
    order: Literal[1, 2]
    mr_kgm: NonNegative
    angle_deg: float = 0.0
    position_m: Vec3
    direction: Literal[1, -1] = 1


class Engine(Section):
    cylinders: Annotated[int, Field(ge=2, le=6)]
    bore_m: Positive
    stroke_m: Positive
    conrod_length_m: Positive
    conrod_mass_kg: Positive
    conrod_cog_from_big_end_m: Positive
    conrod_inertia_kgm2: NonNegative | None = None
    piston_mass_kg: Positive
    crank_axis: Vec3 = Field(default_factory=lambda: [0.0, 1.0, 0.0])
    cylinder_axis: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 1.0])
    tilt_deg: float = 0.0
    reference_point_m: Vec3
    cylinder_positions_m: list[float]
    throw_angles_deg: list[float]
    firing_order: list[int]
    crank_spin_inertia_kgm2: NonNegative = 0.0
    unbalances: list[Unbalance] = Field(default_factory=list)
    balance_shafts: list[BalanceShaft] = Field(default_factory=list)

    @field_validator("crank_axis", "cylinder_axis")
    @classmethod
    def _axis(cls, v: list[float]) -> list[float]:
        return _unit(v, "axis")

    @model_validator(mode="after")
    def _geometry(self) -> Engine:
        n = self.cylinders
        for key in ("cylinder_positions_m", "throw_angles_deg", "firing_order"):
            if len(getattr(self, key)) != n:
                raise ValueError(
                    f"{key}: expected {n} values (one per cylinder), got {len(getattr(self, key))}"
                )
        if sorted(self.firing_order) != list(range(1, n + 1)):
            raise ValueError(
                f"firing_order: expected a permutation of 1..{n}, got {self.firing_order}"
            )
        lam = self.stroke_m / 2 / self.conrod_length_m
        if lam >= 1:
            raise ValueError(
                f"stroke/2 / conrod_length = {lam:.3f}: lambda must be < 1 (con rod longer than the crank radius)"
            )
        if self.conrod_cog_from_big_end_m >= self.conrod_length_m:
            raise ValueError("conrod_cog_from_big_end_m: must be shorter than conrod_length_m")
        dot = float(np.dot(self.crank_axis, self.cylinder_axis))
        if abs(dot) > 1e-6:
            raise ValueError(
                f"cylinder_axis must be perpendicular to crank_axis (cos angle = {dot:.3g}); use tilt_deg to lean the bank"
            )
        # Even firing: cylinder firing_order[j] fires at 720 j / n deg; its throw must be there mod 360.
        for j, cyl in enumerate(self.firing_order):
            expected = (720.0 * j / n) % 360.0
            got = self.throw_angles_deg[cyl - 1] % 360.0
            if min(abs(got - expected), 360 - abs(got - expected)) > 1e-6:
                raise ValueError(
                    f"throw_angles_deg: cylinder {cyl} fires {720.0 * j / n:g} deg after cylinder "
                    f"{self.firing_order[0]}, so its throw must be at {expected:g} deg, got {got:g}"
                )
        return self


class GasParametric(Section):
    """Closed-cycle pressure from compression, Wiebe heat release, expansion."""

    model: Literal["parametric"] = "parametric"
    compression_ratio: Annotated[float, Field(gt=1)] = 10.5
    intake_pressure_pa: Positive = 0.5e5
    exhaust_pressure_pa: Positive = 1.05e5
    polytropic_exponent: Annotated[float, Field(gt=1, lt=1.7)] = 1.32
    heat_release_j: NonNegative = 150.0
    combustion_start_deg: float = -8.0
    combustion_duration_deg: Positive = 50.0
    wiebe_a: Positive = 5.0
    wiebe_m: NonNegative = 2.0


class GasTrace(Section):
    """Cylinder-1 pressure over 0..720 deg from firing TDC, CSV ``crank_deg,pressure_bar``."""

    model: Literal["trace"]
    file: str


class GasOrder(Section):
    order: Annotated[float, Field(gt=0)]
    torque_nm: NonNegative
    phase_deg: float = 0.0


class GasOrders(Section):
    """Roll-torque orders ``T(t) = Re{T_h exp(i h phi)}`` delivered to the crank."""

    model: Literal["orders"]
    orders: list[GasOrder]


class Sensor(Section):
    name: str
    position_m: Vec3
    axes: Matrix3 = Field(default_factory=lambda: [row[:] for row in IDENTITY])
    channels: Annotated[list[str], Field(min_length=1, max_length=3)]

    @field_validator("axes")
    @classmethod
    def _axes(cls, v: list[list[float]]) -> list[list[float]]:
        return _orthonormal_rows(v, "axes")


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

    @model_validator(mode="after")
    def _wheel(self) -> Tacho:
        if self.kind == "wheel" and self.missing >= self.teeth:
            raise ValueError(f"missing: a wheel of {self.teeth} teeth cannot miss {self.missing}")
        return self


class Sampling(Section):
    accel_rate_hz: Positive = 5120.0


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
    seed: int = 0
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
    max_relative_residual: Positive = 0.05
    max_rpm_change: Positive = 0.03
    min_mode_ratio: NonNegative = 1.25
    rpm_min: NonNegative = 0.0
    rpm_max: Positive = 1e6


class Can(Section):
    """CAN acquisition: the DBC that maps frames to channels, and the bus."""

    dbc: str | None = None
    interface: str = "virtual"
    channel: str = "ptinertia"
    bitrate: Annotated[int, Field(gt=0)] = 500_000
    data_bitrate: Annotated[int, Field(gt=0)] = 2_000_000
    fd: bool = True


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
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{path}: cannot read bench file ({err.strerror})") from None
    return loads_bench(text, str(path), base_dir=path.parent)


def loads_bench(text: str, where: str = "bench", base_dir: Path | None = None) -> Bench:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{where}: not valid TOML ({err})") from None
    bench = parse_bench(data, where)
    if base_dir is not None and bench.can.dbc and not Path(bench.can.dbc).is_absolute():
        bench = bench.model_copy(
            update={"can": bench.can.model_copy(update={"dbc": str(base_dir / bench.can.dbc)})}
        )
    if isinstance(bench.gas, GasTrace) and base_dir is not None:
        trace = Path(bench.gas.file)
        if not trace.is_absolute():
            bench = bench.model_copy(
                update={"gas": GasTrace(model="trace", file=str(base_dir / trace))}
            )
    return bench
