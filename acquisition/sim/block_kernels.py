"""The compiled synthesis of a run of samples in one sweep segment, in one call that holds no GIL.

:func:`acquisition.sim.synthesis.synthesize_accel` on the compiled path multiplies, per
table interval and chunk of :data:`CHUNK` samples, the interval's coefficients with the
carriers (BLAS), then sums the product's rows in the normalised rpm ``u`` by Horner. Done
from Python, each chunk was three calls, each releasing the GIL and taking it back: about
45 a block of 0.5 s, 5400 a minute of the i3 at 25.6 kHz. In a live run the simulator's
thread shares the GIL with the processing thread, which holds it for most of its time, and
every one of those calls meant waiting for it again (a convoy). Measured on 2026-11-26 (the
60 s compiled live run with recording, best of 3, twice, quiet machine): 0.52-0.57 s of wall
time, against 0.31-0.35 s with the simulator's items made before the run; the processing
thread's CPU 0.36-0.39 s against 0.28-0.32 s.

:func:`block_accel` runs the loop over intervals and chunks in one compiled call (the
product by ``np.dot``, which numba hands to the BLAS that scipy ships, on a contiguous copy
of the chunk's carriers; the Horner sums as before). numba's ``dgemm`` is scipy's OpenBLAS
(0.3.30 here), not numpy's (0.3.31): the same operands, transposes and sizes, and with one
BLAS thread the same bits (tested in a process with ``OPENBLAS_NUM_THREADS=1``, as the CLI,
the benchmarks and the Dask workers it starts run, ``ptinertia/cli.py``). With more threads
scipy's OpenBLAS splits a large product its own way, and the samples move at the rounding
level (3.6e-15 m/s^2 seen on one channel of the i3): within the compiled path's contract
(1e-13 of each channel's rms against the numpy path; tested whatever the thread count), as
a run on another CPU's BLAS kernels would. That took the live run to 0.435-0.475 s against
0.605-0.68 s before (two rounds interleaved).

:func:`accel_block` goes further for a block of the simulated bench: the times, the sweep's
motion, the anchors' angles and the carriers in one call, then the intervals and the
products in one call per sweep segment (:mod:`acquisition.sim.kernels`' arithmetic, called
from here: the same bits, tested). The accelerations' GIL releases fall from about 45 a
block to 2. Live run, three rounds interleaved with the build before this module (c2bcbc1),
best of 3: 0.465-0.468 s (128-129x) -> 0.345-0.388 s (155-174x); the simulator's thread
0.20-0.25 -> 0.17-0.21 s of CPU, the processing thread 0.31-0.39 -> 0.28-0.35 s.
"""

from __future__ import annotations

import hashlib
import math
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.sim import kernels
from acquisition.sim.amplitude_table import AmplitudeTable
from acquisition.sim.sweep import RpmProfile

CHUNK = 1024  # samples per product: keeps the operands in cache (~1.5x faster than 2560)
# numba's cache checks only this file's time stamp and size; the fused kernels call the
# motion, carriers and interval kernels of these files: their sha256, renewed with them,
# changes this file and so rebuilds the cache (tests/acquisition/sim/test_synthesis_kernels.py)
HELPERS = ("kernels.py",)
HELPERS_SHA256 = "d530c8b1463c0f6a998531ab9c21db531511b5e310e40dc2931d7822c45977f7"
_compiled: dict[str, Callable[..., Any]] = {}
_compiling = threading.Lock()


def accel_block(
    table: AmplitudeTable, profile: RpmProfile, rate_hz: float, i0: int, i1: int, spacing: int
) -> tuple[np.ndarray, ...]:
    """Samples ``i0 .. i1 - 1`` at ``rate_hz`` of the compiled accelerations, in two calls
    that hold no GIL (one for the block, one per sweep segment it spans): times (s),
    segments, crank angles (rad), speeds (rad/s) and the accelerations (n_ch, n), m/s^2.

    The same arithmetic as :meth:`SimulatedBench._motion` (``kernels.motion``), the
    anchors every ``spacing`` samples, :func:`kernels.carriers` and
    :func:`acquisition.sim.synthesis.synthesize_accel` on the compiled path: the same bits.
    """
    _compile()
    n = max(0, i1 - i0)  # (as np.arange(i0, i1): none for i1 <= i0)
    design = table.compact  # the orders with an rpm dependence first
    seg = np.empty(n, dtype=np.intp)
    t, phi, omega, rpm = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    rows = np.empty((2 * table.orders.size, n))
    _compiled["motion"](
        i0,
        rate_hz,
        spacing,
        *profile.pieces,
        kernels.motion_limits(profile),
        design.position,
        (seg, t, phi, omega, rpm),
        rows,
    )
    return t, seg, phi, omega, segments_accel(table, seg, rpm, rows)


def segments_accel(
    table: AmplitudeTable, seg: np.ndarray, rpm: np.ndarray, rows: np.ndarray
) -> np.ndarray:
    """The accelerations (n_ch, n), m/s^2, of samples in sweep segments ``seg`` (n,
    non-decreasing) at ``rpm`` (n,), from their carriers ``rows`` (2 n_o, n) laid out as
    ``table.compact`` reads them: the intervals and products in one call per segment."""
    _compile()
    design = table.compact
    n = seg.size
    out = np.empty((table.coeffs[0].shape[3], n))
    if n:
        starts = [0] if seg[0] == seg[-1] else [0, *(np.flatnonzero(np.diff(seg)) + 1).tolist()]
        for a0, b0 in zip(starts, [*starts[1:], n], strict=True):
            s = int(seg[a0])
            n_rows = design.constant[s].shape[1] + design.varying[s].shape[1]
            _compiled["segment"](
                rpm[a0:b0], *table.intervals(s), rows, a0, design.constant[s],
                design.varying[s], 2 * design.n_kept, np.empty(n_rows * CHUNK), out,
            )  # fmt: skip
    return out


def edge_times(
    profile: RpmProfile, angles_rad: np.ndarray, period_rad: float, t_a: float, t_b: float
) -> np.ndarray:
    """Times (s) of the edges at ``angles_rad`` (mod ``period_rad``, rad of crank angle)
    with ``t_a <= t < t_b`` (s): :func:`acquisition.sim.tacho_synth.edge_times` in one call
    that holds no GIL (its numpy steps held it for most of what was left of the simulator's
    GIL time in a live run): the same arithmetic, so the same edge times (tested)."""
    _compile()
    if not t_b > t_a:  # an empty window: no edge (as the numpy path's selection)
        return np.empty(0)
    angles = np.ascontiguousarray(angles_rad, dtype=float)
    limits = kernels.motion_limits(profile)
    return _compiled["edges"](t_a, t_b, angles, float(period_rad), *profile.pieces, limits)


def _compile() -> None:
    """Compile (or load from numba's cache) every kernel here, once per process: the
    entries appear together, so a thread never finds some and misses others."""
    if _compiled:
        return
    with _compiling:
        if _compiled:
            return
        from numba import njit  # heavy (0.3 s): only where the kernels are used

        global _motion_c, _carriers_c, _powers_c, _locate_c, _block_c, _horner_c
        # the same options as acquisition.sim.kernels._jit: the two dispatchers of a kernel
        # there share one cache entry, whose key holds no options
        jit = njit(cache=True, nogil=True)
        _motion_c, _carriers_c = jit(kernels._motion), jit(kernels._carriers)
        _powers_c, _locate_c = jit(kernels._powers), jit(kernels._locate)
        _horner_c = jit(_horner)
        _block_c = jit(_block_accel)
        _compiled.update(
            block=_block_c,
            segment=jit(_segment_accel),
            motion=jit(_block_motion),
            edges=jit(_edge_times),
        )


def helpers_sha256() -> str:
    """The sha256 :data:`HELPERS_SHA256` must hold (the helpers' names and bytes)."""
    digest = hashlib.sha256()
    for helper in HELPERS:
        digest.update(helper.encode() + b"\0" + (Path(__file__).parent / helper).read_bytes())
    return digest.hexdigest()


def block_accel(
    rows: np.ndarray,
    first: int,
    j: np.ndarray,
    u: np.ndarray,
    constant: np.ndarray,
    varying: np.ndarray,
    kept: int,
    out: np.ndarray,
) -> None:
    """Accelerations of samples ``first .. first + j.size`` into ``out`` (n_ch, n), m/s^2:
    the compiled loop over one segment's intervals and chunks, given the intervals (the
    simulator calls it with them found in the same call, :func:`segments_accel`).

    ``rows`` (2 n_o, n): the carriers (:func:`acquisition.sim.kernels.carriers`); ``j``,
    ``u``: the samples' table interval and normalised rpm (:func:`kernels.locate`) in one
    segment, whose :class:`~acquisition.sim.compact_design.CompactDesign` operands are
    ``constant`` (n_int, n_ch, 2 n_o) and ``varying`` (n_int, degree n_ch, ``kept``).
    """
    _compile()
    n_rows = constant.shape[1] + varying.shape[1]
    y = np.empty(n_rows * CHUNK)
    _compiled["block"](rows, first, j, u, constant, varying, kept, y, out)


def _block_accel(
    rows: np.ndarray,
    first: int,
    j: np.ndarray,
    u: np.ndarray,
    constant: np.ndarray,
    varying: np.ndarray,
    kept: int,
    y: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`block_accel`'s loop; ``y``: room for ``n_k n_ch`` rows of :data:`CHUNK`."""
    n = j.size
    n_ch = constant.shape[1]
    n_var = varying.shape[1]
    a = 0
    while a < n:
        b = a + 1
        while b < n and j[b] == j[a]:
            b += 1
        d0 = constant[j[a]]
        dk = varying[j[a]]
        for c0 in range(a, b, CHUNK):
            m = min(b, c0 + CHUNK) - c0
            s0 = first + c0
            yk = y[: (n_ch + n_var) * m].reshape(n_ch + n_var, m)
            np.dot(d0, np.ascontiguousarray(rows[:, s0 : s0 + m]), yk[:n_ch])
            if n_var:
                np.dot(dk, np.ascontiguousarray(rows[:kept, s0 : s0 + m]), yk[n_ch:])
            _horner_c(yk, u[c0 : c0 + m], out, s0)
        a = b


def _block_motion(
    i0: int,
    rate_hz: float,
    spacing: int,
    t_start: np.ndarray,
    phi_start: np.ndarray,
    w0: np.ndarray,
    acc: np.ndarray,
    limits: np.ndarray,
    position: np.ndarray,
    out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    rows: np.ndarray,
) -> None:
    """:func:`accel_block`'s first call: into ``out`` the times (s), segments, crank angles
    (rad), speeds (rad/s) and rpm of samples ``i0 ..`` at ``rate_hz``; into ``rows`` their
    carriers, from the angles of anchors every ``spacing`` samples."""
    seg, t, phi, omega, rpm = out
    n = t.size
    for s in range(n):
        t[s] = (i0 + s) / rate_hz  # (np.arange(i0, i1) / rate_hz)
    _motion_c(t, t_start, phi_start, w0, acc, limits, (seg, phi, omega, rpm))
    a0 = i0 - i0 % spacing
    n_anchor = (i0 + n - a0 + spacing - 1) // spacing
    at = np.empty(n_anchor)
    for k in range(n_anchor):
        at[k] = (a0 + k * spacing) / rate_hz  # (np.arange(a0, i1, spacing) / rate_hz)
    a_seg = np.empty(n_anchor, dtype=np.intp)
    a_phi, a_omega, a_rpm = np.empty(n_anchor), np.empty(n_anchor), np.empty(n_anchor)
    _motion_c(at, t_start, phi_start, w0, acc, limits, (a_seg, a_phi, a_omega, a_rpm))
    _carriers_c(phi, a_phi, i0 - a0, spacing, 2 * position[0], rows)
    _powers_c(position, rows)


def _segment_accel(
    rpm: np.ndarray,
    edges: np.ndarray,
    centre: np.ndarray,
    inv_half: np.ndarray,
    rows: np.ndarray,
    first: int,
    constant: np.ndarray,
    varying: np.ndarray,
    kept: int,
    y: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`accel_block`'s call per segment: the intervals, then :func:`_block_accel`."""
    j = np.empty(rpm.size, dtype=np.intp)
    u = np.empty(rpm.size)
    _locate_c(rpm, edges, centre, inv_half, j, u)
    _block_c(rows, first, j, u, constant, varying, kept, y, out)


def _edge_times(
    t_a: float,
    t_b: float,
    angles: np.ndarray,
    period: float,
    t_start: np.ndarray,
    phi_start: np.ndarray,
    w0: np.ndarray,
    acc: np.ndarray,
    limits: np.ndarray,
) -> np.ndarray:
    """:func:`edge_times`: ``tacho_synth.angles_between`` and ``RpmProfile.t_of_phi``
    operation for operation."""
    ends = np.empty(2)
    ends[0], ends[1] = t_a, t_b
    seg = np.empty(2, dtype=np.intp)
    ph, om, rp = np.empty(2), np.empty(2), np.empty(2)
    _motion_c(ends, t_start, phi_start, w0, acc, limits, (seg, ph, om, rp))
    margin = 1e-9 * max(1.0, abs(ph[1]))
    lo, hi = ph[0] - margin, ph[1] + margin
    m0 = math.floor(lo / period) - 1
    m1 = math.floor(hi / period) + 2
    cand = np.empty((m1 - m0) * angles.size)
    n = 0
    for m in range(m0, m1):
        for a in angles:
            v = m * period + a
            if v >= lo and v < hi:
                cand[n] = v
                n += 1
    phi = np.sort(cand[:n])
    duration, phi_end, w_end = limits[0], limits[1], limits[2]
    last = t_start.size - 1
    out = np.empty(n)
    kept = 0
    for i in range(n):
        p = phi[i]
        k = -1  # searchsorted(phi_start, p, "right") - 1, clipped
        while k < last and phi_start[k + 1] <= p:
            k += 1
        k = max(k, 0)
        after = p > phi_end
        if after:
            dphi, w, a, t0 = p - phi_end, w_end, 0.0, duration
        else:
            dphi, w, a, t0 = p - phi_start[k], w0[k], acc[k], t_start[k]
            if p < phi_start[0]:
                a = 0.0
        x = w * w + 2.0 * a * dphi
        disc = x if x >= 0.0 else 0.0  # (np.maximum(x, 0.0))
        t = t0 + 2.0 * dphi / (w + math.sqrt(disc))
        if t >= t_a and t < t_b:
            out[kept] = t
            kept += 1
    return out[:kept].copy()


def _horner(y: np.ndarray, u: np.ndarray, out: np.ndarray, first: int) -> None:
    """``out[c, first + s] = sum_k y[k n_ch + c, s] u[s]^k`` by Horner, highest ``k`` first.

    ``y`` (n_k n_ch, n) the product's rows (power ``k`` of channel ``c`` in row
    ``k n_ch + c``), ``u`` (n,), ``out`` (n_ch, >= first + n).
    """
    n_ch = out.shape[0]
    n_k = y.shape[0] // n_ch
    n = y.shape[1]
    for c in range(n_ch):
        if n_k == 5:  # the table's default degree, the sum in registers: one pass
            y0 = y[c]
            y1 = y[n_ch + c]
            y2 = y[2 * n_ch + c]
            y3 = y[3 * n_ch + c]
            y4 = y[4 * n_ch + c]
            for s in range(n):
                us = u[s]
                out[c, first + s] = (((y4[s] * us + y3[s]) * us + y2[s]) * us + y1[s]) * us + y0[s]
            continue
        top = y[(n_k - 1) * n_ch + c]
        for s in range(n):
            out[c, first + s] = top[s]
        for k in range(n_k - 2, -1, -1):
            yk = y[k * n_ch + c]
            for s in range(n):
                out[c, first + s] = out[c, first + s] * u[s] + yk[s]


# the compiled kernels the others call, set by _compile
_horner_c: Any = None
_motion_c: Any = None
_carriers_c: Any = None
_powers_c: Any = None
_locate_c: Any = None
_block_c: Any = None
