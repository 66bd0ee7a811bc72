"""From a bench file to the estimator's view of the bench (nominal values only).

The estimator gets the sensor geometry, the engine's known excitation, the
mounts, the crank-train spin and the nominal (or weighed) mass, cog and
inertia. It never sees the simulated truth.
"""

from __future__ import annotations

import numpy as np

from estimator.setup import Corrections, EstimatorSetup, Gates, MountStiffness, Tolerances
from powertrain.engine import OrderExcitation
from powertrain.model import BenchModel
from ptinertia import config
from ptinertia.bench import build_model


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
) -> EstimatorSetup:
    """The :class:`EstimatorSetup` of a bench file.

    Corrections default to on when their data exist: the suspension term needs
    mounts, the gyroscopic term a crank-train spin inertia.
    """
    model = build_model(bench) if model is None else model
    engine = model.engine
    s, c, _ = engine.frame
    reference = np.asarray(bench.powertrain.cog_m, float)
    has_mounts = bool(model.mounts)
    corr = corrections or Corrections()
    corr = Corrections(
        suspension=corr.suspension and has_mounts,
        gyroscopic=corr.gyroscopic and engine.crank_spin_inertia > 0,
        unbalance=corr.unbalance,
        crank_offset=corr.crank_offset,
        mount_scale=corr.mount_scale and corr.suspension and has_mounts,
    )
    if corr.mount_scale and not bench.powertrain.mass_known:
        raise config.ConfigError(
            "[estimator] mount_scale: needs [powertrain] mass_known = true "
            "(estimated mass and mount scales would multiply)"
        )
    sensor_of_channel = np.array(
        [i for i, sensor in enumerate(bench.sensors) for name in sensor.channels if name]
    )

    # A stream tracks the same orders frame after frame: keep their speed-independent parts.
    by_orders: dict[tuple[float, ...], OrderExcitation] = {}

    def excitation(rpm: float, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key = tuple(np.asarray(orders, float).tolist())
        if key not in by_orders:
            by_orders[key] = engine.order_excitation(key, about=reference)
        return by_orders[key].at(rpm)

    mode_max = float(np.max(model.modes().frequency_hz)) if has_mounts else None
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
        excitation=excitation,
        mounts=mount_stiffness(model) if corr.suspension else (),
        mass_nominal=float(bench.powertrain.mass_kg),
        mass_known=bench.powertrain.mass_known,
        cog_nominal=reference,
        inertia_nominal=bench.powertrain.inertia_kgm2.matrix(),
        mode_max_hz=mode_max,
        corrections=corr,
        tolerances=tolerances or Tolerances(),
        gates=gates or Gates(),
    )
