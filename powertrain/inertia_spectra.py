"""An engine's inertia loads per order at unit speed, computed once per process per engine.

A run's set-up takes the unit-speed inertia spectra (:meth:`powertrain.engine.Engine.
unit_inertia_orders`) of the nominal engine (8192 points a cycle) and of about ten
engines of the model-input derivatives (``ptinertia/to_model_inputs.py``, 1024 points),
which differ from each other in a mass, the gas or the crankcase pressure; a campaign's
or a study's runs, and a replay in a long-lived process, take the same engines again.
Those spectra were 80 % of the set-up (measured 2026-11-26 with py-spy: 13 of 16.6 ms of
CPU on the i3 bench's second run in a process, the slider-crank kinematics and the
balancing masses of every cylinder on every point).

So they are kept here, keyed on the engine's value rather than its identity (an engine
compares by identity: ``eq=False``): every field but the three the inertia loads do not
read (:data:`NOT_INERTIA`; a test changes each of those and checks the loads do not
move, and each of the others and checks they do). The arrays are read-only: engines that
share them must not write to them. The cache holds keys and arrays, not the engines
(about 0.45 MiB for an 8192-point engine, 60 KiB for a 1024-point one).
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
    """The engine's value as far as its inertia loads go: its type and its fields but
    :data:`NOT_INERTIA`, arrays as their shape, dtype and bytes (hashable)."""
    fields = (f.name for f in dataclasses.fields(engine) if f.name not in NOT_INERTIA)
    return (type(engine), *((name, _hashable(getattr(engine, name))) for name in fields))


def _hashable(v: Any) -> Any:
    """``v`` as a hashable value that compares equal exactly when ``v`` does: arrays by
    their bytes, sequences (a list of unbalances) and dataclasses (a balance shaft with an
    array position) item by item."""
    if isinstance(v, np.ndarray):
        return (v.shape, v.dtype.str, v.tobytes())
    if isinstance(v, list | tuple):
        return tuple(_hashable(x) for x in v)
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return (type(v), *(_hashable(getattr(v, f.name)) for f in dataclasses.fields(v)))
    return v


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
    e, by.engine = by.engine, None  # the cache keeps the key, not the engine and its caches
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
