"""Pendulum axis sets: how well six or more swing axes determine the inertia tensor.

Each swing about a unit axis ``u = (u, v, w)`` through the cog gives one linear
equation in the six terms (:mod:`estimator.classical.pendulum`, eq. 7), with
the row ``[u^2, v^2, w^2, -2uv, -2uw, -2vw]``. Conditioning is measured in the
Frobenius-orthonormal basis of symmetric tensors (row ``[u^2, v^2, w^2, sqrt2 uv,
sqrt2 uw, sqrt2 vw]``), where it does not change when the whole axis set is
turned: the best six axes (through opposite vertices of an icosahedron) reach
``sqrt(5/2) = 1.58``, the lab set X, Y, Z plus the three face diagonals 3.2. A
degenerate set is refused with the pattern that makes it so.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from powertrain.errors import PhysicsError

SQRT2 = math.sqrt(2.0)
#: above this condition number the axis set is accepted with a warning
CONDITION_WARN = 10.0
#: above this it is refused: period errors would be amplified a thousandfold
CONDITION_REFUSE = 1e3
BEST_CONDITION = math.sqrt(2.5)


class PendulumError(PhysicsError):
    """Pendulum data that cannot determine the tensor or the cog; the message says why."""


def unit_axes(axes: npt.ArrayLike) -> np.ndarray:
    """(n, 3) unit directions (eq. 4) from any non-zero (n, 3) vectors."""
    a = np.atleast_2d(np.asarray(axes, dtype=float))
    if a.ndim != 2 or a.shape[1] != 3:
        raise PendulumError(f"axes must have shape (n, 3), got {a.shape}")
    norm = np.linalg.norm(a, axis=1)
    bad = np.flatnonzero(~(norm > 1e-12) | ~np.isfinite(norm))
    if bad.size:
        raise PendulumError(
            f"axis {int(bad[0]) + 1} is not a non-zero vector: {a[bad[0]].tolist()}"
        )
    return a / norm[:, None]


def quadratic_rows(axes: npt.ArrayLike) -> np.ndarray:
    """(n, 6) rows of eq. 7: ``rows @ [Ixx, Iyy, Izz, Ixy, Ixz, Iyz] == u^T I u``."""
    u, v, w = unit_axes(axes).T
    return np.stack([u * u, v * v, w * w, -2 * u * v, -2 * u * w, -2 * v * w], axis=1)


def _orthonormal_rows(axes: np.ndarray) -> np.ndarray:
    """Rows in the Frobenius-orthonormal basis of symmetric tensors (rotation invariant)."""
    u, v, w = unit_axes(axes).T
    return np.stack([u * u, v * v, w * w, SQRT2 * u * v, SQRT2 * u * w, SQRT2 * v * w], axis=1)


def axis_set_condition(axes: npt.ArrayLike) -> float:
    """Condition number of an axis set (inf when it cannot determine the tensor).

    1.58 is the best possible for six axes; see the module docstring.
    """
    a = _orthonormal_rows(np.asarray(axes, dtype=float))
    if a.shape[0] < 6:
        return math.inf
    s = np.linalg.svd(a, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else math.inf


def _shown(v: np.ndarray) -> list[float]:
    """Rounded for a message, without the "-0.0" of a tiny negative."""
    return (np.round(v, 3) + 0.0).tolist()


def _degeneracy_reason(axes: np.ndarray) -> str:
    """Why the axes do not determine the tensor: the plane, planes or cone they lie on."""
    # One plane, the common slip, is told apart directly by the scatter of the axes.
    eig, vec = np.linalg.eigh(axes.T @ axes)
    n = vec[:, 0] * np.sign(vec[np.argmax(np.abs(vec[:, 0])), 0])
    tilt = math.degrees(math.asin(min(1.0, float(np.max(np.abs(axes @ n))))))
    if tilt < 1.0:
        where = "in one plane" if tilt < 1e-6 else f"within {tilt:.2g} deg of one plane"
        return f"all {len(axes)} axes lie {where} (normal {_shown(n)})"
    a = _orthonormal_rows(axes)
    _, sv, vt = np.linalg.svd(a, full_matrices=True)
    sv = np.concatenate([sv, np.zeros(6 - len(sv))])
    missing = int(np.sum(sv < 1e-9 * sv[0]))
    if missing > 1:
        return (
            f"the {len(axes)} axes leave {missing} combinations of the six terms unmeasured "
            "(they lie on several common cones)"
        )
    q = vt[-1]
    # u^T Q u = 0 for every axis u: the axes lie on the cone of Q.
    big_q = np.array(
        [
            [q[0], q[3] / SQRT2, q[4] / SQRT2],
            [q[3] / SQRT2, q[1], q[5] / SQRT2],
            [q[4] / SQRT2, q[5] / SQRT2, q[2]],
        ]
    )
    eig = np.linalg.eigvalsh(big_q)
    significant = np.abs(eig) > 0.05 * np.abs(eig).max()
    if int(significant.sum()) == 2 and eig[significant].prod() < 0:
        return f"the {len(axes)} axes lie in two planes"
    return (
        f"the {len(axes)} axes lie on one cone (for example all at the same angle to one direction)"
    )


def check_axis_set(axes: npt.ArrayLike) -> float:
    """The condition number of ``axes``; :class:`PendulumError` with the reason if degenerate.

    Raises
    ------
    PendulumError
        Fewer than 6 axes, or axes that leave a combination of the six terms
        unmeasured (all in one plane, in two planes, on one cone), or a
        condition number above ``CONDITION_REFUSE``.
    """
    a = unit_axes(axes)
    if len(a) < 6:
        raise PendulumError(f"need at least 6 configurations for the 6 inertia terms, got {len(a)}")
    # u and -u are the same swing axis: count the distinct ones first, it is the usual slip.
    same = np.abs(a @ a.T) > 1 - 1e-9
    distinct = len({int(np.argmax(row)) for row in same})
    if distinct < 6:
        raise PendulumError(
            f"only {distinct} distinct axes among the {len(a)} configurations (u and -u are the "
            "same axis): need at least 6 for the 6 inertia terms"
        )
    cond = axis_set_condition(a)
    if not cond <= CONDITION_REFUSE:
        shown = "inf" if not math.isfinite(cond) else f"{cond:.3g}"
        raise PendulumError(
            f"axis set cannot determine the tensor: {_degeneracy_reason(a)}; "
            f"condition number {shown} (best possible {BEST_CONDITION:.2f}, refused above "
            f"{CONDITION_REFUSE:g}): turn at least one axis out of that pattern"
        )
    return cond
