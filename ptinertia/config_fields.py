"""Field types and checks shared by the bench file's tables (:mod:`ptinertia.config`).

Vectors and frames are in the bench frame; a frame's rows are its axes. A check
raises ValueError, which pydantic reports under the key it failed on.
"""

from __future__ import annotations

import math
from typing import Annotated

import numpy as np
from pydantic import ConfigDict, Field

from acquisition.tables import TomlTable

# A bench coordinate, m (or an axis component): a powertrain fits in a few metres; a
# value kilometres away is a unit mistake, and squared in the inertia terms it would
# overflow the fit long after the file was read.
MAX_COORDINATE_M = 1000.0
Coordinate = Annotated[float, Field(ge=-MAX_COORDINATE_M, le=MAX_COORDINATE_M)]
Vec3 = Annotated[list[Coordinate], Field(min_length=3, max_length=3)]  # (x, y, z)
Matrix3 = Annotated[list[Vec3], Field(min_length=3, max_length=3)]  # three rows
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]
Seed = Annotated[int, Field(ge=0, lt=2**63)]  # numpy's generators take 0 <= seed

# Sample rates, Hz: the dsp and the simulator hold blocks of rate x block length per
# channel, so a rate typed in the wrong unit (1e9) exhausts memory before any error.
# Accelerometer DAQ inputs run at 200 kHz at most, counter-timer tacho inputs at 10s of MHz.
MAX_ACCEL_RATE_HZ = 1e6
MAX_TACHO_RATE_HZ = 1e8


def rate_at_most(value: float, limit_hz: float, what: str) -> float:
    """``value`` if it is at most ``limit_hz``; ValueError saying why otherwise."""
    if value > limit_hz:
        raise ValueError(
            f"{value:g} Hz is above the {limit_hz:g} Hz {what} this tool accepts "
            "(blocks grow with the rate and would exhaust memory; is the unit Hz?)"
        )
    return value


# the default axes of a mount or sensor: aligned with the bench frame
IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]


class Section(TomlTable):
    """Base of every bench-file table: numbers strict. TOML has real booleans, so
    ``true`` for a number is a mistake, not 1.0; ``nan`` and ``inf`` are valid TOML
    floats but no bench quantity, and they would fail much later, far from the key."""

    model_config = ConfigDict(strict=True, allow_inf_nan=False)


def orthonormal_rows(axes: list[list[float]], what: str) -> list[list[float]]:
    """``axes`` unchanged if its rows are a right-handed orthonormal frame, else ValueError."""
    a = np.asarray(axes, dtype=float)
    err = np.abs(a @ a.T - np.eye(3)).max()
    if err > 1e-3:
        raise ValueError(f"{what} rows must be orthonormal unit vectors (|A A^T - 1| = {err:.3g})")
    if np.linalg.det(a) < 0:
        raise ValueError(f"{what} must be a right-handed frame (determinant is -1)")
    return axes


def unit_vector(v: list[float], what: str) -> list[float]:
    """``v`` scaled to unit length; ValueError for a zero or non-finite vector."""
    n = float(np.linalg.norm(v))
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError(f"{what} must be a non-zero vector")
    return [x / n for x in v]
