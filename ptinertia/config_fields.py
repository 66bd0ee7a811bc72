"""Field types and checks shared by the bench file's tables (:mod:`ptinertia.config`).

Vectors and frames are in the bench frame; a frame's rows are its axes. A check
raises ValueError, which pydantic reports under the key it failed on.
"""

from __future__ import annotations

import math
from typing import Annotated

import numpy as np
from pydantic import Field

from acquisition.tables import TomlTable

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]  # (x, y, z)
Matrix3 = Annotated[list[Vec3], Field(min_length=3, max_length=3)]  # three rows
Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]

# the default axes of a mount or sensor: aligned with the bench frame
IDENTITY = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]

Section = TomlTable  # base of every bench-file table


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
