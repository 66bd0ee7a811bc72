"""Accelerometers on the block: where they are and which way each channel points."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from powertrain.errors import PhysicsError


@dataclass(frozen=True)
class Sensor:
    """A (up to) triaxial accelerometer.

    Parameters
    ----------
    name : label.
    position : (3,) m, bench frame.
    axes : (3, 3) rows = the sensor's x, y, z axes in the bench frame.
    channels : 1 to 3 channel names for the sensor's x, y, z; ``""`` for an axis not recorded.
    """

    name: str
    position: np.ndarray = field(repr=False)
    axes: np.ndarray = field(repr=False)
    channels: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        pos = np.array(self.position, dtype=float)
        axes = np.array(self.axes, dtype=float)
        if pos.shape != (3,) or axes.shape != (3, 3):
            raise PhysicsError(
                f"sensor {self.name}: position (3,) and axes (3, 3) expected, got {pos.shape}, {axes.shape}"
            )
        err = float(np.abs(axes @ axes.T - np.eye(3)).max())
        if err > 1e-6:
            raise PhysicsError(
                f"sensor {self.name}: axes rows must be orthonormal (|A A^T - 1| = {err:.3g})"
            )
        if not 1 <= len(self.channels) <= 3:
            raise PhysicsError(
                f"sensor {self.name}: 1 to 3 channels expected, got {len(self.channels)}"
            )
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "axes", axes)
        object.__setattr__(self, "channels", tuple(self.channels))

    def moved(self, offset: npt.ArrayLike) -> Sensor:
        """The same sensor displaced by ``offset`` (3,) m."""
        return Sensor(
            self.name, self.position + np.asarray(offset, dtype=float), self.axes, self.channels
        )

    def rotated(self, rotation: npt.ArrayLike) -> Sensor:
        """The same sensor with its axes turned by ``rotation`` (3, 3), bench frame."""
        return Sensor(
            self.name, self.position, self.axes @ np.asarray(rotation, dtype=float).T, self.channels
        )


def channel_geometry(sensors: Sequence[Sensor]) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    """Named channels in sensor order, then axis order, skipping empty names.

    Returns
    -------
    names : (n_ch,) channel names.
    positions : (n_ch, 3) m.
    directions : (n_ch, 3) unit vectors, bench frame.
    """
    names: list[str] = []
    positions: list[np.ndarray] = []
    directions: list[np.ndarray] = []
    for sensor in sensors:
        for axis, name in enumerate(sensor.channels):
            if name:
                names.append(name)
                positions.append(sensor.position)
                directions.append(sensor.axes[axis])
    if len(set(names)) != len(names):
        raise PhysicsError(f"channel names must be unique, got {names}")
    return tuple(names), np.array(positions).reshape(-1, 3), np.array(directions).reshape(-1, 3)


def rigid_channel_matrix(
    positions: npt.ArrayLike, directions: npt.ArrayLike, about: npt.ArrayLike
) -> np.ndarray:
    """(n_ch, 6) map from rigid motion ``[u_O; theta]`` about point O to channel readings.

    A channel along ``d`` at P reads ``d . (u_O + theta x OP) = [d, OP x d] . [u_O; theta]``;
    the same matrix maps ``[gamma_O; Omega']`` to accelerations (paper eq. 11).
    """
    p = np.asarray(positions, dtype=float)
    d = np.asarray(directions, dtype=float)
    return np.hstack([d, np.cross(p - np.asarray(about, dtype=float), d)])
