"""Number types for command-line options: argparse refuses what no command can use.

``float("nan")``, ``float("inf")`` and ``1e308`` all parse as floats; passed on, they
fail far from the option (an overflow in the excitation, a sleep of 1e300 s). These
types make argparse print its one line (``argument --rpm: ...``) and exit 2 instead.
"""

from __future__ import annotations

import argparse
import math

# Crank speeds, rev/min: above any engine (F1 engines stop near 15 000 rpm).
MAX_RPM = 30_000.0


def finite_float(text: str) -> float:
    """A finite float (no nan, no inf)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def positive_float(text: str) -> float:
    """A finite float > 0 (a duration, a rate)."""
    value = finite_float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def rpm(text: str) -> float:
    """A crank speed in rev/min, 0 < rpm <= MAX_RPM."""
    value = finite_float(text)
    if not 0.0 < value <= MAX_RPM:
        raise argparse.ArgumentTypeError(
            f"expected a crank speed in rev/min, 0 < rpm <= {MAX_RPM:g}, got {text!r}"
        )
    return value


def seed(text: str) -> int:
    """A random seed: an integer >= 0 (what numpy's generators take)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}")
    return value
