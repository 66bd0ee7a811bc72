"""The engine's gas loads: torque per order against the indicated work, the first law in
the closed phase, a torque table's roll moment (split from test_engine_excitation.py)."""

from __future__ import annotations

import numpy as np
import pytest
from support.engines import (
    BORE,
    DEG,
    GAS,
    ROD,
    STROKE,
    inline3,
    inline4,
)

from powertrain.gas import CylinderGeometry, OrdersGas, ParametricGas

# -- gas ---------------------------------------------------------------------------------------


def loop_work(gas: ParametricGas) -> float:
    """Indicated work of one cylinder, J: the loop integral of p dV over 720 deg, independently."""
    theta = np.linspace(0, 4 * np.pi, 200_001)
    geometry = CylinderGeometry(BORE, STROKE, ROD)
    p = gas.pressure(geometry, theta)
    area = np.pi * BORE**2 / 4
    r = STROKE / 2
    volume = area * (r + ROD - (r * np.cos(theta) + np.sqrt(ROD**2 - (r * np.sin(theta)) ** 2)))
    return float(np.trapezoid(p, volume))


def test_inline3_gas_torque_orders_and_indicated_work():
    e = inline3(gas=GAS)
    orders = np.arange(0, 25) / 2
    t = e.gas_torque_orders(orders)
    multiple = np.isclose(np.mod(orders, 1.5), 0) | np.isclose(np.mod(orders, 1.5), 1.5)
    assert np.abs(t[~multiple]).max() < 1e-10 * abs(t[3])
    assert abs(t[3]) > 10.0  # H1.5 is the strong one
    work = loop_work(GAS)
    assert work > 0
    assert t[0].real * 4 * np.pi == pytest.approx(3 * work, rel=1e-6)


def test_inline4_gas_torque_has_multiples_of_order_two():
    e = inline4(gas=GAS)
    orders = np.arange(1, 17) / 2
    t = e.gas_torque_orders(orders)
    even = np.isclose(np.mod(orders, 2), 0)
    assert np.abs(t[~even]).max() < 1e-10 * abs(t[3])
    np.testing.assert_allclose(e.firing_angles / DEG, [0, 540, 180, 360])


def test_first_law_holds_in_the_closed_phase():
    # dp = ((g-1)/V) dQ - g p dV/V between IVC and EVO, by central differences.
    gas = GAS
    geometry = CylinderGeometry(BORE, STROKE, ROD)
    theta = np.linspace(-130, 120, 2001) * DEG
    h = 1e-4
    p = gas.pressure(geometry, theta)
    dp = (gas.pressure(geometry, theta + h) - gas.pressure(geometry, theta - h)) / (2 * h)
    v, dv = geometry.volume(theta, gas.compression_ratio)
    y = np.maximum((theta - gas.combustion_start) / gas.combustion_duration, 0)
    dq = (
        gas.heat_release
        * gas.wiebe_a
        * 3
        * y**2
        * np.exp(-gas.wiebe_a * y**3)
        / gas.combustion_duration
    )
    g = gas.polytropic_exponent
    rhs = (g - 1) / v * dq - g * p * dv / v
    np.testing.assert_allclose(dp, rhs, atol=2e-6 * np.abs(rhs).max())
    # Gas exchange: exhaust pressure mid exhaust stroke, intake pressure mid intake stroke.
    assert gas.pressure(geometry, np.array([270 * DEG]))[0] == pytest.approx(gas.exhaust_pressure)
    assert gas.pressure(geometry, np.array([450 * DEG]))[0] == pytest.approx(gas.intake_pressure)


def test_torque_table_gas_gives_a_roll_moment_and_no_pressure():
    gas = OrdersGas((1.5, 3.0), (120.0 * np.exp(0.3j), 40.0))
    e = inline3(gas=gas)
    assert e.cylinder_pressure(np.zeros(2)) is None
    np.testing.assert_allclose(e.gas_torque_orders([1, 1.5, 3]), [0, 120 * np.exp(0.3j), 40])
    parts = e.excitation_parts(2000.0, [1.5], about=np.array([1.0, 2.0, 3.0]))
    f, m = parts["gas"]
    np.testing.assert_allclose(f, 0)
    np.testing.assert_allclose(m[0], [0, -120 * np.exp(0.3j), 0])
