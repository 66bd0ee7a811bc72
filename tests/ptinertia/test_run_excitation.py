"""The known excitation and the measured gas moment of a run of frames in one call
(``many``, :mod:`ptinertia.to_estimator`) give every frame the bits of its own call, and
the estimator takes the same loads from a setup whose callables lack ``many`` (the
``ExcitationFn`` contract test helpers implement)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np

from estimator.fitted_runs import gas_moments, run_excitation
from ptinertia.config import load_bench
from ptinertia.paths import EXAMPLES_DIR
from ptinertia.to_estimator import PressureGas, estimator_setup

I3 = EXAMPLES_DIR / "i3-bench.toml"
ORDERS = np.array([1.0, 1.5, 2.0, 3.0])


def _setup():
    bench = load_bench(I3)
    return estimator_setup(bench, pressure=PressureGas("p_cyl1", 1e5, 6.0))


def test_a_run_of_crank_speeds_gets_each_frames_own_excitation() -> None:
    setup = _setup()
    rpm = np.random.default_rng(4).uniform(900.0, 6500.0, 37).tolist()
    force, moment = setup.excitation.many(rpm, ORDERS)  # type: ignore[attr-defined]
    for j, r in enumerate(rpm):
        f, m = setup.excitation(r, ORDERS)
        assert np.array_equal(force[j], f) and np.array_equal(moment[j], m)
    # a setup whose excitation is a plain function: the frame-by-frame calls
    plain = dataclasses.replace(setup, excitation=lambda r, o: setup.excitation(r, o))
    f2, m2 = run_excitation(plain, rpm, ORDERS)
    assert np.array_equal(f2, force) and np.array_equal(m2, moment)


def test_a_run_of_pressure_spectra_gets_each_frames_own_gas_moment() -> None:
    setup = _setup()
    rng = np.random.default_rng(5)
    spectra = 1e5 * (rng.normal(size=(23, 14)) + 1j * rng.normal(size=(23, 14)))
    spectra[4, 2] = np.nan  # a frame whose pressure lost samples: no measured gas
    frames = [SimpleNamespace(spectrum=p) for p in spectra]
    frames[7] = SimpleNamespace()  # a frame without a pressure channel
    gas = gas_moments(setup, frames, ORDERS)[0]  # type: ignore[arg-type]
    assert gas[4] is None and gas[7] is None
    assert setup.gas_moment is not None
    plain = dataclasses.replace(setup, gas_moment=lambda o, p: setup.gas_moment(o, p))
    one_by_one = gas_moments(plain, frames, ORDERS)[0]  # type: ignore[arg-type]
    for j, g in enumerate(gas):
        if j in (4, 7):
            assert one_by_one[j] is None
            continue
        assert g is not None and np.array_equal(g, setup.gas_moment(ORDERS, spectra[j]))
        assert np.array_equal(g, one_by_one[j])
    # the moments as one array (fit_run adds them in one sum): the same rows, at the
    # frames that have one; none from the plain function
    given, at, stack = gas_moments(setup, frames, ORDERS)  # type: ignore[arg-type]
    assert at == [j for j, g in enumerate(gas) if g is not None] and stack is not None
    assert all(given[j] is gas[j] or np.array_equal(given[j], gas[j]) for j in at)
    assert np.array_equal(stack, np.array([gas[j] for j in at]))
    assert gas_moments(plain, frames, ORDERS)[1:] == ([], None)  # type: ignore[arg-type]
    # the gas torque is about the crank axis, and not nil
    g = gas[0]
    assert g is not None and np.allclose(np.cross(g.real, setup.crank_axis), 0.0)
    assert np.abs(g).max() > 0
