"""Crank angle and speed at any time, from the knots of the wheel decoder.

Between knots ``j`` and ``j + 1`` the angle is the cubic through the four
knots ``j - 1 .. j + 2`` (local Lagrange interpolation of ``phi(t)``). Why this
form:

* it is exact for a cubic ``phi(t)``, so for the constant-acceleration sweeps
  of a test bench (``phi`` quadratic) it adds no error at all; for a real
  crank with firing-frequency speed ripple the error is that of a 4-point
  interpolation over 6 deg teeth, far below the tooth-timing jitter;
* it is local: the angle at a sample depends on four knots only, so it can be
  evaluated as soon as the knot two teeth ahead has been committed (a streaming
  latency of about three teeth), and identically whatever the block cut;
* ``dphi/dt`` of the same cubic gives the angular speed used as the Jacobian of
  the angle-domain integral.

An interval is only formed from knots of one synchronised *run*; samples that
fall between runs (the unsynchronised stretch after a missed edge) get no angle.

The table is a frozen dataclass of arrays (never modified in place), advanced
by pure functions: :func:`add_knots`, :func:`trim`, :func:`lookup`, :func:`time_at`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, fields

import numpy as np

from dsp import kernels
from dsp.immutable import evolve


def _f() -> np.ndarray:
    return np.empty(0)


def _i() -> np.ndarray:
    return np.empty(0, dtype=np.int64)


@dataclass(frozen=True)
class AngleTable:
    """Cubic pieces of ``phi(t)``, one per knot interval, in time order.

    Attributes
    ----------
    t_lo, t_hi : (k,) float64, s
        Interval ends (``t_hi[j] == t_lo[j + 1]`` inside a run).
    phi_lo, phi_hi : (k,) float64, rad
        Crank angle at the ends.
    c1, c2, c3 : (k,) float64
        ``phi(t) = phi_lo + c1 tau + c2 tau^2 + c3 tau^3``, ``tau = t - t_lo`` (rad/s^k).
    run : (k,) int64
        Run id of each interval.
    tail_t, tail_phi, tail_run : (<=3,) arrays
        Last knots of the newest run, waiting for the knots that complete
        their stencils.
    """

    t_lo: np.ndarray = field(default_factory=_f)
    t_hi: np.ndarray = field(default_factory=_f)
    phi_lo: np.ndarray = field(default_factory=_f)
    phi_hi: np.ndarray = field(default_factory=_f)
    c1: np.ndarray = field(default_factory=_f)
    c2: np.ndarray = field(default_factory=_f)
    c3: np.ndarray = field(default_factory=_f)
    run: np.ndarray = field(default_factory=_i)
    tail_t: np.ndarray = field(default_factory=_f)
    tail_phi: np.ndarray = field(default_factory=_f)
    tail_run: np.ndarray = field(default_factory=_i)

    @property
    def t_end(self) -> float:
        """End of the newest interval (s); -inf when empty. Samples before it can be resolved."""
        return float(self.t_hi[-1]) if self.t_hi.size else -np.inf


def cubic_pieces(t: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, ...]:
    """Monomial coefficients of the cubics through knots ``j-1 .. j+2`` for ``j = 1 .. k-3``.

    Parameters
    ----------
    t, phi : (k,) float64
        Knot times (s, increasing) and angles (rad), ``k >= 4``.

    Returns
    -------
    c1, c2, c3 : (k-3,) float64
        Coefficients in ``tau = t - t[j]`` of the piece on ``[t[j], t[j+1]]``.
    """
    # Newton divided differences on the nodes z0 = t_j, z1 = t_j+1, z2 = t_j-1, z3 = t_j+2,
    # in local coordinates (relative to t_j and phi_j) to avoid cancellation at hour-long times.
    # knots j-1, j, j+1, j+2 for j = 1 .. k-3, as slices
    t_m, t_j, t_p, t_pp = t[:-3], t[1:-2], t[2:-1], t[3:]
    p_m, p_j, p_p, p_pp = phi[:-3], phi[1:-2], phi[2:-1], phi[3:]
    z1 = t_p - t_j
    z2 = t_m - t_j
    z3 = t_pp - t_j
    y1 = p_p - p_j
    y2 = p_m - p_j
    y3 = p_pp - p_j
    f01 = y1 / z1
    f02 = y2 / z2
    f03 = y3 / z3
    f012 = (f02 - f01) / (z2 - z1)
    f013 = (f03 - f01) / (z3 - z1)
    f0123 = (f013 - f012) / (z3 - z2)
    # p(tau) = f01 tau + f012 tau (tau - z1) + f0123 tau (tau - z1)(tau - z2)
    c3 = f0123
    c2 = f012 - f0123 * (z1 + z2)
    c1 = f01 - f012 * z1 + f0123 * z1 * z2
    return c1, c2, c3


# the table's fields in order: its columns, then its tail
_COLUMNS = tuple(f.name for f in fields(AngleTable))


def add_knots(table: AngleTable, t: np.ndarray, phi: np.ndarray, run: np.ndarray) -> AngleTable:
    """Append committed knots; form every interval whose 4-knot stencil lies in one run."""
    if t.size == 0:
        return table
    if kernels.USE:
        # one compiled pass, the same bits (dsp.angle_loops.append_knots)
        columns = kernels.append_knots(
            table.t_lo, table.t_hi, table.phi_lo, table.phi_hi, table.c1, table.c2, table.c3,
            table.run, table.tail_t, table.tail_phi, table.tail_run, t, phi, run,
        )  # fmt: skip
        return evolve(table, **dict(zip(_COLUMNS, columns, strict=True)))
    kt = np.concatenate((table.tail_t, t))
    kp = np.concatenate((table.tail_phi, phi))
    kr = np.concatenate((table.tail_run, run))
    parts: list[tuple[np.ndarray, ...]] = []
    # split at run changes; each run's knots make intervals 1 .. k-3
    cuts = np.flatnonzero(np.diff(kr)) + 1
    bounds = np.concatenate(([0], cuts, [kt.size]))
    for a, b in itertools.pairwise(bounds):
        if b - a >= 4:
            st, sp = kt[a:b], kp[a:b]
            c1, c2, c3 = cubic_pieces(st, sp)
            # intervals j = 1 .. k-3 of the run: from knot j to knot j + 1
            parts.append((st[1:-2], st[2:-1], sp[1:-2], sp[2:-1], c1, c2, c3, kr[a + 1 : b - 2]))
    a = bounds[-2]
    tail = slice(max(a, kt.size - 3), kt.size)
    new = evolve(table, tail_t=kt[tail], tail_phi=kp[tail], tail_run=kr[tail])
    if not parts:
        return new
    cols = list(zip(*parts, strict=True))
    names = ("t_lo", "t_hi", "phi_lo", "phi_hi", "c1", "c2", "c3", "run")
    return evolve(
        new,
        **{
            name: np.concatenate((getattr(table, name), *col))
            for name, col in zip(names, cols, strict=True)
        },
    )


def trim(table: AngleTable, t_keep: float) -> AngleTable:
    """Drop intervals that end before ``t_keep`` (s); keeps memory flat on long streams."""
    k = int(table.t_hi.searchsorted(t_keep, side="left"))
    if k == 0:
        return table
    names = ("t_lo", "t_hi", "phi_lo", "phi_hi", "c1", "c2", "c3", "run")
    return evolve(table, **{name: getattr(table, name)[k:] for name in names})


def lookup(
    table: AngleTable, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Angle and angular speed at times ``t``.

    Parameters
    ----------
    t : (n,) float64, s, increasing, all ``< table.t_end``

    Returns
    -------
    ok : (n,) bool
        False where ``t`` lies outside every interval (before the first
        knot, or in an unsynchronised stretch between runs).
    phi : (n,) float64, rad
    omega : (n,) float64, rad/s
    run : (n,) int64
    """
    n = t.size
    if not table.t_lo.size or n == 0 or t[-1] < table.t_lo[0]:
        z = np.zeros(n)
        return np.zeros(n, bool), z, z, np.zeros(n, dtype=np.int64)
    # both sides are sorted: place the (fewer) knots among the samples, then repeat each
    # piece's coefficients over its samples (2x faster than a search per sample)
    i0 = max(int(table.t_lo.searchsorted(t[0], side="right")) - 1, 0)
    i1 = int(table.t_lo.searchsorted(t[-1], side="right"))
    sl = slice(i0, i1)
    pos = t.searchsorted(table.t_lo[sl], side="left")
    head = int(pos[0])  # samples before the first piece
    counts = np.diff(np.append(pos, n))
    tt = t[head:]
    if kernels.USE:
        # one pass, no repeated coefficients: the same bits (dsp.kernels.cubic_values)
        phi, omega = np.empty(tt.size), np.empty(tt.size)
        kernels.cubic_values(
            tt, counts, table.t_lo[sl], table.phi_lo[sl], table.c1[sl], table.c2[sl],
            table.c3[sl], phi, omega,
        )  # fmt: skip
    else:
        tau = tt - np.repeat(table.t_lo[sl], counts)
        c1 = np.repeat(table.c1[sl], counts)
        c2 = np.repeat(table.c2[sl], counts)
        c3 = np.repeat(table.c3[sl], counts)
        phi = tau * c3
        phi += c2
        phi *= tau
        phi += c1
        phi *= tau
        phi += np.repeat(table.phi_lo[sl], counts)
        omega = tau * (3.0 * c3)
        omega += 2.0 * c2
        omega *= tau
        omega += c1
    if table.run[i0] == table.run[i1 - 1] and tt[-1] < table.t_hi[i1 - 1]:
        # the pieces of one run follow each other: every sample lies inside one
        ok = np.ones(tt.size, bool)
        run = np.full(tt.size, table.run[i0])
    else:
        ok = tt < np.repeat(table.t_hi[sl], counts)
        run = np.repeat(table.run[sl], counts)
    if head:
        pad = np.zeros(head)
        return (
            np.concatenate((np.zeros(head, bool), ok)),
            np.concatenate((pad, phi)),
            np.concatenate((pad, omega)),
            np.concatenate((np.zeros(head, dtype=np.int64), run)),
        )
    return ok, phi, omega, run


def lookup_grid(
    table: AngleTable, t0_s: float, rate_hz: float, idx: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The times ``t0_s + k / rate_hz`` (s) of consecutive grid indices ``idx`` (n,) int64
    and their :func:`lookup` (all before ``table.t_end``): ``t, ok, phi, omega, run`` (n,).
    Compiled (:data:`dsp.kernels.USE`): one pass over samples and pieces together
    (:func:`dsp.kernels.grid_values`), the same bits."""
    if not kernels.USE:
        t = t0_s + idx / rate_hz
        return (t, *lookup(table, t))
    n = idx.size
    t, phi, omega = np.empty(n), np.empty(n), np.empty(n)
    ok, run = np.empty(n, bool), np.empty(n, np.int64)
    kernels.grid_values(
        t0_s, rate_hz, int(idx[0]) if n else 0, table.t_lo, table.t_hi, table.phi_lo,
        table.c1, table.c2, table.c3, table.run, t, ok, phi, omega, run,
    )  # fmt: skip
    return t, ok, phi, omega, run


def time_at(table: AngleTable, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Time (s) and angular speed (rad/s) at which the crank reaches ``phi`` (rad).

    NaN where ``phi`` is not inside an interval of the table. Newton on the
    interval's cubic from the linear guess; the cubic is monotonic over a
    tooth, three steps reach rounding level.
    """
    phi = np.atleast_1d(np.asarray(phi, dtype=float))
    if not table.t_lo.size:
        nan = np.full(phi.shape, np.nan)
        return nan, nan
    if kernels.USE:
        t, omega = np.empty(phi.size), np.empty(phi.size)
        kernels.cubic_times(
            phi, table.t_lo, table.t_hi, table.phi_lo, table.phi_hi, table.c1, table.c2,
            table.c3, t, omega,
        )  # fmt: skip
        return t.reshape(phi.shape), omega.reshape(phi.shape)
    j = np.searchsorted(table.phi_lo, phi, side="right") - 1
    jj = np.maximum(j, 0)
    phi_lo, phi_hi, t_lo = table.phi_lo[jj], table.phi_hi[jj], table.t_lo[jj]
    ok = (j >= 0) & (phi <= phi_hi)
    target = phi - phi_lo
    c1, c2, c3 = table.c1[jj], table.c2[jj], table.c3[jj]
    c2_2 = 2.0 * c2
    tau = target / (phi_hi - phi_lo) * (table.t_hi[jj] - t_lo)
    for _ in range(4):
        f = tau * (c1 + tau * (c2 + tau * c3)) - target
        fp = c1 + tau * (c2_2 + 3.0 * tau * c3)
        tau -= f / fp
    omega = c1 + tau * (c2_2 + 3.0 * tau * c3)
    return np.where(ok, t_lo + tau, np.nan), np.where(ok, omega, np.nan)


def angle_at_one(table: AngleTable, t: float) -> float:
    """:func:`lookup`'s angle at one time (rad), NaN where it gives ``ok`` False: the same
    arithmetic in Python floats (the same bits), without its array operations."""
    j = int(table.t_lo.searchsorted(t, side="right")) - 1  # (the method: no wrapper calls)
    if j < 0 or not t < float(table.t_hi[j]):
        return math.nan
    tau = t - float(table.t_lo[j])
    c1, c2, c3 = float(table.c1[j]), float(table.c2[j]), float(table.c3[j])
    return ((tau * c3 + c2) * tau + c1) * tau + float(table.phi_lo[j])


def time_at_one(table: AngleTable, phi: float) -> float:
    """:func:`time_at` of one angle (s), NaN outside the table: the same arithmetic in
    Python floats, without the fixed cost of some thirty array operations."""
    if not table.t_lo.size:
        return math.nan
    j = int(table.phi_lo.searchsorted(phi, side="right")) - 1
    if j < 0 or not phi <= float(table.phi_hi[j]):
        return math.nan
    t_lo, t_hi = float(table.t_lo[j]), float(table.t_hi[j])
    phi_lo, phi_hi = float(table.phi_lo[j]), float(table.phi_hi[j])
    c1, c2, c3 = float(table.c1[j]), float(table.c2[j]), float(table.c3[j])
    target = phi - phi_lo
    tau = target / (phi_hi - phi_lo) * (t_hi - t_lo)
    for _ in range(4):
        f = tau * (c1 + tau * (c2 + tau * c3)) - target
        fp = c1 + tau * (2.0 * c2 + 3.0 * tau * c3)
        tau = tau - f / fp
    return t_lo + tau
