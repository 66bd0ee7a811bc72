"""The bench model: engine loads -> mounted rigid body -> accelerometer channels.

One :class:`BenchModel` serves both the estimator (nominal values: what it
assumes) and the simulator (the as-built bench, with sensor errors, a residual
unbalance and, optionally, one elastic mode that breaks rigidity).

Elastic mode
------------
A single modal coordinate ``eta`` (m) with frequency ``f_e`` and damping ratio
``zeta``: the first bending-torsion mode of the block and gearbox along the
crank axis. Its shape at the channels, ``phi`` (n_ch,), comes from the pattern
``xi^2 (c + t/2) + xi s x GP / L`` (bending in both planes, plus a twist growing
along the axis; ``xi`` is a sensor's axial distance from the cog over their
rms axial distance ``L``). The part of the pattern a rigid motion explains is
kept at ``rigid_share`` of its size (a real bending shape seen by three
sensors looks partly like a rigid motion, and that part biases any rigid fit;
0 keeps only the part no rigid motion can explain); scaled to a largest
entry of 1. It is driven by the moments that bend and twist the
block, about ``b = (t + s) / sqrt(2)`` (pitch-type and roll)::

    eta'' + 2 zeta w_e eta' + w_e^2 eta = p L (M_G . b) / I_b,   I_b = b^T I b

``p`` is the participation. Above ``f_e`` it adds ``p`` times the rigid
angular acceleration about ``b`` seen at ``L``; at ``f_e`` ``p / (2 zeta)`` times (25x at
2 %): near its frequency the channels clearly stop moving as a rigid body.
Below, it fades as ``(f / f_e)^2``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from powertrain.engine import Engine
from powertrain.errors import PhysicsError
from powertrain.gas import PressureCycle
from powertrain.half_orders import rpm_to_omega
from powertrain.mounted import Modes, Mount, MountedPowertrain
from powertrain.rigidbody import RigidBody
from powertrain.sensors import Sensor, channel_geometry, rigid_channel_matrix


@dataclass(frozen=True)
class ElasticMode:
    """First elastic mode of the powertrain (see module docstring).

    Parameters
    ----------
    frequency_hz : Hz.
    damping_ratio : zeta.
    participation : p, 1 means the mode's modal inertia equals the body's about ``b``.
    rigid_share : share of the pattern's rigid-looking part kept in the shape (0..1).
    """

    frequency_hz: float
    damping_ratio: float = 0.02
    participation: float = 1.0
    rigid_share: float = 0.5

    def __post_init__(self) -> None:
        if not 0.0 <= self.rigid_share <= 1.0:
            raise PhysicsError(f"elastic mode rigid_share must be in 0..1, got {self.rigid_share}")
        if self.frequency_hz <= 0 or self.damping_ratio <= 0 or self.participation < 0:
            raise PhysicsError(
                f"elastic mode needs frequency > 0 ({self.frequency_hz} Hz), damping ratio > 0 "
                f"({self.damping_ratio}) and participation >= 0 ({self.participation})"
            )


class BenchModel:
    """Powertrain on its mounts, driven by its engine, seen by its sensors.

    Parameters
    ----------
    body : mass, cog, inertia of the whole powertrain.
    mounts : elastic mounts.
    engine : the excitation.
    sensors : accelerometers; channels in sensor order then axis order.
    spin_inertia : kg m^2 of the crank train for the gyroscopic term; None takes
        ``engine.crank_spin_inertia``.
    elastic_mode : optional, see module docstring.
    gains : (n_ch,) channel gain (1 = exact), or None.
    """

    def __init__(
        self,
        body: RigidBody,
        mounts: Sequence[Mount],
        engine: Engine,
        sensors: Sequence[Sensor],
        spin_inertia: float | None = None,
        elastic_mode: ElasticMode | None = None,
        gains: np.ndarray | None = None,
    ) -> None:
        self.body = body
        self.mounts = tuple(mounts)
        self.engine = engine
        self.sensors = tuple(sensors)
        spin = engine.crank_spin_inertia if spin_inertia is None else float(spin_inertia)
        self.mounted = MountedPowertrain(body, self.mounts, spin, engine.crank_axis)
        names, positions, directions = channel_geometry(self.sensors)
        self._names = names
        self._positions = positions
        self._directions = directions
        self.gains = np.ones(len(names)) if gains is None else np.asarray(gains, dtype=float)
        if self.gains.shape != (len(names),):
            raise PhysicsError(f"gains must have shape ({len(names)},), got {self.gains.shape}")
        # Channel displacement from q about the cog: [d, GP x d] . q.
        self._channels_from_q = rigid_channel_matrix(positions, directions, body.cog)
        self.elastic_mode = elastic_mode
        self.elastic_shape = None if elastic_mode is None else self._elastic_shape()
        self._load_cache: dict[tuple[float, ...], tuple[np.ndarray, np.ndarray]] = {}

    # -- geometry --------------------------------------------------------------------------------

    @property
    def channel_names(self) -> tuple[str, ...]:
        return self._names

    @property
    def channel_positions(self) -> np.ndarray:
        """(n_ch, 3) m."""
        return self._positions

    @property
    def channel_directions(self) -> np.ndarray:
        """(n_ch, 3) unit vectors, bench frame."""
        return self._directions

    def _elastic_scale(self) -> tuple[float, np.ndarray]:
        """``L`` (m) and the unit drive axis ``b`` of the elastic mode."""
        s, _, t = self.engine.frame
        axial = (self._positions - self.body.cog) @ s
        return float(np.sqrt(np.mean(axial**2))), (t + s) / np.sqrt(2.0)

    def _elastic_shape(self) -> np.ndarray:
        length, _ = self._elastic_scale()
        s, c, t = self.engine.frame
        if length == 0:
            raise PhysicsError("elastic mode: the sensors span no length along the crank axis")
        arm = self._positions - self.body.cog
        xi = (arm @ s) / length
        bend = xi**2 * (self._directions @ (c + 0.5 * t))
        twist = xi * np.einsum("ij,ij->i", self._directions, np.cross(s, arm)) / length
        pattern = bend + twist
        rigid = self._channels_from_q
        # Remove what any rigid motion explains: least-squares residual of the pattern.
        coef, *_ = np.linalg.lstsq(rigid, pattern, rcond=None)
        shape = pattern - rigid @ coef
        size = float(np.abs(shape).max())
        shape = (
            shape + self.elastic_mode.rigid_share * (rigid @ coef) if self.elastic_mode else shape
        )
        if size < 1e-6 * max(float(np.abs(pattern).max()), 1e-300):
            raise PhysicsError(
                f"elastic mode: {len(self._names)} channels leave no motion that is not rigid "
                "(need more than 6 independent channels)"
            )
        return shape / float(np.abs(shape).max())

    # -- loads and response ------------------------------------------------------------------

    def _unit_loads(self, orders: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(n_o, 6) load at 1 rad/s from inertia, and (n_o, 6) gas load, about the cog."""
        key = tuple(float(h) for h in np.atleast_1d(orders))
        if key not in self._load_cache:
            h = np.asarray(key)
            f1, m1 = self.engine.unit_inertia_orders(h, about=self.body.cog)
            fg, mg = self.engine.gas_excitation(h)
            self._load_cache[key] = (np.hstack([f1, m1]), np.hstack([fg, mg]))
        return self._load_cache[key]

    def excitation(self, rpm: float, orders: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Force (n_o, 3) complex N and moment about the cog (n_o, 3) complex N m."""
        inertia, gas = self._unit_loads(orders)
        load = float(rpm_to_omega(rpm)) ** 2 * inertia + gas
        return load[:, :3], load[:, 3:]

    def response(self, rpm: float, orders: npt.ArrayLike) -> np.ndarray:
        """(n_o, 6) complex ``[u_G (m); theta (rad)]`` per order at one speed."""
        f, m = self.excitation(rpm, orders)
        return self.mounted.response(
            float(rpm_to_omega(rpm)), np.atleast_1d(orders), np.hstack([f, m])
        )

    def channel_amplitudes(self, rpm: npt.ArrayLike, orders: npt.ArrayLike) -> np.ndarray:
        """Complex acceleration per channel, order and speed.

        Parameters
        ----------
        rpm : (n_rpm,) rev/min (a scalar counts as one).
        orders : (n_o,) multiples of 0.5.

        Returns
        -------
        (n_rpm, n_o, n_ch) complex m/s^2, gains applied: channel reading
        ``Re{A exp(i h phi)}``.
        """
        h = np.atleast_1d(np.asarray(orders, dtype=float))
        omega = rpm_to_omega(np.atleast_1d(np.asarray(rpm, dtype=float)))
        inertia, gas = self._unit_loads(h)
        q = self.mounted.response_sweep(omega, h, inertia, gas)  # (n_rpm, n_o, 6)
        w2 = (omega[:, None] * h) ** 2  # (n_rpm, n_o)
        acc = -w2[..., None] * (q @ self._channels_from_q.T)
        if self.elastic_mode is not None and self.elastic_shape is not None:
            load = (omega**2)[:, None, None] * inertia + gas
            acc += self._elastic_acceleration(omega, h, load)
        return acc * self.gains

    def _elastic_acceleration(
        self, omega: np.ndarray, h: np.ndarray, load: np.ndarray
    ) -> np.ndarray:
        mode = self.elastic_mode
        assert mode is not None and self.elastic_shape is not None
        length, b = self._elastic_scale()
        i_b = float(b @ self.body.inertia @ b)
        we = 2 * np.pi * mode.frequency_hz
        w = omega[:, None] * h
        drive = mode.participation * length * (load[..., 3:] @ b) / i_b
        eta = drive / (we**2 - w**2 + 2j * mode.damping_ratio * we * w)
        return -(w**2 * eta)[..., None] * self.elastic_shape

    def modes(self, rpm: float | None = None) -> Modes:
        """Rigid-body modes: undamped at zero speed, or complex at ``rpm`` (gyroscopic + loss)."""
        return self.mounted.modes(None if rpm is None else float(rpm_to_omega(rpm)))

    @property
    def pressure_cycle(self) -> PressureCycle | None:
        """Cylinder 1's pressure over the cycle (its spline's pieces: a compiled evaluation
        reads them), None without a pressure model."""
        return self.engine.pressure_cycle

    def pressure(self, phi: npt.ArrayLike) -> np.ndarray | None:
        """Cylinder-1 pressure (Pa) at crank angles ``phi`` (rad), None without a pressure model."""
        return self.engine.cylinder_pressure(phi)
