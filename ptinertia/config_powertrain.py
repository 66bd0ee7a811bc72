"""The bench file's tables that describe the powertrain: its body, mounts, engine, gas, sensors.

Part of the bench file (:class:`ptinertia.config.Bench`); :mod:`ptinertia.to_physics` turns
them into the physics model.
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from ptinertia.config_fields import (
    IDENTITY,
    Matrix3,
    NonNegative,
    Positive,
    Section,
    Vec3,
    orthonormal_rows,
    unit_vector,
)


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
        return orthonormal_rows(v, "axes")


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
        return unit_vector(v, "axis")

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
    # under the pistons: only p - p_crankcase loads them (it has orders of its own)
    crankcase_pressure_pa: Positive = 101325.0


class GasTrace(Section):
    """Cylinder-1 pressure over 0..720 deg from firing TDC, CSV ``crank_deg,pressure_bar``."""

    model: Literal["trace"]
    file: str
    crankcase_pressure_pa: Positive = 101325.0  # under the pistons (see GasParametric)


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
        return orthonormal_rows(v, "axes")
