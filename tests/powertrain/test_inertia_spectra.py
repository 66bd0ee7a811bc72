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


def _loaded(base=inline4, **kw) -> Engine:
    """An engine with every kind of inertia load: rods with their own inertia, a crank
    unbalance and a balance shaft, on a tilted cylinder axis."""
    return base(
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


# Every field the key keeps, changed validly. Two are kept though no inertia load reads
# them (a cache miss at worst): the bore, and the firing order (the throw angles must
# agree with it, so they change together here).
KEPT_UNREAD = {"bore", "firing_order"}
CHANGES = {
    "cylinders": lambda e: inline3(samples_per_cycle=512),
    "stroke": lambda e: dataclasses.replace(e, stroke=e.stroke * 1.01),
    "conrod_length": lambda e: dataclasses.replace(e, conrod_length=e.conrod_length * 1.01),
    "conrod_mass": lambda e: dataclasses.replace(e, conrod_mass=e.conrod_mass * 1.01),
    "conrod_cog_from_big_end": lambda e: dataclasses.replace(
        e, conrod_cog_from_big_end=e.conrod_cog_from_big_end * 1.1
    ),
    "piston_mass": lambda e: dataclasses.replace(e, piston_mass=e.piston_mass * 1.01),
    "reference_point": lambda e: dataclasses.replace(e, reference_point=[0.0, 0.0, 0.01]),
    "cylinder_positions": lambda e: dataclasses.replace(
        e, cylinder_positions=e.cylinder_positions + 0.01
    ),
    # (an inline 4's throws are the same for every firing order: the test takes an inline 3)
    "throw_angles": lambda e: dataclasses.replace(
        e, throw_angles=np.deg2rad([0.0, 120.0, 240.0]), firing_order=(1, 3, 2)
    ),
    "conrod_inertia": lambda e: dataclasses.replace(e, conrod_inertia=2e-3),
    "crank_axis": lambda e: dataclasses.replace(e, crank_axis=[1.0, 0.0, 0.0]),
    "cylinder_axis": lambda e: dataclasses.replace(e, cylinder_axis=[1.0, 0.0, 0.0]),
    "tilt": lambda e: dataclasses.replace(e, tilt=0.3),
    "unbalances": lambda e: dataclasses.replace(e, unbalances=(Unbalance(mr=3e-4, angle=0.3),)),
    "balance_shafts": lambda e: dataclasses.replace(
        e, balance_shafts=(BalanceShaft(order=2, mr=2e-3, angle=0.1),)
    ),
    "samples_per_cycle": lambda e: dataclasses.replace(e, samples_per_cycle=256),
}


def test_the_key_keeps_every_other_field():
    names = {name for name, _ in inertia_key(_loaded())[1:]}
    assert names == {f.name for f in dataclasses.fields(Engine)} - NOT_INERTIA
    # every field the key keeps is read by the inertia loads (changed below), or said not to be
    assert names == CHANGES.keys() | KEPT_UNREAD


@pytest.mark.parametrize("field", sorted(CHANGES), ids=sorted(CHANGES))
def test_every_field_the_key_keeps_moves_the_inertia_loads(field):
    engine = _loaded(inline3) if field == "throw_angles" else _loaded()
    other = CHANGES[field](engine)
    assert getattr(other, field) is not getattr(engine, field)
    assert inertia_key(other) != inertia_key(engine)
    own, changed = _computed(engine), _computed(other)
    assert any(
        a.shape != b.shape or not np.allclose(a, b) for a, b in zip(own, changed, strict=True)
    )
    for got, want in zip(other._unit_inertia_spectra, changed, strict=True):
        assert got.tobytes() == want.tobytes()


def test_a_list_of_unbalances_and_an_array_position_are_keys_too():
    """Engines built by hand with lists or arrays where the bench builds tuples."""
    shaft = BalanceShaft(order=1, mr=1e-3, position=np.array([0.0, 0.05, -0.1]))  # type: ignore[arg-type]
    listed = _loaded().__class__(**{
        **{f.name: getattr(_loaded(), f.name) for f in dataclasses.fields(Engine)},
        "unbalances": [Unbalance(mr=2e-4)],
        "balance_shafts": [shaft],
    })  # fmt: skip
    hash(inertia_key(listed))
    for got, want in zip(listed._unit_inertia_spectra, _computed(listed), strict=True):
        assert got.tobytes() == want.tobytes()


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
