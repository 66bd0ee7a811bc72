"""``[gas] crankcase_pressure_pa`` reaches the gas torque (issue 20, item 6).

Reference: the closed form of a constant pressure under the pistons of an
inline 4 (throws 0, 180, 180, 0 deg). Only ``p - p_cc`` loads a piston, whose
pin moves by ``x'(theta) = -r sin(theta) (1 + lam cos(theta) / sqrt(1 - lam^2
sin^2 theta))`` per radian along the cylinder axis, so by virtual work the
torque changes by ``dp_cc A sum_k x'(phi - throw_k)``: the first terms cancel
over the throws, the second add, ``-4 dp_cc A r lam sin(phi) cos(phi) / sqrt(1
- lam^2 sin^2 phi)``, a pure order-2 torque to first order in lam.
"""

from __future__ import annotations

import numpy as np
import pytest

from powertrain.gas import CYCLE, PressureCycle
from ptinertia.config import ConfigError, load_bench, loads_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_physics import build_model, build_simulated_model

I4 = EXAMPLES_DIR / "i4-bench.toml"


def _with_crankcase(pa: float | None):
    bench = load_bench(I4)
    if pa is None:
        return bench
    return bench.model_copy(
        update={"gas": bench.gas.model_copy(update={"crankcase_pressure_pa": pa})}
    )


def test_default_is_one_atmosphere() -> None:
    assert build_model(_with_crankcase(None)).engine.crankcase_pressure == 101325.0


def test_the_key_moves_the_gas_torque_by_the_closed_form() -> None:
    at_atm = build_model(_with_crankcase(None)).engine
    at_1e5 = build_model(_with_crankcase(1.0e5)).engine
    # the simulator's engine takes the same key
    assert build_simulated_model(_with_crankcase(1.0e5))[0].engine.crankcase_pressure == 1.0e5
    assert at_1e5.crankcase_pressure == 1.0e5
    phi = np.linspace(0.0, 4 * np.pi, 721)
    bore, r, rod = 0.078, 0.0836 / 2, 0.136
    lam = r / rod
    area = np.pi * bore**2 / 4
    s, c = np.sin(phi), np.cos(phi)
    expected = (1.0e5 - 101325.0) * -4 * area * r * lam * s * c / np.sqrt(1 - lam**2 * s**2)
    got = at_1e5.gas_torque(phi) - at_atm.gas_torque(phi)
    np.testing.assert_allclose(got, expected, atol=1e-9 * np.max(np.abs(expected)))
    # per order (T(phi) = Re{T_h exp(i h phi)}): the closed form's order 2, no order 1
    grid = np.linspace(0.0, 4 * np.pi, 4096, endpoint=False)
    sg, cg = np.sin(grid), np.cos(grid)
    closed = (1.0e5 - 101325.0) * -4 * area * r * lam * sg * cg / np.sqrt(1 - lam**2 * sg**2)
    want2 = 2 * np.mean(closed * np.exp(-2j * grid))
    h = at_1e5.gas_torque_orders([1.0, 2.0]) - at_atm.gas_torque_orders([1.0, 2.0])
    assert abs(h[1] - want2) < 1e-3 * abs(want2)
    assert abs(h[0]) < 1e-9 * abs(want2)


def test_a_bad_crankcase_pressure_is_a_config_error() -> None:
    text = I4.read_text().replace(
        "heat_release_j = 220.0", "heat_release_j = 220.0\ncrankcase_pressure_pa = -1"
    )
    with pytest.raises(ConfigError, match="crankcase_pressure_pa"):
        loads_bench(text, base_dir=I4.parent)


def test_engines_differing_in_crankcase_pressure_share_one_pressure_cycle() -> None:
    # the cycle is p(phi) of the gas and the geometry alone: computed once, the same values
    # as a fresh evaluation of the first law, and read-only since engines share it
    a = build_model(_with_crankcase(None)).engine
    b = build_model(_with_crankcase(1.0e5)).engine
    assert a.pressure_cycle is b.pressure_cycle
    n = a.samples_per_cycle
    fresh = PressureCycle(a.gas.pressure(a.geometry, np.arange(n) * CYCLE / n))
    np.testing.assert_array_equal(a.pressure_cycle.samples, fresh.samples)
    with pytest.raises(ValueError, match="read-only"):
        a.pressure_cycle.samples[0] = 0.0
