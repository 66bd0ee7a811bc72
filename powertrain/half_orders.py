"""Loads per half order: the FFT over one 720 deg cycle, and the split by speed scaling.

``x(phi) = Re{sum_h X_h exp(i h phi)}`` for every half order ``h``; index ``k`` of a
spectrum is order ``k / 2``. Inertia loads scale with ``omega^2``, so they are
decomposed once at unit speed (:class:`OrderExcitation` scales them back); the gas
part does not depend on speed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from powertrain.errors import PhysicsError


def rpm_to_omega(rpm: npt.ArrayLike) -> np.ndarray:
    """rad/s from rev/min."""
    return np.asarray(rpm, dtype=float) * (2.0 * np.pi / 60.0)


def half_order_spectrum(x: np.ndarray) -> np.ndarray:
    """Complex amplitudes per half order along axis 0: index ``k`` is order ``k / 2``."""
    n = x.shape[0]
    y = np.fft.rfft(x, axis=0) * (2.0 / n)
    y[0] *= 0.5
    return y


def half_order_index(orders: npt.ArrayLike, samples_per_cycle: int) -> np.ndarray:
    """Index ``2 h`` of each order ``h`` in a spectrum of ``samples_per_cycle`` points.

    Orders are multiples of 0.5 with ``2 h`` below a quarter of ``samples_per_cycle``.
    """
    h = np.atleast_1d(np.asarray(orders, dtype=float))
    k = np.rint(2 * h).astype(int)
    bad = (np.abs(2 * h - k) > 1e-9) | (k < 0) | (k >= samples_per_cycle // 4)
    if np.any(bad):
        raise PhysicsError(
            f"orders must be multiples of 0.5 in 0..{samples_per_cycle // 8}, got {h[bad].tolist()}"
        )
    return k


@dataclass(frozen=True)
class OrderExcitation:
    """Excitation per order split by how it scales with speed (gas: not at all with our
    pressure models; crank-train inertia: with omega^2). Each (n_orders, 3) complex."""

    gas_force: np.ndarray  # N
    gas_moment: np.ndarray  # N m
    unit_inertia_force: np.ndarray  # N / (rad/s)^2
    unit_inertia_moment: np.ndarray  # N m / (rad/s)^2

    def at(self, rpm: float) -> tuple[np.ndarray, np.ndarray]:
        """Force (N) and moment (N m) per order at ``rpm`` rev/min."""
        w2 = float(rpm_to_omega(rpm)) ** 2
        return (
            self.gas_force + w2 * self.unit_inertia_force,
            self.gas_moment + w2 * self.unit_inertia_moment,
        )

    def at_many(self, rpm: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`at` at each of the speeds ``rpm`` (n,): force and moment (n, n_orders, 3),
        each speed's the bits of its own call (omega^2 squared as a Python float, as there)."""
        w2 = np.array([w**2 for w in rpm_to_omega(rpm).tolist()])[:, None, None]
        return (
            self.gas_force + w2 * self.unit_inertia_force,
            self.gas_moment + w2 * self.unit_inertia_moment,
        )
