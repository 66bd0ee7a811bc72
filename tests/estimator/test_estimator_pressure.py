"""Gas moment from a measured pressure spectrum instead of a gas model (harness data).

The harness's H1.5 roll moment plays the gas torque; with ``gas_moment`` set the
estimator takes it from the frame's ``spectrum`` (index k is order k/2), measured in
the frame's own crank angle.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support import estimator_harness as harness
from support.estimator_harness import Body, Frame, frames, make_setup

from estimator.streaming import InertiaEstimator

RPMS = np.linspace(1500, 4500, 41)
GAS_ROLL = np.array([0.0, -150.0, 0.0])  # N m per unit pressure order 1.5 (harness H1.5)
GAS_PHASE = np.exp(0.4j)
HARNESS_EXCITATION = harness.excitation


def inertia_part(rpm: float, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The harness's loads at whole orders (crank-train inertia has no half orders)."""
    f, m = HARNESS_EXCITATION(rpm, orders)
    half = (2 * np.asarray(orders)) % 2 == 1
    f, m = f.copy(), m.copy()
    f[half], m[half] = 0, 0
    return f, m


def gas_part(orders: np.ndarray, scale: float) -> np.ndarray:
    out = np.zeros((len(orders), 3), complex)
    out[np.asarray(orders) == 1.5] = scale * GAS_ROLL * GAS_PHASE
    return out


def model_excitation(rpm: float, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inertia plus the gas model."""
    f, m = inertia_part(rpm, orders)
    return f, m + gas_part(orders, 1.0)


def gas_moment(orders: np.ndarray, spectrum: np.ndarray) -> np.ndarray:
    """The gas from the pressure's order 1.5 (spectrum index 3)."""
    out = np.zeros((len(orders), 3), complex)
    out[np.asarray(orders) == 1.5] = GAS_ROLL * spectrum[3]
    return out


@pytest.fixture
def drive(monkeypatch: pytest.MonkeyPatch):
    """Drive the harness body with inertia and ``scale`` times the modelled gas."""

    def set_gas(scale: float) -> None:
        def driven(rpm: float, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            f, m = inertia_part(rpm, orders)
            return f, m + gas_part(orders, scale)

        monkeypatch.setattr(harness, "excitation", driven)

    set_gas(1.0)
    return set_gas


def with_spectrum(f: Frame, gas_scale: float = 1.0) -> Frame:
    spectrum = np.zeros(13, complex)
    spectrum[0] = 5e5
    spectrum[3] = gas_scale * GAS_PHASE
    spectrum[5] = 0.3 - 0.1j  # orders the harness gas does not use, to be carried along
    return dataclasses.replace(f, spectrum=spectrum)


def _estimate(body: Body, pressure: bool, frame_map=lambda f: f, gas_scale: float = 1.0):
    setup = make_setup(body)
    if pressure:
        setup = dataclasses.replace(setup, excitation=inertia_part, gas_moment=gas_moment)
    else:
        setup = dataclasses.replace(setup, excitation=model_excitation)
    est = InertiaEstimator(setup)
    for f in frames(body, RPMS):
        est.update(frame_map(with_spectrum(f, gas_scale)))
    return est


def test_measured_gas_gives_the_body_back(drive):
    body = Body()
    e = _estimate(body, pressure=True).estimate()
    assert e.frames_used == len(RPMS)
    np.testing.assert_allclose(e.inertia, body.inertia, atol=1e-9)
    np.testing.assert_allclose(e.cog, body.cog, atol=1e-10)


def test_a_wrong_gas_model_biases_and_the_pressure_channel_does_not(drive):
    body = Body()
    drive(1.2)
    modelled = _estimate(body, pressure=False).estimate()
    measured = _estimate(body, pressure=True, gas_scale=1.2).estimate()
    assert np.max(np.abs(modelled.inertia - body.inertia)) > 0.02  # kg m^2, biased
    np.testing.assert_allclose(measured.inertia, body.inertia, atol=1e-9)
    np.testing.assert_allclose(measured.cog, body.cog, atol=1e-10)


def test_reference_offset_turns_the_pressure_with_the_motion(drive):
    body = Body()
    d = np.radians(0.5)

    def late_reference(f: Frame) -> Frame:
        h = np.asarray(f.orders)[:, None]
        assert f.spectrum is not None
        k = np.arange(f.spectrum.size)
        return dataclasses.replace(
            f,
            amplitudes=f.amplitudes * np.exp(1j * h * d),
            spectrum=f.spectrum * np.exp(0.5j * k * d),
        )

    e = _estimate(body, pressure=True, frame_map=late_reference).estimate()
    assert np.degrees(e.value("crank_offset")) == pytest.approx(0.5, abs=0.01)
    assert np.max(np.abs(e.inertia - body.inertia)) < 2e-3 * np.max(np.abs(body.inertia))


def test_a_lost_cycle_needs_no_hypothesis_with_a_measured_gas(drive):
    body = Body()

    def lose_cycle(f: Frame) -> Frame:
        amps = f.amplitudes.copy()
        amps[1] *= -1  # H1.5 seen through phi + 360 deg, and so is the pressure
        assert f.spectrum is not None
        spectrum = f.spectrum * np.where(np.arange(f.spectrum.size) % 2 == 1, -1.0, 1.0)
        return dataclasses.replace(
            f, amplitudes=amps, spectrum=spectrum, flags=frozenset({"cycle_ambiguous"})
        )

    e = _estimate(body, pressure=True, frame_map=lose_cycle).estimate()
    assert e.half_order is None
    np.testing.assert_allclose(e.inertia, body.inertia, atol=1e-9)


def test_frames_without_pressure_are_rejected_with_a_reason(drive):
    body = Body()

    def drop_some(f: Frame) -> Frame:
        if f.time_s % 4 == 0:
            return dataclasses.replace(f, spectrum=None)
        if f.time_s % 4 == 1:
            assert f.spectrum is not None
            return dataclasses.replace(f, spectrum=f.spectrum * np.nan)
        return f

    est = _estimate(body, pressure=True, frame_map=drop_some)
    e = est.estimate()
    n_bad = sum(1 for i in range(len(RPMS)) if i % 4 in (0, 1))
    assert e.frames_rejected["no_pressure"] == n_bad
    assert e.frames_used == len(RPMS) - n_bad
    np.testing.assert_allclose(e.inertia, body.inertia, atol=1e-9)
