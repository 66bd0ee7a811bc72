"""From the bench file's declared model tolerances to the estimator's model inputs (type B).

``[estimator]`` declares, 1 sigma, how well the bench file knows the inputs of the
model the estimator takes as known (docs/bench-file.md):

=================================  =========================================================
``gas_tolerance_pct``              the gas model: a parametric model's heat release, a
                                   trace's or a torque table's gas torque as a whole
``spin_inertia_tolerance_pct``     ``[engine] crank_spin_inertia_kgm2``
``piston_mass_tolerance_pct``      ``[engine] piston_mass_kg`` (reciprocating)
``conrod_mass_tolerance_pct``      ``[engine] conrod_mass_kg`` (its big end rotates, its
                                   small end reciprocates)
``mount_stiffness_tolerance_pct``  each mount's stiffness, independently
``crankcase_pressure_tolerance_pa`` ``[gas] crankcase_pressure_pa``
=================================  =========================================================

How each moves the equations is in :mod:`estimator.model_inputs`. The excitation's
derivatives are taken here, once per set of orders: analytic for a gas-torque scale
(the gas part itself), a central difference of the engine's excitation for the rest
(the masses and the crankcase pressure enter it linearly, so the difference is exact;
the heat release enters the Wiebe pressure smoothly, stepped by its own tolerance).

What is estimated rather than declared: the mount stiffness scales with ``[estimator]
mount_scale`` (the reactions scale like ``1/W^2`` along the sweep, the inertia terms do
not; their tolerance then leaves the type-B part). The others are declared, because:

* the masses and the gas scale the known excitation the inertia is measured against.
  The inertia loads scale like the inertia terms' own response (``omega^2``), so a mass
  error is an error of the inertia's scale; and with the default orders (1, 1.5, 2) the
  i3's roll is driven by the gas alone (its inertia torque has orders 3, 6, ...), so its
  roll equation holds ``Iyy`` against the gas torque with nothing to tell them apart but
  the mounts' weak ``1/W^2`` share;
* the spin inertia could be told in principle: its gyroscopic term is the imaginary,
  skew part of the moment equation, which no inertia tensor has. It would be a new
  unknown of the parameter layout (``estimator/equations.py``, which the unbalance's
  location reworks now); declared, it costs the i3's Izz interval about a fifth more
  (5 % tolerance, 20 s sweep: std 1.5 -> 1.9 %).

With a cylinder-pressure channel the gas is measured, and its tolerance does not apply.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np

from estimator.setup import Corrections, ModelInput, PairExcitationFn
from powertrain.engine import Engine
from powertrain.gas import OrdersGas, ParametricGas
from powertrain.half_orders import OrderExcitation, rpm_to_omega
from ptinertia import config

#: (engine, step) -> the engine with the input moved by ``step`` (in the input's unit)
Perturb = Callable[[Engine, float], Engine]


def _difference(
    engine: Engine, perturb: Perturb, step: float, about: np.ndarray
) -> PairExcitationFn:
    """d(excitation)/d(input) by a central difference of +-``step``, cached per set of orders."""
    # A coarser cycle than the nominal excitation's (8192 points) is plenty for a
    # derivative: the loads are smooth (the gas spectrum falls like 1/h^3), and the
    # difference of two engines costs a tenth (8 ms, not 80, per input).
    coarse = dataclasses.replace(engine, samples_per_cycle=min(engine.samples_per_cycle, 1024))
    plus, minus = perturb(coarse, step), perturb(coarse, -step)

    def parts(orders: tuple[float, ...]) -> OrderExcitation:
        a, b = plus.order_excitation(orders, about), minus.order_excitation(orders, about)
        return OrderExcitation(
            *(
                (getattr(a, f.name) - getattr(b, f.name)) / (2 * step)
                for f in dataclasses.fields(OrderExcitation)
            )
        )

    return _PairDerivative(parts)


def _gas_part(engine: Engine, about: np.ndarray) -> PairExcitationFn:
    """The gas part of the excitation: its derivative by a scale of the gas torque."""

    def parts(orders: tuple[float, ...]) -> OrderExcitation:
        full = engine.order_excitation(orders, about)
        none = np.zeros_like(full.unit_inertia_force)
        return OrderExcitation(full.gas_force, full.gas_moment, none, none)

    return _PairDerivative(parts)


class _PairDerivative:
    """A :data:`estimator.setup.PairExcitationFn` from the speed-split parts of a set of
    orders (cached): evaluated for (frame, order) pairs at once, the gas part plus
    ``omega^2`` times the inertia part; offering the parts themselves as ``split`` (the
    compiled rows gather them)."""

    def __init__(self, parts: Callable[[tuple[float, ...]], OrderExcitation]) -> None:
        self.parts = parts
        # per set of orders (sorted): the gas parts and the inertia parts, (K, 2, 3)
        # [force, moment] each (one gather per call instead of four)
        self.by_orders: dict[tuple[float, ...], tuple[np.ndarray, np.ndarray]] = {}

    def split(self, key: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
        """The gas and the unit-speed inertia parts (K, 2, 3) complex of the sorted
        distinct orders ``key``: a pair of order ``key[i]`` at crank speed omega rad/s
        has ``gas[i] + omega^2 unit[i]`` ([force N, moment N m] per unit of the input)."""
        known = self.by_orders.get(key)
        if known is None:
            ex = self.parts(key)
            known = self.by_orders[key] = (
                np.stack([ex.gas_force, ex.gas_moment], axis=1),
                np.stack([ex.unit_inertia_force, ex.unit_inertia_moment], axis=1),
            )
        return known

    def __call__(self, rpm: np.ndarray, orders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        key, at = _order_index(np.asarray(orders, float).tobytes())
        gas, unit = self.split(key)
        both = gas[at] + _speed_squared(np.asarray(rpm, float).tobytes()) * unit[at]
        return both[:, 0], both[:, 1]


# Each excitation input's derivative is evaluated for the same (frame, order) pairs in a
# batch of rows: their order index and speeds squared are made once for all of them.
@functools.lru_cache(maxsize=64)
def _order_index(orders: bytes) -> tuple[tuple[float, ...], np.ndarray]:
    """The sorted distinct orders of the pairs' ``orders`` (float64 bytes; np.unique's
    without its cost) and each pair's index among them (read-only)."""
    h = np.frombuffer(orders)
    key = tuple(sorted(set(h.tolist())))
    at = np.searchsorted(np.array(key), h)
    at.flags.writeable = False
    return key, at


@functools.lru_cache(maxsize=4)
def _speed_squared(rpm: bytes) -> np.ndarray:
    """(n, 1, 1) the pairs' crank speeds ``rpm`` (float64 bytes) squared, (rad/s)^2
    (read-only)."""
    w2 = (rpm_to_omega(np.frombuffer(rpm)) ** 2)[:, None, None]
    w2.flags.writeable = False
    return w2


def _with_heat_release(engine: Engine, step: float) -> Engine:
    gas = engine.gas
    assert isinstance(gas, ParametricGas)
    scaled = dataclasses.replace(gas, heat_release=gas.heat_release * (1 + step))
    return dataclasses.replace(engine, gas=scaled)


# The masses move the inertia loads only: their engines leave the gas out (its part of the
# difference is zero, and its pressure cycle is most of an engine's cost).
def _with_piston_mass(engine: Engine, step: float) -> Engine:
    return dataclasses.replace(engine, piston_mass=engine.piston_mass * (1 + step), gas=None)


def _with_conrod_mass(engine: Engine, step: float) -> Engine:
    return dataclasses.replace(engine, conrod_mass=engine.conrod_mass * (1 + step), gas=None)


def _with_crankcase(engine: Engine, step: float) -> Engine:
    return dataclasses.replace(engine, crankcase_pressure=engine.crankcase_pressure + step)


def model_inputs(
    bench: config.Bench,
    engine: Engine,
    about: np.ndarray,
    corrections: Corrections,
    gas_measured: bool,
    mounts: tuple[str, ...],
) -> tuple[ModelInput, ...]:
    """The model inputs of ``bench`` with a declared tolerance above zero.

    ``engine``: the nominal engine; ``about``: the point the excitation moment is
    taken about; ``corrections``: those in force (no spin inertia without the
    gyroscopic term, no mount without the suspension, none for estimated mount
    scales); ``gas_measured``: the gas torque comes from a pressure channel;
    ``mounts``: the names of the mounts the estimator models. Relative tolerances are
    relative (std 0.05 for 5 %); the spin inertia's std is in kg m^2, the
    crankcase pressure's in Pa.
    """
    tol = bench.estimator
    out: list[ModelInput] = []
    gas = engine.gas
    if tol.gas_tolerance_pct > 0 and gas is not None and not gas_measured:
        rel = tol.gas_tolerance_pct / 100.0
        if isinstance(gas, ParametricGas):
            d_gas = _difference(engine, _with_heat_release, rel, about)
        else:
            d_gas = _gas_part(engine, about)
        out.append(ModelInput("gas", "excitation", rel, d_excitation=d_gas))
    spin = engine.crank_spin_inertia
    if tol.spin_inertia_tolerance_pct > 0 and corrections.gyroscopic and spin > 0:
        out.append(
            ModelInput(
                "spin_inertia", "spin_inertia", spin * tol.spin_inertia_tolerance_pct / 100.0
            )
        )
    for name, pct, perturb in (
        ("piston_mass", tol.piston_mass_tolerance_pct, _with_piston_mass),
        ("conrod_mass", tol.conrod_mass_tolerance_pct, _with_conrod_mass),
    ):
        if pct > 0:
            rel = pct / 100.0
            out.append(
                ModelInput(
                    name, "excitation", rel, d_excitation=_difference(engine, perturb, rel, about)
                )
            )
    pcc = tol.crankcase_pressure_tolerance_pa
    if pcc > 0 and gas is not None and not isinstance(gas, OrdersGas):
        d_pcc = _difference(engine, _with_crankcase, pcc, about)
        out.append(ModelInput("crankcase_pressure", "excitation", pcc, d_excitation=d_pcc))
    if (
        tol.mount_stiffness_tolerance_pct > 0
        and corrections.suspension
        and not corrections.mount_scale
    ):
        rel = tol.mount_stiffness_tolerance_pct / 100.0
        out += [ModelInput(f"mount:{name}", "mount", rel, mount=i) for i, name in enumerate(mounts)]
    # The excitation derivatives of the bench's orders built now, not at the first batch of
    # rows (about 0.1 s in all: a live run's first estimate would be late), as the
    # nominal excitation is (ptinertia/to_estimator.py).
    orders = np.asarray(bench.dsp.orders, float)
    for inp in out:
        if inp.d_excitation is not None:
            inp.d_excitation(np.zeros(len(orders)), orders)
    return tuple(out)
