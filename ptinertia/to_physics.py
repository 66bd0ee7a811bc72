"""From a bench file to the physics: the nominal model and the as-built (simulated) one.

:func:`build_model` is what the estimator assumes: the bench file's values.
:func:`build_simulated_model` is the bench the simulator measures: the same
powertrain with the imperfections of ``[simulation]`` drawn from its seed
(sensor gains, misalignment, position errors), a residual static unbalance and
an optional elastic mode, plus a JSON-serialisable ``truth`` to score against.

Random draws are made in a fixed order and always all of them (gains, then
misalignment axes, then position-error directions), so changing one
imperfection's size never reshuffles the others.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from powertrain.balancing import BalanceShaft, Unbalance
from powertrain.engine import Engine
from powertrain.gas import GasModel, OrdersGas, ParametricGas, TraceGas
from powertrain.model import BenchModel, ElasticMode
from powertrain.mounted import Mount
from powertrain.rigidbody import RigidBody, inertia_terms, rotation_matrix
from powertrain.sensors import Sensor
from ptinertia import config, config_powertrain
from ptinertia.config import ConfigError

DEG = math.pi / 180.0


def read_pressure_trace(path: str | Path) -> TraceGas:
    """Read a cylinder-1 pressure trace, CSV ``crank_deg,pressure_bar``.

    Blank lines and lines starting with ``#`` are skipped; a first line that is
    not numeric is a header. Angles from firing TDC, increasing, within 0..720.

    Raises
    ------
    ConfigError
        One line naming the file and the row (1-based line number).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise ConfigError(f"{path}: cannot read pressure trace ({err.strerror})") from None
    angles: list[float] = []
    pressures: list[float] = []
    seen_data = False
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        try:
            values = [float(f) for f in fields]
        except ValueError:
            if not seen_data and len(fields) == 2:
                seen_data = True  # a header
                continue
            raise ConfigError(
                f"{path}: row {number}: expected two numbers 'crank_deg,pressure_bar', got {line!r}"
            ) from None
        seen_data = True
        if len(values) != 2 or not all(math.isfinite(v) for v in values):
            raise ConfigError(
                f"{path}: row {number}: expected two finite numbers 'crank_deg,pressure_bar', got {line!r}"
            )
        angle, bar = values
        if not 0.0 <= angle <= 720.0:
            raise ConfigError(f"{path}: row {number}: crank angle {angle:g} deg outside 0..720")
        if angles and angle <= angles[-1]:
            raise ConfigError(
                f"{path}: row {number}: crank angle {angle:g} deg does not increase (previous {angles[-1]:g})"
            )
        if bar <= 0:
            raise ConfigError(f"{path}: row {number}: pressure {bar:g} bar must be > 0 (absolute)")
        angles.append(angle)
        pressures.append(bar)
    if len(angles) < 8:
        raise ConfigError(f"{path}: pressure trace needs at least 8 rows, got {len(angles)}")
    return TraceGas(np.array(angles) * DEG, np.array(pressures) * 1e5)


def gas_model(
    gas: config_powertrain.GasParametric | config_powertrain.GasTrace | config_powertrain.GasOrders,
) -> GasModel:
    """The physics gas model of a ``[gas]`` table (reads the trace file)."""
    if isinstance(gas, config_powertrain.GasParametric):
        return ParametricGas(
            compression_ratio=gas.compression_ratio,
            intake_pressure=gas.intake_pressure_pa,
            exhaust_pressure=gas.exhaust_pressure_pa,
            polytropic_exponent=gas.polytropic_exponent,
            heat_release=gas.heat_release_j,
            combustion_start=gas.combustion_start_deg * DEG,
            combustion_duration=gas.combustion_duration_deg * DEG,
            wiebe_a=gas.wiebe_a,
            wiebe_m=gas.wiebe_m,
        )
    if isinstance(gas, config_powertrain.GasTrace):
        return read_pressure_trace(gas.file)
    return OrdersGas(
        tuple(o.order for o in gas.orders),
        tuple(
            o.torque_nm * complex(math.cos(o.phase_deg * DEG), math.sin(o.phase_deg * DEG))
            for o in gas.orders
        ),
    )


def crankcase_pa(
    gas: config_powertrain.GasParametric | config_powertrain.GasTrace | config_powertrain.GasOrders,
) -> float:
    """Pa under the pistons: ``[gas] crankcase_pressure_pa`` (1 atm for a torque-order
    model, whose torque already holds it)."""
    return float(getattr(gas, "crankcase_pressure_pa", 101325.0))


def build_engine(
    engine: config_powertrain.Engine,
    gas: GasModel | None,
    extra_unbalances: tuple[Unbalance, ...] = (),
    crankcase_pressure: float = 101325.0,
) -> Engine:
    """The physics :class:`Engine` of an ``[engine]`` table, SI and rad
    (``crankcase_pressure``: Pa under the pistons, ``[gas] crankcase_pressure_pa``)."""
    return Engine(
        crankcase_pressure=crankcase_pressure,
        cylinders=engine.cylinders,
        bore=engine.bore_m,
        stroke=engine.stroke_m,
        conrod_length=engine.conrod_length_m,
        conrod_mass=engine.conrod_mass_kg,
        conrod_cog_from_big_end=engine.conrod_cog_from_big_end_m,
        piston_mass=engine.piston_mass_kg,
        reference_point=np.array(engine.reference_point_m),
        cylinder_positions=np.array(engine.cylinder_positions_m),
        throw_angles=np.array(engine.throw_angles_deg) * DEG,
        firing_order=tuple(engine.firing_order),
        gas=gas,
        conrod_inertia=engine.conrod_inertia_kgm2,
        crank_axis=np.array(engine.crank_axis),
        cylinder_axis=np.array(engine.cylinder_axis),
        tilt=engine.tilt_deg * DEG,
        crank_spin_inertia=engine.crank_spin_inertia_kgm2,
        unbalances=tuple(
            Unbalance(u.mr_kgm, u.angle_deg * DEG, u.axial_m) for u in engine.unbalances
        )
        + extra_unbalances,
        balance_shafts=tuple(
            BalanceShaft(
                b.order,
                b.mr_kgm,
                b.angle_deg * DEG,
                (b.position_m[0], b.position_m[1], b.position_m[2]),
                b.direction,
            )
            for b in engine.balance_shafts
        ),
    )


def _body(bench: config.Bench) -> RigidBody:
    p = bench.powertrain
    return RigidBody(p.mass_kg, np.array(p.cog_m), p.inertia_kgm2.matrix())


def _mounts(bench: config.Bench) -> tuple[Mount, ...]:
    return tuple(
        Mount(
            m.name,
            np.array(m.position_m),
            np.array(m.axes),
            np.array(m.stiffness_n_per_m),
            m.loss_factor,
        )
        for m in bench.mounts
    )


def _sensors(bench: config.Bench) -> tuple[Sensor, ...]:
    return tuple(
        Sensor(s.name, np.array(s.position_m), np.array(s.axes), tuple(s.channels))
        for s in bench.sensors
    )


def build_model(
    bench: config.Bench, body: RigidBody | None = None, extra_unbalances: tuple[Unbalance, ...] = ()
) -> BenchModel:
    """The nominal model: the bench file as the estimator assumes it (no errors, rigid).

    ``body`` replaces the bench file's powertrain and ``extra_unbalances`` join the
    engine's: the re-simulation check puts an estimate there
    (:func:`ptinertia.resim.resim_model`).
    """
    engine = build_engine(
        bench.engine, gas_model(bench.gas), extra_unbalances, crankcase_pa(bench.gas)
    )
    body = _body(bench) if body is None else body
    return BenchModel(body, _mounts(bench), engine, _sensors(bench))


def _true_gas(
    bench: config.Bench, sim: config.Simulation
) -> config_powertrain.GasParametric | config_powertrain.GasTrace | config_powertrain.GasOrders:
    """The gas the simulated engine burns: ``[gas]``, its heat release off by the given share."""
    if not sim.heat_release_error_pct:
        return bench.gas
    if not isinstance(bench.gas, config_powertrain.GasParametric):
        raise ConfigError(
            "[simulation] heat_release_error_pct: needs [gas] model = 'parametric', "
            f"got {bench.gas.model!r}"
        )
    scale = 1.0 + sim.heat_release_error_pct / 100.0
    return bench.gas.model_copy(update={"heat_release_j": bench.gas.heat_release_j * scale})


def _true_engine(bench: config.Bench, sim: config.Simulation) -> config_powertrain.Engine:
    """The ``[engine]`` the simulated bench runs: its spin inertia and moving masses off
    by ``[simulation]``'s relative errors."""
    e = bench.engine
    scale = {
        "crank_spin_inertia_kgm2": sim.spin_inertia_error_pct,
        "piston_mass_kg": sim.piston_mass_error_pct,
        "conrod_mass_kg": sim.conrod_mass_error_pct,
    }
    update = {k: getattr(e, k) * (1 + pct / 100.0) for k, pct in scale.items() if pct}
    return e.model_copy(update=update) if update else e


def _true_mounts(bench: config.Bench, sim: config.Simulation) -> tuple[Mount, ...]:
    """The mounts of the simulated bench: their stiffness off by ``[simulation]
    mount_stiffness_error_pct`` (one value for all, or one per mount)."""
    mounts = _mounts(bench)
    pct = sim.mount_stiffness_error_pct
    errors = [pct] * len(mounts) if isinstance(pct, int | float) else list(pct)
    if len(errors) != len(mounts):
        raise ConfigError(
            f"[simulation] mount_stiffness_error_pct: expected one value or {len(mounts)} "
            f"(one per mount), got {len(errors)}"
        )
    if any(e <= -100 for e in errors):
        raise ConfigError(
            f"[simulation] mount_stiffness_error_pct: must be above -100, got {errors}"
        )
    return tuple(
        Mount(m.name, m.position, m.axes, m.stiffness * (1 + e / 100.0), m.loss_factor)
        for m, e in zip(mounts, errors, strict=True)
    )


def build_simulated_model(
    bench: config.Bench, sim: config.Simulation | None = None
) -> tuple[BenchModel, dict[str, Any]]:
    """The as-built bench the simulator measures, and its truth.

    Parameters
    ----------
    bench : the bench file.
    sim : imperfections; default ``bench.simulation``.

    Returns
    -------
    model : with gains, moved and turned sensors, the residual unbalance and the elastic mode.
    truth : JSON-serialisable dict (SI, degrees): ``mass_kg``, ``cog_m``,
        ``inertia_kgm2`` (terms), ``unbalance`` (``mr_kgm``, ``angle_deg``,
        ``axial_m``), ``gains`` per channel, ``sensors`` (true position and axes,
        errors), ``elastic_mode``, ``crank_spin_inertia_kgm2``, ``seed``.
    """
    sim = bench.simulation if sim is None else sim
    rng = np.random.default_rng(sim.seed)
    nominal = _sensors(bench)
    n_channels = sum(1 for s in nominal for c in s.channels if c)
    gain_draw = rng.standard_normal(n_channels)
    axis_draw = rng.standard_normal((len(nominal), 3))
    offset_draw = rng.standard_normal((len(nominal), 3))

    gains = 1.0 + sim.gain_error_pct / 100.0 * gain_draw
    sensors = []
    sensor_truth: dict[str, Any] = {}
    for sensor, axis, offset in zip(nominal, axis_draw, offset_draw, strict=True):
        axis = axis / np.linalg.norm(axis)
        offset = sim.position_error_m * offset / np.linalg.norm(offset)
        built = sensor.rotated(rotation_matrix(axis, sim.misalignment_deg * DEG)).moved(offset)
        sensors.append(built)
        sensor_truth[sensor.name] = {
            "position_m": built.position.tolist(),
            "axes": built.axes.tolist(),
            "position_error_m": offset.tolist(),
            "misalignment_deg": sim.misalignment_deg,
            "misalignment_axis": axis.tolist(),
        }
    residual = Unbalance(
        sim.residual_unbalance_kgm, sim.residual_unbalance_deg * DEG, sim.residual_unbalance_axial_m
    )
    extra = (residual,) if sim.residual_unbalance_kgm > 0 else ()
    engine = build_engine(
        _true_engine(bench, sim),
        gas_model(_true_gas(bench, sim)),
        extra,
        crankcase_pa(bench.gas) + sim.crankcase_pressure_error_pa,
    )
    elastic = (
        None
        if sim.elastic_mode is None
        else ElasticMode(
            sim.elastic_mode.frequency_hz,
            sim.elastic_mode.damping_ratio,
            sim.elastic_mode.participation,
            sim.elastic_mode.rigid_share,
        )
    )
    body = _body(bench)
    mounts = _true_mounts(bench, sim)
    model = BenchModel(body, mounts, engine, sensors, elastic_mode=elastic, gains=gains)
    truth: dict[str, Any] = {
        "mass_kg": body.mass,
        "cog_m": body.cog.tolist(),
        "inertia_kgm2": inertia_terms(body.inertia),
        "unbalance": {
            "mr_kgm": sim.residual_unbalance_kgm,
            "angle_deg": sim.residual_unbalance_deg,
            "axial_m": sim.residual_unbalance_axial_m,
        },
        "gains": dict(zip(model.channel_names, gains.tolist(), strict=True)),
        "sensors": sensor_truth,
        "elastic_mode": None if sim.elastic_mode is None else sim.elastic_mode.model_dump(),
        "crank_spin_inertia_kgm2": engine.crank_spin_inertia,
        "heat_release_error_pct": sim.heat_release_error_pct,
        "piston_mass_kg": engine.piston_mass,
        "conrod_mass_kg": engine.conrod_mass,
        "crankcase_pressure_pa": engine.crankcase_pressure,
        "mount_stiffness_n_per_m": {m.name: m.stiffness.tolist() for m in mounts},
        "seed": sim.seed,
    }
    return model, truth
