"""The 720 deg cycle: which crank revolution holds cylinder 1's firing TDC.

A crank wheel knows phi modulo 360 deg. The wheel angle ``phi_w`` the decoder
builds satisfies ``phi = phi_w + 2 pi p`` with an unknown *parity* ``p`` in {0, 1};
a wrong parity multiplies every half order by -1 (``exp(-i h 2 pi)``) and
leaves integer orders alone. Two references fix it:

* cam: one edge per cycle at ``phi = cam_angle`` (mod 720 deg), so
  ``p = round(((cam_angle - phi_w) mod 4 pi) / 2 pi) mod 2``. The residual must be
  within 90 deg of zero, else the cam angle in the configuration is wrong.
* cylinder-1 pressure: the mean pressure within +-60 deg of the two candidate
  TDCs (``phi_w = 2 pi k``) is compared over consecutive candidates; firing TDC
  is the one with the higher pressure (compression plus combustion, against
  about 1 bar at the gas-exchange TDC). A pair decides only if one exceeds the
  other by half, so a motored engine's equal compression peaks would never
  vote falsely (they do differ: only the firing TDC compresses).

Parities are kept per *chain*: runs of the wheel joined by a bridged re-sync
share the same parity; an unbridged re-sync starts a new chain.
"""

from __future__ import annotations

import math

import numpy as np

from dsp import kernels

PRESSURE_HALF_WIDTH_RAD = math.radians(60.0)
PRESSURE_RATIO = 1.5
CAM_TOLERANCE_RAD = math.radians(90.0)


def offset_steps(kind: str, teeth: int) -> int:
    """In how many equal steps per revolution the wheel angle may be off the crank angle.

    A wheel (its gap) and a once-per-revolution pulse fix phi modulo 360 deg: 1. N equal
    pulses per revolution fix it only modulo 360/N deg: N. The unknown offset of a chain
    is then ``phi - phi_w = s 2 pi / N`` with ``s`` in ``0 .. 2N - 1`` over the 720 deg
    cycle (the *parity* ``s = p`` of the wheel is the case N = 1).
    """
    return teeth if kind == "pulses" else 1


def cam_parity(phi_w: float, cam_angle_rad: float, steps: int = 1) -> tuple[int, float]:
    """Offset ``s`` (in steps of ``2 pi / steps``) implied by a cam edge seen at wheel angle
    ``phi_w`` (rad), and the residual (rad, within half a step)."""
    step = 2.0 * math.pi / steps
    off = (cam_angle_rad - phi_w) % (4.0 * math.pi)
    s = round(off / step) % (2 * steps)
    resid = (off - step * s + 0.5 * step) % step - 0.5 * step
    return s, resid


def cam_tolerance(steps: int) -> float:
    """How far (rad) a cam edge may lie from a candidate offset: 90 deg, at most a quarter step
    of N pulses (halfway between two candidates the cam would pick either)."""
    return min(CAM_TOLERANCE_RAD, 0.25 * 2.0 * math.pi / steps)


def offset_rotation(s: np.ndarray, k2: np.ndarray, steps: int) -> np.ndarray:
    """``exp(-i h delta)`` for orders ``h = k2 / 2`` and chain offsets ``delta = s 2 pi / steps``:
    ``(f, n_orders)``, the factor taking amplitudes from the wheel angle to the crank angle.

    For a wheel (``steps == 1``) it is the exact sign ``(-1) ** (k2 s)``: half orders flip
    with the cycle, integer orders stay (no rounding in the complex exponential).
    """
    if steps == 1:
        # (-1.0) ** n, exactly: -1 for odd n (numpy's % is a floor modulo, so also below 0)
        return np.where((k2[None, :] * s[:, None]) % 2 == 1, -1.0, 1.0)
    m = (k2[None, :] * s[:, None]) % (4 * steps)  # h delta = pi m / steps, period 4 pi h
    return np.exp(-1j * math.pi * m / steps)


def pressure_half_width(steps: int = 1) -> float:
    """Half-width (rad) of the window summed around each candidate TDC: 60 deg, at most
    half the spacing of N pulses' candidates (4 pulses: 45 deg) so that no sample
    counts for two candidates."""
    return min(PRESSURE_HALF_WIDTH_RAD, 0.5 * 2.0 * math.pi / steps)


def pressure_sums(
    phi_w: np.ndarray, pressure: np.ndarray, steps: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pressure sums near the candidate TDCs ``k 2 pi / steps`` crossed by these samples.

    A wheel's candidates are one revolution apart; N pulses per revolution leave one
    at each pulse (``steps`` = N, :func:`offset_steps`).

    Returns
    -------
    k : (c,) int64
        Candidate indices.
    total : (c,) float
        Sum of the pressure samples within :func:`pressure_half_width` of the candidate
        (NaN samples skipped).
    count : (c,) int64
    """
    step = 2.0 * math.pi / steps
    if kernels.USE:  # two passes over the samples instead of a dozen array operations
        return kernels.pressure_sums(phi_w, pressure, step, pressure_half_width(steps))
    k = np.rint(phi_w / step)  # whole numbers, as float
    near = np.abs(phi_w - step * k) < pressure_half_width(steps)
    near &= np.isfinite(pressure)
    if not near.any():
        e = np.empty(0, dtype=np.int64)
        return e, np.empty(0), e
    kk, pp = k[near].astype(np.int64), pressure[near]
    base = int(kk.min())
    kk -= base
    total = np.bincount(kk, weights=pp)
    count = np.bincount(kk)
    has = np.flatnonzero(count)
    return has + base, total[has], count[has]


def pressure_parity(mean_k: float, mean_k1: float, k: int) -> int | None:
    """Parity from the mean pressures at candidates ``k`` and ``k + 1``; None if undecided.

    Either mean may be negative (a relative pressure sensor with an offset): each is
    compared with the other as it is, in this order."""
    if not (math.isfinite(mean_k) and math.isfinite(mean_k1)):
        return None
    if mean_k > PRESSURE_RATIO * mean_k1:
        return k % 2
    if mean_k1 > PRESSURE_RATIO * mean_k:
        return (k + 1) % 2
    return None


def pressure_offset(means: np.ndarray, k0: int, steps: int) -> int | None:
    """Chain offset ``s`` (in steps of ``2 pi / steps``, :func:`offset_steps`) from the
    mean pressures at the ``2 steps`` consecutive candidates ``k0, k0 + 1, ...`` of one
    720 deg cycle; None if undecided.

    Firing TDC is the candidate whose mean exceeds every other's by ``PRESSURE_RATIO``;
    there ``phi = phi_w + s 2 pi / steps`` is a multiple of 4 pi, so ``s = -k mod 2 steps``
    (a wheel: the parity ``k mod 2``).
    """
    if steps == 1 and means.size == 2:  # a wheel: the pair rule, exactly as it always was
        return pressure_parity(float(means[0]), float(means[1]), k0)
    if means.size != 2 * steps or not np.all(np.isfinite(means)):
        return None
    order = np.argsort(means)
    top, second = means[order[-1]], means[order[-2]]
    if not top > PRESSURE_RATIO * second:
        return None
    return int(-(k0 + int(order[-1])) % (2 * steps))
