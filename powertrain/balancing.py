"""Balancing masses on the crank and on balance shafts, and the loads they put on the block.

Both are rotating unbalances: at unit crank speed (1 rad/s) a mass ``mr`` turning at
``order`` times crank speed pulls with ``mr order^2`` along the direction it points in
(centrifugal, ``-m a``). Directions are in the engine's frame ``(s, c, t)``
(:attr:`powertrain.engine.Engine.frame`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Unbalance:
    """A point mass on the crank: ``mr`` (kg m) at ``angle`` (rad, measured like
    throw angles: it points along ``c`` when ``phi = angle``), ``axial`` m
    along ``s`` from the reference point."""

    mr: float
    angle: float = 0.0
    axial: float = 0.0


@dataclass(frozen=True)
class BalanceShaft:
    """A rotating unbalance ``mr`` (kg m) at ``order`` times crank speed.

    ``direction`` +1 turns with the crank, -1 against it. The mass points
    along ``c`` when ``order * phi = angle`` (rad); in general along
    ``cos(d (h phi - angle)) c + sin(d (h phi - angle)) t``. Its axis is parallel
    to ``s`` through ``position`` (3,) m. Its spin inertia is not modelled.
    """

    order: int
    mr: float
    angle: float = 0.0
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    direction: int = 1


def add_balancing_loads(
    force: np.ndarray,
    moment: np.ndarray,
    unbalances: Sequence[Unbalance],
    balance_shafts: Sequence[BalanceShaft],
    phi: np.ndarray,
    frame: tuple[np.ndarray, np.ndarray, np.ndarray],
    reference_point: np.ndarray,
    about: np.ndarray,
) -> None:
    """Add the force and moment of the balancing masses at unit crank speed (1 rad/s).

    In place, mass by mass onto the crank train's loads, so the sums round as they
    always have.

    Parameters
    ----------
    force : (n, 3) N per (rad/s)^2, added to.
    moment : (n, 3) N m per (rad/s)^2 about Q, added to.
    phi : (n,) rad, crank angle.
    frame : ``(s, c, t)`` unit (3,) vectors.
    reference_point : (3,) m, where the crank's unbalances are measured from along ``s``.
    about : (3,) m, the point Q moments are taken about.
    """
    s, c, t = frame
    for u in unbalances:
        e = np.outer(np.cos(phi - u.angle), c) + np.outer(np.sin(phi - u.angle), t)
        f = u.mr * e  # centrifugal: -m a = m r omega^2 e
        force += f
        moment += np.cross(reference_point + u.axial * s - about, f)
    for b in balance_shafts:
        ang = b.direction * (b.order * phi - b.angle)
        e = np.outer(np.cos(ang), c) + np.outer(np.sin(ang), t)
        f = b.mr * b.order**2 * e
        force += f
        moment += np.cross(np.asarray(b.position, dtype=float) - about, f)
