"""Gas torque from a cylinder-pressure spectrum: against the model's time-domain torque,
the indicated work (integrated by parts, from the volume), firing symmetry and pegging."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.interpolate import CubicSpline
from support.engines import GAS, inline3, inline4

from powertrain.errors import PhysicsError
from powertrain.gas import CYCLE
from powertrain.half_orders import half_order_spectrum
from powertrain.pressure_torque import pressure_torque_map


def pressure_spectrum(engine, max_order: float) -> np.ndarray:
    """Cylinder-1 pressure orders 0 .. max_order (Pa) of the engine's own gas model."""
    n = engine.samples_per_cycle
    p = engine.cylinder_pressure(np.arange(n) * CYCLE / n)
    return half_order_spectrum(p)[: round(2 * max_order) + 1]


@pytest.mark.parametrize("make", [inline3, inline4])
def test_matches_the_model_torque(make):
    e = make(gas=GAS)
    orders = [0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 4.5]
    truth = e.gas_torque_orders(orders)
    scale = np.max(np.abs(truth))
    # every pressure order the grid resolves: the same torque to rounding
    full = pressure_torque_map(e, orders, max_pressure_order=200.0)
    np.testing.assert_allclose(full.torque(pressure_spectrum(e, 200.0)), truth, atol=1e-9 * scale)
    # pressure orders up to 6 (the dsp's default): orders up to 2 (those the estimator
    # uses) to 1e-5 of the largest; order 3 would need 7.5
    short = pressure_torque_map(e, orders[:5], max_pressure_order=6.0)
    got = short.torque(pressure_spectrum(e, 6.0))
    np.testing.assert_allclose(got, truth[:5], atol=1e-5 * scale)


def test_mean_torque_is_the_indicated_work():
    """T_0 = n_cyl / (4 pi) * closed integral of p dV, the integral taken as -closed integral
    of V dp (by parts) with V from the piston position, not its derivative."""
    e = inline3(gas=GAS)
    n = e.samples_per_cycle
    phi = np.arange(n) * CYCLE / n
    spectrum = pressure_spectrum(e, 200.0)
    k = np.arange(spectrum.size)
    # dp/dphi from the spectrum, V from the cylinder geometry
    dp = np.real(np.exp(0.5j * np.outer(phi, k)) @ (0.5j * k * spectrum))
    volume, _ = e.geometry.volume(phi, GAS.compression_ratio)
    work = -np.sum(volume * dp) * CYCLE / n
    t0 = pressure_torque_map(e, [0.0], 200.0).torque(spectrum)[0]
    assert work > 20.0  # J: a firing cycle does work
    assert t0.real == pytest.approx(e.cylinders * work / CYCLE, rel=1e-9)


def test_inline3_gas_torque_has_only_multiples_of_one_and_a_half():
    e = inline3(gas=GAS)
    t = pressure_torque_map(e, [0.5, 1.0, 1.5, 2.0, 2.5, 3.0]).torque(pressure_spectrum(e, 6.0))
    assert np.max(np.abs(t[[0, 1, 3, 4]])) < 1e-12 * np.abs(t[2])
    assert np.abs(t[5]) > 0.1 * np.abs(t[2])


def test_raising_pressure_and_crankcase_together_changes_nothing():
    """Only p - p_cc loads the piston: pegging errors matter as much as crankcase pressure."""
    e = inline4(gas=GAS)
    spectrum = pressure_spectrum(e, 6.0)
    t = pressure_torque_map(e, [2.0, 4.0]).torque(spectrum)
    raised = spectrum.copy()
    raised[0] += 0.3e5
    shifted = replace(e, crankcase_pressure=e.crankcase_pressure + 0.3e5)
    np.testing.assert_allclose(pressure_torque_map(shifted, [2.0, 4.0]).torque(raised), t)
    # and a pegging error alone moves the inline 4's order 2 by -A dp (sum of lever orders)
    moved = pressure_torque_map(e, [2.0, 4.0]).torque(raised)
    assert np.abs(moved[0] - t[0]) > 1e-3 * np.abs(t[0])


def test_batches_and_bad_sizes():
    e = inline3(gas=GAS)
    m = pressure_torque_map(e, [1.5, 3.0], 6.0)
    s = pressure_spectrum(e, 6.0)
    both = m.torque(np.stack([s, 2 * s - np.eye(1, s.size)[0] * s[0]]))
    np.testing.assert_allclose(both[1] - m.constant, 2 * (both[0] - m.constant), rtol=1e-12)
    with pytest.raises(PhysicsError, match=r"half orders 0\.\.12"):
        m.torque(s[:5])
    with pytest.raises(PhysicsError, match=r"multiple of 0\.5"):
        pressure_torque_map(e, [1.5], 6.2)


@pytest.mark.parametrize("make", [inline3, inline4])
def test_pressure_cycle_is_scipys_periodic_spline_bit_for_bit(make):
    """The uniform-grid evaluation against scipy's own (bisection) on random angles over
    several cycles, negative ones, every grid point and the floats either side of it."""
    cycle = make(gas=GAS).pressure_cycle
    n = cycle.samples.size
    grid = np.linspace(0.0, CYCLE, n + 1)
    spline = CubicSpline(grid, np.append(cycle.samples, cycle.samples[0]), bc_type="periodic")
    rng = np.random.default_rng(7)
    near = np.concatenate([grid, np.nextafter(grid, -1.0), np.nextafter(grid, 99.0)])
    phi = np.concatenate([rng.uniform(-3 * CYCLE, 5 * CYCLE, 20000), near, [-1e-300, -0.0]])
    assert np.array_equal(cycle(phi), spline(phi))
    assert np.array_equal(cycle(near), spline(np.mod(near, CYCLE)))


def _map_on_the_grid(engine, orders, max_pressure_order):
    """The map built in the time domain: each unit pressure order's torque on the grid,
    then its spectrum (the construction the shifted-DFT form replaced)."""
    h = np.asarray(orders, float)
    n_half = round(2 * max_pressure_order) + 1
    n = engine.samples_per_cycle
    phi = np.arange(n) * CYCLE / n
    area = engine.geometry.area
    lever = np.stack(
        [-area * engine.slider_crank.piston_motion(phi - a)[1] for a in engine.throw_angles]
    )
    half_angle = 0.5 * (phi[None, :] - engine.firing_angles[:, None])
    k = np.arange(n_half)[:, None, None]
    torque_re = np.sum(np.cos(k * half_angle) * lever, axis=1)
    torque_im = np.sum(-np.sin(k * half_angle) * lever, axis=1)
    constant = np.sum(-engine.crankcase_pressure * lever, axis=0)
    index = np.rint(2 * h).astype(int)
    return (
        half_order_spectrum(constant)[index],
        half_order_spectrum(torque_re.T)[index],
        half_order_spectrum(torque_im.T)[index],
    )


@pytest.mark.parametrize("make", [inline3, inline4])
@pytest.mark.parametrize("max_order", [6.0, 60.0])
def test_the_map_is_the_time_domain_construction(make, max_order):
    e = make(gas=GAS)
    orders = [0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.5, 7.0]
    got = pressure_torque_map(e, orders, max_order)
    constant, from_re, from_im = _map_on_the_grid(e, orders, max_order)
    scale = max(np.max(np.abs(from_re)), np.max(np.abs(from_im)))
    np.testing.assert_allclose(got.from_re, from_re, rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(got.from_im, from_im, rtol=0, atol=1e-13 * scale)
    # the crankcase share is -p_cc times the k = 0 column: it cancels to rounding on an
    # inline 3, so it is judged on that column's scale
    np.testing.assert_allclose(
        got.constant, constant, rtol=0, atol=1e-13 * e.crankcase_pressure * scale
    )
