"""Compiled per-sample work of the simulated bench (numba; ``PTINERTIA_NUMBA=1``).

Per sample, the numpy path spends a complex ``exp`` for the base carrier
``exp(i phi / 2)``, a strided complex product per half order for its powers, a BLAS
product of the table's coefficients with those carriers, a Horner pass over the
product's rows in the table's normalised rpm ``u``, and a dozen passes for the crank
angle, the table interval and the pressure. The BLAS product is the machine's best
and stays (about half of the compiled path's time); the rest is compiled here:

* :func:`carriers`: the base carrier from an exact one at an anchor sample every
  ``spacing`` samples (``cos``, ``sin`` of the anchor's half angle) times ``exp(i d)``,
  ``d`` the half angle travelled since the anchor (``|d| <= 1/4`` rad by the choice of
  ``spacing``), by its Taylor series to ``d^15`` (truncation below ``1e-19``); then its
  powers by the running product, a row per half order (``cos h phi``, ``sin h phi``:
  the layout BLAS reads as is). Anchors sit at absolute sample indices, so a sample's
  carriers depend on its index only, never on the block it falls in.
* the product and the Horner sums of a run of samples: :mod:`acquisition.sim.block_kernels`.
* :func:`motion`, :func:`locate`, :func:`pressure`: ``RpmProfile.evaluate``,
  ``AmplitudeTable.locate`` and ``PressureCycle.__call__`` (its ``mod`` without libm's
  ``fmod``, exactly), one pass each, the interval found by walking from the previous
  sample's instead of bisecting.

What moves: numpy's ``exp`` rounds its own way; the anchored carriers agree with it to
a few units in the last place, and the orders :mod:`acquisition.sim.compact_design`
leaves without rpm dependence lose at most 1e-14 of the channel's largest amplitude
(2e-16 on the i3), so the accelerations move at the rounding level (under 5e-15 of each
channel's rms on the i3; the tests check 1e-13). Everything else is the
numpy path's arithmetic, operation for operation (numba contracts no ``a * b + c`` into
a fused multiply-add unless asked to): angles, speeds, rpm, intervals, ``u``, the Horner
sums and the pressure are the same bits (tests). The runs' results (``ptinertia run``,
default and ``--realistic``) are identical to the numpy path's: the pipeline rounds the
samples to float32.

Measured (issue 24, 2-core machine shared with other work, load average 6 to 17, CPU
time, best of 3 to 40): per minute of the i3's 9 accelerometers at 25.6 kHz the carriers
take 14 ms (numpy 38), the Horner sums 10 (27), the angles 3 (9), the intervals 3 (9),
the pressure 9 (22, and 50 with scipy's evaluation before this issue); the BLAS
product 47-70 ms, which is now the limit: 1080 multiply-adds per sample (12 half orders,
cos and sin, 9 channels, degree 4 in rpm), 792 on the i3 once its four cancelled orders
lose their rpm dependence (:mod:`acquisition.sim.compact_design`; the compiled path
only). The whole simulator on the stage budget's load (10 channels at 25.6 kHz, 60 s;
``benchmarks/bench_pipeline.py``, ``simulator_alone``): 0.13 s compiled (about 460x),
0.23 s numpy (260x), 0.27 s on main before this work (220x), load 12.

As :mod:`dsp.kernels`, numba is optional and imported on first use only (its import and
the cached machine code cost about 0.5 s of CPU per process), and used only when asked
(``PTINERTIA_NUMBA=1``, the same switch: long runs, campaigns and studies).
"""

from __future__ import annotations

import importlib.util
import math
import os
from collections.abc import Callable
from typing import Any

import numpy as np

from acquisition.sim.amplitude_table import AmplitudeTable
from acquisition.sim.sweep import RPM_TO_RAD_S, RpmProfile

# numba is optional and imported on first use only, as in dsp.kernels
AVAILABLE = importlib.util.find_spec("numba") is not None
# PTINERTIA_NUMBA=1: the simulator uses the kernels; benchmarks and tests switch it per call
USE = AVAILABLE and os.environ.get("PTINERTIA_NUMBA", "0") == "1"
# largest half angle (rad) from an anchor: the Taylor series below is exact to 1e-19 there
MAX_HALF_ANGLE = 0.25
_compiled: dict[str, Callable[..., None]] = {}


def _jit(name: str, func: Callable[..., None]) -> Callable[..., None]:
    if name not in _compiled:
        from numba import njit  # heavy (0.3 s): only where the kernels are used

        _compiled[name] = njit(cache=True, nogil=True)(func)
    return _compiled[name]


def anchor_spacing(omega_max_rad_s: float, rate_hz: float, longest: int = 64) -> int:
    """Samples between anchors: the half angle travelled stays within ``MAX_HALF_ANGLE``."""
    per_sample = 0.5 * omega_max_rad_s / rate_hz  # rad of half angle per sample
    return max(1, min(longest, math.floor(MAX_HALF_ANGLE / per_sample)))


def carriers(
    phi: np.ndarray,
    anchor_phi: np.ndarray,
    offset: int,
    spacing: int,
    position: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`_carriers` then :func:`_powers`, compiled on the first call (numba's cache
    keeps the machine code); ``position``: ``CompactDesign.position``, the row pair of each
    order."""
    _jit("carriers", _carriers)(phi, anchor_phi, offset, spacing, 2 * position[0], out)
    _jit("powers", _powers)(position, out)


def motion(
    profile: RpmProfile, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``profile.evaluate(t)`` (segment, crank angle rad, speed rad/s) and the speed in rpm,
    by :func:`_motion`: the same operations in the same order, so the same bits."""
    n = t.size
    seg = np.empty(n, dtype=np.intp)
    phi, omega, rpm = np.empty(n), np.empty(n), np.empty(n)
    _jit("motion", _motion)(t, *profile.pieces, motion_limits(profile), (seg, phi, omega, rpm))
    return seg, phi, omega, rpm


def motion_limits(profile: RpmProfile) -> np.ndarray:
    """What :func:`_motion` reads beside the profile's pieces: its duration (s), end angle
    (rad) and end speed (rad/s)."""
    w_end = profile.segments[-1].rpm_to * RPM_TO_RAD_S
    return np.array([profile.duration_s, profile.phi_end, w_end])


def locate(table: AmplitudeTable, segment: int, rpm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``table.locate(segment, rpm)`` (interval index, normalised rpm) by :func:`_locate`."""
    j = np.empty(rpm.size, dtype=np.intp)
    u = np.empty(rpm.size)
    _jit("locate", _locate)(rpm, *table.intervals(segment), j, u)
    return j, u


def pressure(pieces: tuple[Any, ...], phi: np.ndarray) -> np.ndarray:
    """A pressure cycle's spline (``powertrain.gas.PressureCycle.pieces``) at the crank
    angles ``phi`` (rad), Pa, by :func:`_spline`: its ``__call__``'s arithmetic, so its bits."""
    out = np.empty(phi.size)
    cycle = 4.0 * np.pi
    cycle_hi = float(np.float32(cycle))  # 24 significant bits: q * cycle_hi is exact
    _jit("spline", _spline)(phi, cycle, cycle_hi, cycle - cycle_hi, *pieces, out)
    return out


def _spline(
    phi: np.ndarray,
    cycle: float,
    cycle_hi: float,
    cycle_lo: float,
    grid: np.ndarray,
    per_rad: float,
    c0: np.ndarray,
    c1: np.ndarray,
    c2: np.ndarray,
    c3: np.ndarray,
    out: np.ndarray,
) -> None:
    """The periodic cubic of ``PressureCycle.__call__`` at the angles ``phi`` (rad).

    Its ``np.mod(phi, cycle)`` exactly, without libm's ``fmod`` (6 ns a call, as much as
    the rest): the remainder ``phi - q cycle`` is a double (fmod is exact), and with
    ``cycle = cycle_hi + cycle_lo`` (24 and 29 significant bits) both products with an
    integer ``q < 2^24`` are exact, ``phi - q cycle_hi`` is too (the difference of two
    doubles needing no more than 53 bits), and so is the last subtraction, whose exact
    value is the remainder itself. A negative angle (or one past 2^24 cycles) takes
    Python's ``%``, which is numpy's ``mod``.
    """
    last = grid.size - 2
    for s in range(phi.size):
        x = phi[s]
        q = math.floor(x / cycle)
        if x >= 0.0 and q < 16777216.0:
            r = (x - q * cycle_hi) - q * cycle_lo
            if r < 0.0:  # the quotient rounded up
                q -= 1.0
                r = (x - q * cycle_hi) - q * cycle_lo
            elif r >= cycle:
                q += 1.0
                r = (x - q * cycle_hi) - q * cycle_lo
            x = r
        else:
            x = x % cycle
        i = min(int(x * per_rad), last)
        if x < grid[i]:
            i -= 1
        if x >= grid[i + 1] and i < last:
            i += 1
        d = x - grid[i]
        z = d
        v = c3[i] + c2[i] * z
        z = z * d
        v = v + c1[i] * z
        z = z * d
        out[s] = v + c0[i] * z


def _motion(
    t: np.ndarray,
    t_start: np.ndarray,
    phi_start: np.ndarray,
    w0: np.ndarray,
    acc: np.ndarray,
    limits: np.ndarray,
    out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
) -> None:
    """:meth:`RpmProfile.evaluate`'s arithmetic sample by sample (``limits``: duration s,
    end angle rad, end speed rad/s), and the rpm as the synthesis takes it."""
    seg, phi, omega, rpm = out
    n_seg = t_start.size
    duration, phi_end, w_end = limits[0], limits[1], limits[2]
    to_rpm = 60.0 / (2.0 * math.pi)
    k = 0
    for s in range(t.size):
        ts = t[s]
        # the last segment starting at or before ts (searchsorted 'right' - 1, clipped)
        while k < n_seg - 1 and t_start[k + 1] <= ts:
            k += 1
        while k > 0 and t_start[k] > ts:
            k -= 1
        tau = ts - t_start[k]
        w = w0[k]
        a = acc[k]
        ref = phi_start[k]
        if ts < 0.0:  # before the start the speed holds
            a = 0.0
        elif ts > duration:  # after the end too, from the end's angle
            a = 0.0
            w = w_end
            tau = ts - duration
            ref = phi_end
        seg[s] = k
        phi[s] = ref + tau * (w + 0.5 * a * tau)
        omega[s] = w + a * tau
        rpm[s] = omega[s] * to_rpm


def _locate(
    rpm: np.ndarray,
    edges: np.ndarray,
    centre: np.ndarray,
    inv_half: np.ndarray,
    j_out: np.ndarray,
    u_out: np.ndarray,
) -> None:
    """:meth:`AmplitudeTable.locate`'s interval (the last edge at or below the rpm, clipped
    to the intervals) found by walking from the previous sample's, and its ``u``."""
    last = edges.size - 2
    j = 0
    for s in range(rpm.size):
        r = rpm[s]
        while j < last and edges[j + 1] <= r:
            j += 1
        while j > 0 and edges[j] > r:
            j -= 1
        j_out[s] = j
        u_out[s] = (r - centre[j]) * inv_half[j]


def _carriers(
    phi: np.ndarray, anchor_phi: np.ndarray, offset: int, spacing: int, row: int, out: np.ndarray
) -> None:
    """Rows ``row``, ``row + 1`` of ``out`` (2 n_o, n): ``cos(phi / 2)``, ``sin(phi / 2)``.

    ``phi`` (n,) rad the samples' crank angles; sample ``s`` takes anchor
    ``(offset + s) // spacing`` of ``anchor_phi`` (rad), whose half angle must lie
    within ``MAX_HALF_ANGLE`` of the sample's.
    """
    n = phi.size
    # the anchors' exact carriers first, then every sample from its anchor in one flat loop
    m = anchor_phi.size
    ac = np.empty(m)
    asn = np.empty(m)
    for j in range(m):
        ac[j] = math.cos(0.5 * anchor_phi[j])
        asn[j] = math.sin(0.5 * anchor_phi[j])
    for s in range(n):
        j = (offset + s) // spacing
        d = 0.5 * (phi[s] - anchor_phi[j])
        d2 = d * d
        # Taylor series of cos d and sin d to d^14 and d^15 (|d| <= 1/4: the rest < 1e-19)
        c = 1.0 + d2 * (-1.0 / 2 + d2 * (1.0 / 24 + d2 * (-1.0 / 720 + d2 * (
            1.0 / 40320 + d2 * (-1.0 / 3628800 + d2 * (1.0 / 479001600 + d2 * (
                -1.0 / 87178291200)))))))  # fmt: skip
        sn = d * (1.0 + d2 * (-1.0 / 6 + d2 * (1.0 / 120 + d2 * (-1.0 / 5040 + d2 * (
            1.0 / 362880 + d2 * (-1.0 / 39916800 + d2 * (1.0 / 6227020800 + d2 * (
                -1.0 / 1307674368000))))))))  # fmt: skip
        out[row, s] = ac[j] * c - asn[j] * sn
        out[row + 1, s] = ac[j] * sn + asn[j] * c


def _powers(position: np.ndarray, out: np.ndarray) -> None:
    """The carrier of order ``k + 1`` (half orders) in rows ``2 position[k]`` and the next
    of ``out`` (2 n_o, n), from order 1's (``position[0]``) by the running product.

    A row at a time (contiguous; indexing the one array, not row views of it, and a kernel
    of its own let LLVM vectorise: measured 2.7x faster).
    """
    n = out.shape[1]
    b = 2 * position[0]
    for k in range(1, position.size):
        p = 2 * position[k - 1]
        q = 2 * position[k]
        for s in range(n):
            # every load before the stores (else each store forces a reload)
            pr = out[p, s]
            pi = out[p + 1, s]
            br = out[b, s]
            bi = out[b + 1, s]
            out[q, s] = pr * br - pi * bi
            out[q + 1, s] = pr * bi + pi * br
