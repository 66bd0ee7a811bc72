"""Small 3-vector helpers, fast for the tiny arrays of one frame."""

from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix: ``skew(a) @ b == a x b`` (works for complex vectors)."""
    x, y, z = v
    return np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a x b`` along the last axis, broadcasting (np.cross costs ~20 us per call here)."""
    a = np.asarray(a)
    b = np.asarray(b)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    # three copies into one array: np.stack's checks and reshapes cost more than that
    out = np.empty((*c0.shape, 3), dtype=c0.dtype)
    out[..., 0], out[..., 1], out[..., 2] = c0, c1, c2
    return out
