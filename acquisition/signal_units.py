"""The units of recorded channels, converted to the units the pipeline computes in.

A recording says in what unit each channel is (a CSV header ``A_x[g]``, an MDF4
channel's unit, a DBC signal's unit); the pipeline takes accelerations in m/s^2,
rotation speeds in rpm, pressures in bar and a sampled tacho in V
(:class:`acquisition.channels.ChannelNeed` ``unit``). :func:`unit_factor` gives the
factor from one to the other, or refuses a unit it cannot place with a message
saying what was expected.

Decision: pint (0.24+) rather than a hand-written table. Measured here: building its
registry takes 0.4 s once per process (cached below, and only file and CAN runs
build it); each channel's factor is then computed once when a file opens, and the
samples are scaled by numpy, so reading costs nothing more. A table would have to
list every spelling a DAQ writes (``m/s^2``, ``m/s²``, ``m s^-2``, ``mm/s^2``,
``1/min``, ``min^-1``, ``kPa``, ``psi``, ``mV`` ...) and every prefix; pint parses
them all with the SI factors of its definitions file. Three field conventions pint
does not know are applied here, each by the quantity the channel measures:

* ``g`` on an accelerometer is the standard gravity 9.80665 m/s^2 (for pint it is
  the gram); ``gn`` and ``G`` too.
* A rotation speed in a unit without an angle (``1/min``, ``Hz``, ``1/s``) counts
  revolutions (1/min is rpm), while ``rad/s`` and ``deg/s`` are angles per time.
* ``U/min`` and ``r/min`` (German and ISO spellings of rpm), and ``m/s2``
  (a digit exponent without ``^``).
"""

from __future__ import annotations

import functools
import re
from typing import Any

from acquisition.stream import SourceError

# what each pipeline unit measures, for messages
QUANTITY = {
    "m/s^2": "an acceleration (m/s^2, g, mm/s^2, ...)",
    "rpm": "a rotation speed (rpm, 1/min, Hz, rad/s, ...)",
    "bar": "a pressure (bar, kPa, Pa, psi, ...)",
    "V": "a voltage (V, mV, ...)",
    "s": "a time (s, ms, ...)",
}
_ACCEL_ALIASES = {"g": "g_0", "G": "g_0", "gn": "g_0", "g0": "g_0"}
_RPM_ALIASES = {"U/min": "rpm", "u/min": "rpm", "r/min": "rpm", "RPM": "rpm", "rev/min": "rpm"}
# "m/s2" -> "m/s**2": a letter followed directly by an exponent digit
_BARE_EXPONENT = re.compile(r"(?<=[A-Za-z])([2-4])\b")


class UnitError(SourceError):
    """A unit that cannot be converted to the one the pipeline needs; the message says why
    (prefixed with where, when the caller says where)."""


@functools.cache
def _registry() -> Any:
    import pint  # on use: 0.4 s to build, and a simulated run never needs it

    return pint.UnitRegistry()


def _spelling(unit: str, target: str) -> str:
    text = unit.strip()
    if target == "m/s^2":
        text = _ACCEL_ALIASES.get(text, text)
    if target == "rpm":
        text = _RPM_ALIASES.get(text, text)
    return _BARE_EXPONENT.sub(r"**\1", text)


def unit_factor(unit: str, target: str, where: str = "") -> float:
    """The factor taking values in ``unit`` to ``target`` (one of :data:`QUANTITY`).

    ``where`` (a file, channel or message) prefixes the message of a refusal.

    Raises
    ------
    UnitError
        ``unit`` empty, unknown, or of another quantity than ``target``.
    """
    try:
        return _factor(unit, target)
    except UnitError as err:
        if where:
            raise UnitError(f"{where}: {err}") from None
        raise


def _factor(unit: str, target: str) -> float:
    expected = QUANTITY.get(target, target)
    if not unit.strip():
        raise UnitError(f"no unit given, expected {expected}")
    if unit.strip() == target:
        return 1.0
    import pint  # for its error types; the registry above imported it already

    ureg = _registry()
    try:
        q = ureg.Quantity(1.0, _spelling(unit, target))
    except (pint.errors.UndefinedUnitError, pint.errors.DefinitionSyntaxError, ValueError):
        raise UnitError(f"unit {unit!r} is unknown, expected {expected}") from None
    except Exception as err:  # pint's parser raises tokenizer errors of several types
        raise UnitError(f"unit {unit!r} cannot be read ({err}), expected {expected}") from None
    if target == "rpm" and "radian" not in dict(q.to_root_units().unit_items()):
        q = q * ureg.turn  # a bare frequency of a shaft counts revolutions
    try:
        return float(q.to(target).magnitude)
    except pint.errors.DimensionalityError:
        raise UnitError(f"unit {unit!r} is not {expected}") from None
