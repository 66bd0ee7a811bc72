"""An engine's inertia loads per order at unit speed, computed once per process per engine.

A run's set-up takes the unit-speed inertia spectra (:meth:`powertrain.engine.Engine.
unit_inertia_orders`) of the nominal engine (8192 points a cycle) and of about ten
engines of the model-input derivatives (``ptinertia/to_model_inputs.py``, 1024 points),
which differ from each other in a mass, the gas or the crankcase pressure; a campaign's
or a study's runs, and a replay in a long-lived process, take the same engines again.
Each spectrum was 80 % of the set-up (measured 2026-11-26 with py-spy: 13 of 16.6 ms of
CPU on the i3 bench's second run in a process, the slider-crank kinematics and the
balancing masses of every cylinder on every point).

So they are kept here, keyed on the engine's value rather than its identity (an engine
compares by identity: ``eq=False``): every field but the three the inertia loads do not
read (:data:`NOT_INERTIA`; a test changes each and checks the loads do not move). The
arrays are read-only: engines that share them must not write to them.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import numpy as np

from powertrain.half_orders import half_order_spectrum

#: Engine fields the inertia loads do not depend on (the gas torque reads them).
NOT_INERTIA = frozenset({"gas", "crank_spin_inertia", "crankcase_pressure"})

Spectra = tuple[np.ndarray, np.ndarray, np.ndarray]


def inertia_key(engine: Any) -> tuple[Any, ...]:
    """The engine's value as far as its inertia loads go: its fields but
    :data:`NOT_INERTIA`, arrays as their shape and bytes (hashable)."""
    key = []
    for f in dataclasses.fields(engine):
        if f.name in NOT_INERTIA:
            continue
        v = getattr(engine, f.name)
        key.append((f.name, v.shape, v.tobytes()) if isinstance(v, np.ndarray) else (f.name, v))
    return tuple(key)


class _ByInertia:
    """An engine that hashes and compares by :func:`inertia_key` (the cache's argument)."""

    __slots__ = ("engine", "key")

    def __init__(self, engine: Any) -> None:
        self.engine = engine
        self.key = inertia_key(engine)

    def __hash__(self) -> int:
        return hash(self.key)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _ByInertia) and self.key == other.key


# 32 engines: a run's dozen, with room for a campaign's few benches.
@functools.lru_cache(maxsize=32)
def _spectra(by: _ByInertia) -> Spectra:
    e = by.engine
    f, m, torque = e._inertia_parts(e._grid, e.reference_point)
    out = half_order_spectrum(f), half_order_spectrum(m), half_order_spectrum(torque)
    for a in out:
        a.flags.writeable = False
    return out


def shared_spectra(engine: Any) -> Spectra:
    """The engine's force, moment (about its reference point) and inertia-torque spectra
    at 1 rad/s (:mod:`powertrain.half_orders`), or the same arrays computed before for an
    engine of the same inertia (read-only)."""
    return _spectra(_ByInertia(engine))
