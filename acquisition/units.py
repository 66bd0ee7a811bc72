"""Unit-suffixed configuration keys.

Every dimensional key in a bench file carries its unit in its name
(``stroke_mm``, ``position_m``, ``stiffness_kn_per_m``). The schema declares
the SI spelling; :func:`normalise_keys` rewrites the accepted alternatives to
it, scaling the values, and refuses a dimensional key written without a unit.

A table rather than pint (which converts the units of recorded channels,
:mod:`acquisition.signal_units`): the work here is splitting identifier suffixes
(``_kgmm2``, ``_n_per_mm``) that no unit library parses, the factors are a dozen exact
powers of ten, and every command reads a bench file, so pint's 0.4 s registry would
be paid by every run, the simulated default one included.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

# SI suffix -> {alternative suffix: factor to SI}
ALTERNATIVES: dict[str, dict[str, float]] = {
    "m": {"mm": 1e-3, "cm": 1e-2},
    "kg": {"g": 1e-3},
    "kgm": {"gmm": 1e-6, "gcm": 1e-5, "kgmm": 1e-3},
    "kgm2": {"kgmm2": 1e-6, "gmm2": 1e-9},
    "deg": {"rad": 180.0 / math.pi},
    "n_per_m": {"kn_per_m": 1e3, "n_per_mm": 1e3},
    "pa": {"bar": 1e5, "kpa": 1e3, "mpa": 1e6},
    "nm": {"knm": 1e3},
    "hz": {"khz": 1e3},
    "s": {"ms": 1e-3},
    "j": {"kj": 1e3},
}


def _split(key: str, suffixes: list[str]) -> tuple[str, str] | None:
    for suffix in sorted(suffixes, key=len, reverse=True):
        if key.endswith("_" + suffix):
            return key[: -len(suffix) - 1], suffix
    return None


def _scale(value: Any, factor: float) -> Any:
    if isinstance(value, bool) or factor == 1.0:
        return value
    if isinstance(value, int | float):
        return value * factor
    if isinstance(value, list):
        return [_scale(v, factor) for v in value]
    if isinstance(value, Mapping):
        return {k: _scale(v, factor) for k, v in value.items()}
    return value


def normalise_keys(data: Mapping[str, Any], si_fields: set[str]) -> dict[str, Any]:
    """Rewrite unit-suffixed alternatives of ``si_fields`` to their SI spelling.

    Raises
    ------
    KeyError
        Carrying ``(key, message)`` for a dimensional key without a unit or
        given twice in different units.
    """
    stems: dict[str, tuple[str, str]] = {}
    for name in si_fields:
        split = _split(name, list(ALTERNATIVES))
        if split:
            stems[split[0]] = (name, split[1])
    out: dict[str, Any] = {}
    for key, value in data.items():
        if key in si_fields:
            target, converted = key, value
        elif key in stems:
            name, si = stems[key]
            units = ", ".join([si, *ALTERNATIVES[si]])
            raise KeyError(key, f"missing unit: write {name} (or another unit of {units})")
        else:
            target, converted = key, value
            for stem, (name, si) in stems.items():
                split = _split(key, list(ALTERNATIVES[si]))
                if split and split[0] == stem:
                    target = name
                    converted = _scale(value, ALTERNATIVES[si][split[1]])
                    break
        if target in out:
            raise KeyError(key, f"given twice (also as {target})")
        out[target] = converted
    return out
