"""The bench model and its wiring from a bench file: channels, sweeps, as-built errors, commands."""

from __future__ import annotations

import json

import numpy as np
import pytest

from powertrain.gas import CylinderGeometry
from powertrain.half_orders import rpm_to_omega
from powertrain.model import BenchModel, ElasticMode
from powertrain.rigidbody import inertia_terms
from powertrain.sensors import rigid_channel_matrix
from ptinertia import config, config_powertrain
from ptinertia.cli import main
from ptinertia.config import ConfigError, load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_physics import build_model, build_simulated_model, gas_model, read_pressure_trace

I3 = EXAMPLES_DIR / "i3-bench.toml"
ORDERS = np.array([0.5, 1.0, 1.5, 2.0, 3.0])


@pytest.fixture(scope="module")
def bench():
    return load_bench(I3)


@pytest.fixture(scope="module")
def model(bench):
    return build_model(bench)


def simulation(bench, **kw):
    return bench.simulation.model_copy(update=kw)


def rigid_residual(model: BenchModel, acc: np.ndarray) -> np.ndarray:
    """Per (rpm, order): the part of the channel readings no rigid motion explains, relative."""
    d = rigid_channel_matrix(model.channel_positions, model.channel_directions, model.body.cog)
    flat = acc.reshape(-1, acc.shape[-1]).T
    coef, *_ = np.linalg.lstsq(d, flat, rcond=None)
    res = np.linalg.norm(flat - d @ coef, axis=0) / np.linalg.norm(flat, axis=0)
    return res.reshape(acc.shape[:-1])


def test_channels_follow_sensor_then_axis_order(model):
    assert model.channel_names == ("A_x", "A_y", "A_z", "B_x", "B_y", "B_z", "C_x", "C_y", "C_z")
    np.testing.assert_allclose(model.channel_positions[3], [0.02, -0.42, 0.25])
    # Sensor B is turned 90 deg about Z: its x reads bench +Y, its y bench -X.
    np.testing.assert_allclose(model.channel_directions[3:5], [[0, 1, 0], [-1, 0, 0]])


def test_sweep_equals_one_speed_at_a_time(model):
    rpm = np.array([900.0, 1500.0, 3333.0, 4500.0])
    acc = model.channel_amplitudes(rpm, ORDERS)
    assert acc.shape == (4, ORDERS.size, 9)
    for i, r in enumerate(rpm):
        q = model.response(r, ORDERS)
        for j, p in enumerate(model.channel_positions):
            point = model.mounted.point_acceleration(q, float(rpm_to_omega(r)), ORDERS, p)
            expected = point @ model.channel_directions[j]
            np.testing.assert_allclose(
                acc[i, :, j], expected, rtol=1e-9, atol=1e-12 * np.abs(acc).max()
            )
    np.testing.assert_allclose(model.channel_amplitudes(1500.0, ORDERS)[0], acc[1])


def test_nominal_channels_move_rigidly_and_excitation_is_about_the_cog(model):
    acc = model.channel_amplitudes(np.array([1500.0, 4000.0]), ORDERS)
    assert rigid_residual(model, acc).max() < 1e-12
    f, m = model.excitation(3000.0, ORDERS)
    f2, m2 = model.engine.excitation(3000.0, ORDERS, about=model.body.cog)
    np.testing.assert_allclose(
        np.hstack([f, m]), np.hstack([f2, m2]), atol=1e-12 * np.abs(m2).max()
    )


def test_gains_scale_each_channel(bench, model):
    gains = np.linspace(0.9, 1.1, 9)
    scaled = BenchModel(model.body, model.mounts, model.engine, model.sensors, gains=gains)
    np.testing.assert_allclose(
        scaled.channel_amplitudes(2000.0, ORDERS),
        model.channel_amplitudes(2000.0, ORDERS) * gains,
        rtol=1e-12,
    )


def test_elastic_mode_is_not_rigid_and_breaks_rigidity_near_its_frequency(model):
    mode = ElasticMode(frequency_hz=150.0, damping_ratio=0.02, participation=1.0, rigid_share=0.0)
    elastic = BenchModel(model.body, model.mounts, model.engine, model.sensors, elastic_mode=mode)
    d = rigid_channel_matrix(
        elastic.channel_positions, elastic.channel_directions, elastic.body.cog
    )
    np.testing.assert_allclose(d.T @ elastic.elastic_shape, 0, atol=1e-12)
    assert np.abs(elastic.elastic_shape).max() == pytest.approx(1.0)
    # 150 Hz: order 3 at 3000 rpm (roll moment only on an i3) and order 2 at 4500 rpm
    # (pitch-type moment only) both drive it; order 1 at 1500 rpm is 25 Hz, (25/150)^2 below.
    for rpm, order in ((3000.0, 3.0), (4500.0, 2.0)):
        assert rigid_residual(elastic, elastic.channel_amplitudes(rpm, [order]))[0, 0] > 0.5
    assert rigid_residual(elastic, elastic.channel_amplitudes(1500.0, [1.0]))[0, 0] < 0.05
    # The rigid part is untouched: what rigid motion explains equals the rigid model.
    rigid_only = model.channel_amplitudes(3000.0, [3.0])
    diff = elastic.channel_amplitudes(3000.0, [3.0]) - rigid_only
    np.testing.assert_allclose(d.T @ diff[0, 0], 0, atol=1e-9 * np.abs(diff).max())


def test_elastic_shape_keeps_the_asked_share_of_its_rigid_looking_part(model):
    def shape(share: float) -> np.ndarray:
        mode = ElasticMode(frequency_hz=150.0, rigid_share=share)
        m = BenchModel(model.body, model.mounts, model.engine, model.sensors, elastic_mode=mode)
        return m.elastic_shape

    d = rigid_channel_matrix(model.channel_positions, model.channel_directions, model.body.cog)

    def split(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        coef, *_ = np.linalg.lstsq(d, v, rcond=None)
        return v - d @ coef, d @ coef

    ortho0, rigid0 = split(shape(0.0))
    np.testing.assert_allclose(rigid0, 0, atol=1e-12)
    ortho_half, rigid_half = split(shape(0.5))
    ortho_full, rigid_full = split(shape(1.0))
    # same non-rigid direction; the rigid-looking part scales with the share
    scale_half = np.linalg.norm(ortho_half) / np.linalg.norm(ortho0)
    scale_full = np.linalg.norm(ortho_full) / np.linalg.norm(ortho0)
    np.testing.assert_allclose(ortho_half / scale_half, ortho0, atol=1e-12)
    np.testing.assert_allclose(rigid_half / scale_half, 0.5 * rigid_full / scale_full, atol=1e-12)
    assert np.linalg.norm(rigid_full) > 0.1 * np.linalg.norm(ortho_full)


def test_simulated_model_is_deterministic_and_json_serialisable(bench):
    sim = simulation(
        bench, seed=11, gain_error_pct=2.0, misalignment_deg=1.5, position_error_m=0.004
    )
    a, truth_a = build_simulated_model(bench, sim)
    b, truth_b = build_simulated_model(bench, sim)
    assert json.dumps(truth_a) == json.dumps(truth_b)
    np.testing.assert_array_equal(
        a.channel_amplitudes(2000.0, ORDERS), b.channel_amplitudes(2000.0, ORDERS)
    )
    other, _ = build_simulated_model(bench, simulation(bench, seed=12, gain_error_pct=2.0))
    assert not np.allclose(other.gains, a.gains)
    truth = json.loads(json.dumps(truth_a))
    assert truth["mass_kg"] == 110.0
    assert truth["inertia_kgm2"] == inertia_terms(bench.powertrain.inertia_kgm2.matrix())
    assert list(truth["gains"]) == list(a.channel_names)
    np.testing.assert_allclose(list(truth["gains"].values()), a.gains)


def test_sensor_errors_have_exactly_the_asked_size(bench):
    nominal = build_model(bench)
    sim = simulation(bench, misalignment_deg=2.0, position_error_m=0.005)
    built, truth = build_simulated_model(bench, sim)
    for s0, s1 in zip(nominal.sensors, built.sensors, strict=True):
        rel = s1.axes.T @ s0.axes  # the rotation taking nominal axes to the built ones
        angle = np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1)))
        assert angle == pytest.approx(2.0, rel=1e-9)
        assert np.linalg.norm(s1.position - s0.position) == pytest.approx(0.005, rel=1e-12)
        np.testing.assert_allclose(truth["sensors"][s0.name]["position_m"], s1.position)
    np.testing.assert_allclose(built.gains, 1.0)  # no gain error asked


def test_changing_one_error_does_not_reshuffle_the_others(bench):
    a, _ = build_simulated_model(
        bench, simulation(bench, gain_error_pct=1.0, position_error_m=0.002)
    )
    b, _ = build_simulated_model(
        bench, simulation(bench, gain_error_pct=3.0, position_error_m=0.002)
    )
    np.testing.assert_allclose(b.gains - 1, 3 * (a.gains - 1), rtol=1e-12)
    for sa, sb in zip(a.sensors, b.sensors, strict=True):
        np.testing.assert_array_equal(sa.position, sb.position)


def test_residual_unbalance_is_the_only_order_one_force_of_the_i3(bench):
    nominal = build_model(bench)
    rpm, mr, beta = 3000.0, 5e-4, 35.0
    sim = simulation(
        bench,
        residual_unbalance_kgm=mr,
        residual_unbalance_deg=beta,
        residual_unbalance_axial_m=0.02,
    )
    built, truth = build_simulated_model(bench, sim)
    f0, _ = nominal.excitation(rpm, [1.0])
    f1, _ = built.excitation(rpm, [1.0])
    w2 = float(rpm_to_omega(rpm)) ** 2
    assert np.abs(f0).max() < 1e-9 * mr * w2
    _, c, t = built.engine.frame
    # cos(phi - b) c + sin(phi - b) t  ->  e^{-i b} (c - i t)
    np.testing.assert_allclose(
        f1[0], mr * w2 * np.exp(-1j * np.radians(beta)) * (c - 1j * t), rtol=1e-9
    )
    assert truth["unbalance"] == {"mr_kgm": mr, "angle_deg": beta, "axial_m": 0.02}


def test_elastic_mode_from_the_simulation_table(bench):
    sim = simulation(bench, elastic_mode=config.ElasticMode(frequency_hz=180.0, damping_ratio=0.03))
    built, truth = build_simulated_model(bench, sim)
    assert built.elastic_mode == ElasticMode(180.0, 0.03, 1.0)
    assert truth["elastic_mode"]["frequency_hz"] == 180.0
    assert build_model(bench).elastic_mode is None


def test_pressure_channel(model):
    phi = np.linspace(0, 4 * np.pi, 7)
    geometry = CylinderGeometry(model.engine.bore, model.engine.stroke, model.engine.conrod_length)
    np.testing.assert_allclose(
        model.pressure(phi), model.engine.gas.pressure(geometry, phi), rtol=1e-6
    )


def write_trace(path, model, step_deg=0.5):
    geometry = CylinderGeometry(model.engine.bore, model.engine.stroke, model.engine.conrod_length)
    deg = np.arange(0, 720 + step_deg / 2, step_deg)
    bar = model.engine.gas.pressure(geometry, np.radians(deg)) / 1e5
    path.write_text(
        "crank_deg,pressure_bar\n"
        + "".join(f"{a:.3f},{p:.9f}\n" for a, p in zip(deg, bar, strict=True))
    )


def test_pressure_trace_gives_the_same_gas_torque(tmp_path, bench, model):
    trace = tmp_path / "p.csv"
    write_trace(trace, model)
    data = bench.model_dump()
    data["gas"] = {"model": "trace", "file": str(trace)}
    traced = build_model(config.parse_bench(data))
    np.testing.assert_allclose(
        traced.pressure(np.array([0.3, 2.0])), model.pressure(np.array([0.3, 2.0])), rtol=1e-4
    )
    t0 = model.engine.gas_torque_orders([0.0, 1.5, 3.0])
    t1 = traced.engine.gas_torque_orders([0.0, 1.5, 3.0])
    np.testing.assert_allclose(t1, t0, rtol=1e-3)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ("crank_deg,pressure_bar\n0,1.0\n1,abc\n", r"p\.csv: row 3: expected two numbers"),
        ("0,1.0\n2,1.0\n1,1.0\n", r"p\.csv: row 3: crank angle 1 deg does not increase"),
        ("0,1.0\n800,1.0\n", r"p\.csv: row 2: crank angle 800 deg outside 0\.\.720"),
        ("0,1.0\n1,-2\n", r"p\.csv: row 2: pressure -2 bar must be > 0"),
        ("0,1.0,3\n", r"p\.csv: row 1: expected two finite numbers"),
        ("0,1\n1,1\n", r"p\.csv: pressure trace needs at least 8 rows, got 2"),
    ],
)
def test_malformed_trace_is_a_one_line_config_error(tmp_path, body, message):
    path = tmp_path / "p.csv"
    path.write_text(body)
    with pytest.raises(ConfigError, match=message) as err:
        read_pressure_trace(path)
    assert "\n" not in str(err.value)


def test_missing_trace_names_the_file(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.csv: cannot read pressure trace"):
        gas_model(config_powertrain.GasTrace(model="trace", file=str(tmp_path / "nope.csv")))


def test_torque_table_gas_has_no_pressure(bench):
    data = bench.model_dump()
    data["gas"] = {
        "model": "orders",
        "orders": [{"order": 1.5, "torque_nm": 100.0, "phase_deg": 30.0}],
    }
    model = build_model(config.parse_bench(data))
    assert model.pressure(np.zeros(3)) is None
    np.testing.assert_allclose(
        model.engine.gas_torque_orders([1.5]), 100 * np.exp(1j * np.radians(30))
    )


# -- commands ----------------------------------------------------------------------------------


def test_excitation_command_json_matches_the_model(capsys, model):
    assert (
        main(["excitation", "--bench", str(I3), "--rpm", "3000", "--orders", "1,1.5,2", "--json"])
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    f, m = model.excitation(3000.0, [1.0, 1.5, 2.0])
    for i, entry in enumerate(out["orders"]):
        total = entry["total"]
        got = [total[k]["re"] + 1j * total[k]["im"] for k in ("Fx", "Fy", "Fz", "Mx", "My", "Mz")]
        np.testing.assert_allclose(got, np.hstack([f[i], m[i]]), atol=1e-9 * np.abs(m).max())
        gas_my = entry["gas"]["My"]
        assert gas_my["re"] + 1j * gas_my["im"] == pytest.approx(
            -model.engine.gas_torque_orders([entry["order"]])[0]
        )


def test_excitation_command_table(capsys):
    assert main(["excitation", "--bench", str(I3), "--rpm", "2000", "--orders", "1.5"]) == 0
    out = capsys.readouterr().out
    assert "2000 rpm" in out and "|My| N m" in out
    assert [line.split()[1] for line in out.splitlines()[-3:]] == ["gas", "inertia", "total"]


def test_excitation_command_refuses_bad_orders_in_one_line(capsys):
    assert main(["excitation", "--bench", str(I3), "--rpm", "2000", "--orders", "0.3"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "0.3" in err


def test_modes_command(capsys, model):
    assert main(["modes", "--bench", str(I3), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    np.testing.assert_allclose(
        [m["frequency_hz"] for m in out["modes"]], model.modes().frequency_hz
    )
    assert sorted(m["dominant"] for m in out["modes"]) == sorted(
        ["fore-aft", "lateral", "bounce", "pitch", "roll", "yaw"]
    )
    assert main(["modes", "--bench", str(I3), "--rpm", "3000"]) == 0
    text = capsys.readouterr().out
    assert (
        "3000 rpm" in text
        and len([ln for ln in text.splitlines() if ln[:4].strip().isdigit()]) == 6
    )
