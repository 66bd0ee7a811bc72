"""The pendulum / rolling-plate test file (TOML): what the lab measured, with its uncertainties.

Layout (see ``docs/classical-methods.md`` and ``examples/pendulum-test.toml``)::

    [meta]            name, description, method = "pendulum" | "rolling_plate"
    [uncertainty]     1-sigma defaults for every configuration and line
    [plate]           rolling plate only: its inertia, the body mass, optionally the cog
    [[lines]]         plumb lines for the cog: point_m, direction
    [[configurations]] axis, period_s, stiffness_nm_per_rad (+ per-row uncertainties,
                      plate_axis_point_m on a rolling plate)
    [truth]           optional, from a simulation: mass_kg, cog_m, inertia_kgm2

Keys carry their unit like the bench file (``period_ms``, ``point_mm``,
``axis_std_rad`` are accepted and converted); unknown keys are refused.
Errors are :class:`~acquisition.stream.SourceError`, one line naming the key.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, ValidationError, model_validator

from acquisition.stream import SourceError
from acquisition.tables import TomlTable, format_validation_error

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]


def _nonzero(v: list[float], what: str) -> list[float]:
    n = math.sqrt(sum(x * x for x in v))
    if not (math.isfinite(n) and n > 1e-12):
        raise ValueError(f"{what} must be a non-zero vector, got {v}")
    return v


class Meta(TomlTable):
    name: str = "pendulum test"
    description: str = ""
    method: Literal["pendulum", "rolling_plate"] = "pendulum"


class Uncertainty(TomlTable):
    """1-sigma defaults; a configuration or line may override its own.

    ``stiffness_pct`` is independent per configuration; ``stiffness_calibration_pct``
    is one error shared by all (the same rig, calibrated once).
    """

    period_pct: NonNegative = 0.0
    stiffness_pct: NonNegative = 0.0
    stiffness_calibration_pct: NonNegative = 0.0
    axis_std_deg: NonNegative = 0.0
    line_position_std_m: NonNegative = 0.0
    line_angle_std_deg: NonNegative = 0.0
    plate_point_std_m: NonNegative = 0.0


class Plate(TomlTable):
    """The rolling plate (eq. 8): its inertia about its pivot and the body mass ``M``."""

    inertia_kgm2: NonNegative
    inertia_std_kgm2: NonNegative = 0.0
    body_mass_kg: Positive
    body_mass_std_kg: NonNegative = 0.0
    cog_m: Vec3 | None = None
    cog_std_m: NonNegative = 0.0


class Line(TomlTable):
    """A plumb line through the suspension point, in body (bench) coordinates."""

    point_m: Vec3
    direction: Vec3
    position_std_m: NonNegative | None = None
    angle_std_deg: NonNegative | None = None

    @model_validator(mode="after")
    def _direction(self) -> Line:
        _nonzero(self.direction, "direction")
        return self


class Configuration(TomlTable):
    """One swing: axis through the cog, torsional period, suspension stiffness."""

    name: str = ""
    axis: Vec3
    period_s: Positive
    stiffness_nm_per_rad: Positive
    period_std_s: NonNegative | None = None
    stiffness_std_nm_per_rad: NonNegative | None = None
    axis_std_deg: NonNegative | None = None
    plate_axis_point_m: Vec3 | None = None
    plate_point_std_m: NonNegative | None = None

    @model_validator(mode="after")
    def _axis(self) -> Configuration:
        _nonzero(self.axis, "axis")
        return self


class TruthTerms(TomlTable):
    Ixx: float
    Iyy: float
    Izz: float
    Ixy: float = 0.0
    Ixz: float = 0.0
    Iyz: float = 0.0


class Truth(TomlTable):
    mass_kg: Positive | None = None
    cog_m: Vec3 | None = None
    inertia_kgm2: TruthTerms | None = None


class PendulumTestFile(TomlTable):
    meta: Meta = Field(default_factory=Meta)
    uncertainty: Uncertainty = Field(default_factory=Uncertainty)
    plate: Plate | None = None
    lines: list[Line] = Field(default_factory=list)
    configurations: list[Configuration]
    truth: Truth | None = None

    @model_validator(mode="after")
    def _plate(self) -> PendulumTestFile:
        if self.meta.method == "rolling_plate":
            if self.plate is None:
                raise ValueError("plate: a rolling_plate test needs a [plate] table")
            missing = [
                c.name or str(i + 1)
                for i, c in enumerate(self.configurations)
                if c.plate_axis_point_m is None
            ]
            if missing:
                raise ValueError(
                    f"configurations {missing}: plate_axis_point_m (a point of the pivot axis) "
                    "is required on a rolling plate"
                )
            if self.plate.cog_m is None and len(self.lines) < 2:
                raise ValueError(
                    f"plate: the M d(G, Delta')^2 term needs the cog: give plate.cog_m or "
                    f"at least 2 [[lines]] (got {len(self.lines)})"
                )
        return self


def parse_pendulum_test(data: dict[str, Any], where: str = "pendulum test") -> PendulumTestFile:
    """Validate a mapping; :class:`SourceError` with a one-line message."""
    try:
        return PendulumTestFile.model_validate(data)
    except ValidationError as err:
        raise SourceError(format_validation_error(err, where)) from None


def load_pendulum_test(path: str | Path) -> PendulumTestFile:
    """Read and validate a pendulum test TOML file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise SourceError(f"{path}: cannot read pendulum test ({err.strerror})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SourceError(f"{path}: not valid TOML ({err})") from None
    return parse_pendulum_test(data, str(path))


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def dumps_pendulum_test(test: PendulumTestFile, header: str = "") -> str:
    """TOML text of a test (floats written with full precision: it reads back exactly)."""
    data = test.model_dump(exclude_none=True)
    lines = [f"# {h}" if h else "#" for h in header.splitlines()] if header else []
    for table in ("meta", "uncertainty", "plate"):
        if table in data:
            lines += ["", f"[{table}]"] + [
                f"{k} = {_toml_value(v)}" for k, v in data[table].items()
            ]
    for array in ("lines", "configurations"):
        for row in data.get(array, []):
            lines += ["", f"[[{array}]]"] + [f"{k} = {_toml_value(v)}" for k, v in row.items()]
    if "truth" in data:
        lines += ["", "[truth]"] + [f"{k} = {_toml_value(v)}" for k, v in data["truth"].items()]
    return "\n".join(lines) + "\n"
