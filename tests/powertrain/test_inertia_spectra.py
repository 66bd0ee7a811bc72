"""The inertia spectra shared by engines of the same inertia (powertrain/inertia_spectra.py):
what the key leaves out moves no inertia load, what it keeps tells engines apart, and a
shared spectrum is the one the engine computes itself."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from support.engines import GAS, inline3, inline4

from powertrain.balancing import BalanceShaft, Unbalance
from powertrain.engine import Engine
from powertrain.half_orders import half_order_spectrum
from powertrain.inertia_spectra import NOT_INERTIA, inertia_key


def _loaded(**kw) -> Engine:
    """An engine with every kind of inertia load: rods with their own inertia, a crank
    unbalance and a balance shaft, on a tilted cylinder axis."""
    return inline4(
        gas=GAS,
        tilt=0.2,
        conrod_inertia=1.5e-3,
        unbalances=(Unbalance(mr=2e-4, angle=0.3, axial=0.05),),
        balance_shafts=(BalanceShaft(order=2, mr=1e-3, angle=0.1, position=(0.0, 0.05, -0.1)),),
        samples_per_cycle=512,
        **kw,
    )


def _computed(engine: Engine) -> tuple[np.ndarray, ...]:
    """The spectra as the engine computes them, no cache."""
    f, m, torque = engine._inertia_parts(engine._grid, engine.reference_point)
    return half_order_spectrum(f), half_order_spectrum(m), half_order_spectrum(torque)


@pytest.mark.parametrize(
    "field, value",
    [("gas", None), ("crank_spin_inertia", 0.25), ("crankcase_pressure", 2.5e5)],
)
def test_the_fields_the_key_leaves_out_move_no_inertia_load(field, value):
    assert field in NOT_INERTIA
    engine = _loaded()
    other = dataclasses.replace(engine, **{field: value})
    phi = np.linspace(0.0, 4 * np.pi, 97)
    about = np.array([0.1, -0.2, 0.3])
    for a, b in zip(
        engine._inertia_parts(phi, about), other._inertia_parts(phi, about), strict=True
    ):
        assert a.tobytes() == b.tobytes()
    # the field is not idle: the gas torque reads it
    if field != "crank_spin_inertia":
        assert not np.array_equal(engine.gas_torque_orders([2.0]), other.gas_torque_orders([2.0]))


def test_the_key_keeps_every_other_field():
    names = {name for name, *_ in inertia_key(_loaded())}
    assert names == {f.name for f in dataclasses.fields(Engine)} - NOT_INERTIA


def test_engines_of_the_same_inertia_share_the_arrays_and_others_get_their_own():
    engine = _loaded()
    gasless = dataclasses.replace(engine, gas=None)
    heavier = dataclasses.replace(engine, piston_mass=engine.piston_mass * 1.01)
    shifted = dataclasses.replace(engine, reference_point=np.array([0.0, 0.0, 0.01]))
    shared = engine._unit_inertia_spectra
    assert all(a is b for a, b in zip(shared, gasless._unit_inertia_spectra, strict=True))
    for e in (engine, heavier, shifted):
        for got, own in zip(e._unit_inertia_spectra, _computed(e), strict=True):
            assert got.tobytes() == own.tobytes()
            assert not got.flags.writeable
    assert not np.array_equal(heavier._unit_inertia_spectra[0], shared[0])
    assert not np.array_equal(shifted._unit_inertia_spectra[1], shared[1])


def test_an_inline3_and_an_inline4_of_the_same_parts_are_told_apart():
    three, four = inline3(samples_per_cycle=512), inline4(samples_per_cycle=512)
    assert inertia_key(three) != inertia_key(four)
    assert not np.array_equal(three._unit_inertia_spectra[1], four._unit_inertia_spectra[1])
