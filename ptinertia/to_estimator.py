"""From a bench file to the estimator's view of the bench (nominal values only).

The estimator gets the sensor geometry, the engine's known excitation, the
mounts, the crank-train spin and the nominal (or weighed) mass, cog and
inertia. It never sees the simulated truth.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from acquisition.stream import StreamLayout
from estimator.setup import (
    Corrections,
    EstimatorSetup,
    Gates,
    MountStiffness,
    Tolerances,
)
from powertrain.engine import Engine
from powertrain.half_orders import OrderExcitation
from powertrain.model import BenchModel
from powertrain.pressure_torque import PressureTorqueMap, pressure_torque_map
from ptinertia import config
from ptinertia.to_model_inputs import model_inputs
from ptinertia.to_physics import build_model

#: Pa per unit of a cylinder-pressure channel.
PRESSURE_UNITS = {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": 1e5, "mbar": 100.0, "psi": 6894.757}


@dataclass(frozen=True)
class PressureGas:
    """The gas torque comes from this cylinder-1 pressure channel (``pa_per_unit`` Pa per
    channel unit), tracked at every half order up to ``max_order``."""

    channel: str
    pa_per_unit: float
    max_order: float


def pressure_gas(bench: config.Bench, layout: StreamLayout) -> PressureGas | None:
    """Where the gas torque comes from: ``[estimator] gas_torque`` against what the source has.

    ``auto`` takes the ``[tacho] pressure_channel`` when the source records it in a
    pressure unit; ``pressure`` insists on it; ``model`` (or ``auto`` without the
    channel) uses ``[gas]``.
    """
    mode = bench.estimator.gas_torque
    name = bench.tacho.pressure_channel
    if mode == "model":
        return None
    unit = next((c.unit for g in layout.groups for c in g.channels if c.name == name), None)
    if mode == "auto" and unit not in PRESSURE_UNITS:
        return None
    where = "[estimator] gas_torque = 'pressure'"
    if unit is None:
        raise config.ConfigError(
            f"{where}: the source has no channel {name!r} ([tacho] pressure_channel); "
            "it has: " + ", ".join(layout.channel_names)
        )
    if unit not in PRESSURE_UNITS:
        raise config.ConfigError(
            f"{where}: channel {name!r} is in {unit!r}, expected one of "
            + ", ".join(PRESSURE_UNITS)
        )
    return PressureGas(name, PRESSURE_UNITS[unit], bench.estimator.pressure_max_order)


def gas_moment_from_pressure(
    engine: Engine, gas: PressureGas, orders: tuple[float, ...] = ()
) -> GasFromPressure:
    """The estimator's gas moment (``-T_gas s``, N m) from a frame's pressure spectrum.

    The map for ``orders`` (those the dsp will track) is built now, not at the first
    frame: a live run must not stall its first estimate on it (~20 ms).
    """
    out = GasFromPressure(engine, gas)
    if orders:
        out.map_for(orders)
    return out


class GasFromPressure:
    """The gas moment of :func:`gas_moment_from_pressure`: a ``GasMomentFn``, with
    ``many`` for the frames of a run at once (``estimator.setup``)."""

    def __init__(self, engine: Engine, gas: PressureGas) -> None:
        self.engine = engine
        self.gas = gas
        self.axis = np.asarray(engine.crank_axis, float)
        self.maps: dict[tuple[float, ...], PressureTorqueMap] = {}

    def map_for(self, orders: npt.ArrayLike) -> PressureTorqueMap:
        key = tuple(np.asarray(orders, float).tolist())
        if key not in self.maps:
            self.maps[key] = pressure_torque_map(self.engine, key, self.gas.max_order)
        return self.maps[key]

    def __call__(self, orders: np.ndarray, spectrum: np.ndarray) -> np.ndarray:
        torque = self.map_for(orders).torque(self.gas.pa_per_unit * np.asarray(spectrum))
        return -np.outer(torque, self.axis)

    def many(self, orders: np.ndarray, spectra: np.ndarray) -> np.ndarray:
        """(n, n_orders, 3) from (n, n_half) spectra: each frame's the bits of its own call
        (the map applied as (n, 1, n_half) stacks: one matrix-vector product per frame,
        as a frame alone gets it, where a (n, n_half) product may take another kernel)."""
        p = self.gas.pa_per_unit * np.asarray(spectra)[:, None, :]
        torque = self.map_for(orders).torque(p)[:, 0]
        return -(torque[:, :, None] * self.axis)  # np.outer's product, per frame


class ExcitationAt:
    """The known excitation per order at a crank speed: an ``ExcitationFn``, with
    ``many`` for the frames of a run at once (``estimator.setup``)."""

    def __init__(self, of_orders: Callable[[npt.ArrayLike], OrderExcitation]) -> None:
        self.of_orders = of_orders  # the speed-independent parts of an order set

    def __call__(self, rpm: float, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.of_orders(orders).at(rpm)

    def many(self, rpm: list[float], orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Force and moment (n, n_orders, 3) at the crank speeds ``rpm`` (n,), each frame's
        the bits of its own call (:meth:`OrderExcitation.at_many`)."""
        return self.of_orders(orders).at_many(rpm)


def mount_stiffness(model: BenchModel) -> tuple[MountStiffness, ...]:
    """Bench-frame complex stiffness ``A^T diag(k (1 + i eta)) A`` of each mount."""
    return tuple(
        MountStiffness(
            name=m.name,
            position=np.asarray(m.position, float),
            stiffness=m.axes.T @ np.diag(m.stiffness * (1 + 1j * m.loss_factor)) @ m.axes,
        )
        for m in model.mounts
    )


def estimator_setup(
    bench: config.Bench,
    corrections: Corrections | None = None,
    tolerances: Tolerances | None = None,
    gates: Gates | None = None,
    model: BenchModel | None = None,
    pressure: PressureGas | None = None,
) -> EstimatorSetup:
    """The :class:`EstimatorSetup` of a bench file.

    Corrections default to on when their data exist: the suspension term needs
    mounts, the gyroscopic term a crank-train spin inertia. With ``pressure`` the
    gas torque comes from that channel, frame by frame, instead of ``[gas]``.
    """
    model = build_model(bench) if model is None else model
    engine = model.engine
    s, c, _ = engine.frame
    reference = np.asarray(bench.powertrain.cog_m, float)
    has_mounts = bool(model.mounts)
    sensor_of_channel = np.array(
        [i for i, sensor in enumerate(bench.sensors) for name in sensor.channels if name]
    )
    corr = corrections or Corrections()
    corr = Corrections(
        suspension=corr.suspension and has_mounts,
        gyroscopic=corr.gyroscopic and engine.crank_spin_inertia > 0,
        unbalance=corr.unbalance,
        unbalance_location=corr.unbalance and corr.unbalance_location,
        crank_offset=corr.crank_offset,
        mount_scale=corr.mount_scale and corr.suspension and has_mounts,
        self_calibration=corr.self_calibration,
        channel_weights=corr.channel_weights,
    )
    if corr.self_calibration and len(sensor_of_channel) <= 6:
        raise config.ConfigError(
            f"[estimator] self_calibration: needs more than six accelerometer channels, the "
            f"bench has {len(sensor_of_channel)} (it calibrates from the readings no rigid "
            "motion explains)"
        )
    if corr.mount_scale and not bench.powertrain.mass_known:
        raise config.ConfigError(
            "[estimator] mount_scale: needs [powertrain] mass_known = true "
            "(estimated mass and mount scales would multiply)"
        )

    # A stream tracks the same orders frame after frame: keep their speed-independent parts.
    by_orders: dict[tuple[float, ...], OrderExcitation] = {}

    def excitation_of(orders: npt.ArrayLike) -> OrderExcitation:
        key = tuple(np.asarray(orders, float).tolist())
        if key not in by_orders:
            if pressure is None:
                full = engine.order_excitation(key, about=reference)
            else:  # the gas comes with each frame: the model's pressure cycle is not run
                force, moment = engine.unit_inertia_orders(key, about=reference)
                gas_free = np.zeros_like(moment)
                full = OrderExcitation(gas_free, gas_free, force, moment)
            by_orders[key] = full
        return by_orders[key]

    # Built for the bench's orders now, not at the first frame (tens of ms: a live
    # run's first estimate would be late), as the pressure map below.
    excitation_of(bench.dsp.orders)

    mode_max = float(np.max(model.modes().frequency_hz)) if has_mounts else None
    mounts = mount_stiffness(model) if corr.suspension else ()
    declared = model_inputs(
        bench, engine, reference, corr, pressure is not None, tuple(m.name for m in mounts)
    )
    return EstimatorSetup(
        channels=model.channel_names,
        sensor_of_channel=sensor_of_channel,
        positions=model.channel_positions,
        directions=model.channel_directions,
        reference_point=reference,
        unbalance_point=np.asarray(engine.reference_point, float),
        crank_axis=np.asarray(s, float),
        cylinder_axis=np.asarray(c, float),
        spin_inertia=float(engine.crank_spin_inertia),
        excitation=ExcitationAt(excitation_of),
        mounts=mounts,
        mass_nominal=float(bench.powertrain.mass_kg),
        mass_known=bench.powertrain.mass_known,
        cog_nominal=reference,
        inertia_nominal=bench.powertrain.inertia_kgm2.matrix(),
        mode_max_hz=mode_max,
        corrections=corr,
        tolerances=tolerances or Tolerances(),
        gates=gates or Gates(),
        gas_moment=None
        if pressure is None
        else gas_moment_from_pressure(engine, pressure, tuple(bench.dsp.orders)),
        model_inputs=declared,
    )
