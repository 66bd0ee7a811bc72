"""The simulated bench: a :class:`~acquisition.stream.Source` synthesised from a bench model.

Signals (``phi``, ``rpm`` from :class:`~acquisition.sim.sweep.RpmProfile`):

* accelerations ``x_c(t) = sum_h Re{X_hc(rpm(t)) exp(i h phi(t))}`` over the
  half orders ``0.5 .. max_order``, ``X`` from the model (m/s^2);
* cylinder-1 pressure (bar) when ``tacho.phase_reference == "pressure"``;
* the rpm channel (exact instantaneous rpm) at ``tacho.rpm_rate_hz``;
* the tacho (and cam) as edge timestamps or as a sampled square wave
  (:mod:`acquisition.sim.tacho_synth`).

The model is slow compared with the sample rate, so ``X(rpm)`` is tabulated
once per sweep segment (:class:`AmplitudeTable`): piecewise polynomials in rpm
on adaptively bisected intervals, each accepted only when it matches the model
to ``rtol`` (default 1e-10) at check points between its Chebyshev nodes. A
block then costs one real matmul per interval it crosses; a hold is exact.

Noise: white, per channel, ``std_c = rms_c / 10^(snr_db / 20)`` with ``rms_c``
the rms of channel ``c``'s noise-free signal over the whole sweep (that is the
definition ``SNR = 20 log10(rms signal / noise std)``); each channel draws from
its own generator seeded from ``seed``, so the samples do not depend on how
the stream is cut into blocks.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from acquisition.sim import tacho_synth
from acquisition.sim.sweep import RpmProfile
from acquisition.stream import (
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SampleGroup,
    Source,
    SourceError,
    StreamItem,
    StreamLayout,
)

if TYPE_CHECKING:
    from ptinertia.config import Tacho


class AmplitudeModel(Protocol):
    """What the simulator needs from a bench model (``powertrain.model.BenchModel``)."""

    @property
    def channel_names(self) -> tuple[str, ...]: ...

    def channel_amplitudes(self, rpm: np.ndarray, orders: npt.ArrayLike) -> np.ndarray:
        """(n_rpm, n_orders, n_ch) complex, m/s^2, ``x(t) = Re{X exp(i h phi(t))}``."""
        ...

    def pressure(self, phi_rad: np.ndarray) -> np.ndarray | None:
        """Cylinder-1 pressure (Pa) at crank angles from its firing TDC, or None."""
        ...


def half_orders(max_order: float) -> np.ndarray:
    """``0.5, 1.0, ..., max_order`` (the half orders of a four-stroke engine)."""
    return np.arange(1, math.floor(2 * max_order + 1e-9) + 1) / 2.0


# -- the amplitude table -------------------------------------------------------------------------


class AmplitudeTable:
    """Piecewise-polynomial ``X(rpm)`` per profile segment, within ``rtol`` of the model.

    Parameters
    ----------
    model : AmplitudeModel
    orders : (n_o,) float
    profile : RpmProfile
    degree : int
        Polynomial degree per interval (in the interval's normalised rpm ``u``).
    rtol : float
        Accepted error per interval: ``max |P - X| / max_h |X_h|`` per channel
        at check points between the Chebyshev nodes and at the ends.

    Attributes
    ----------
    edges : list of (n_int + 1,) float, rpm
        Interval edges per segment (a hold has one interval of zero width).
    coeffs : list of (n_int, degree + 1, n_o, n_ch) complex
        Monomial coefficients in ``u = (rpm - centre) / half_width``, highest last.
    max_error : float
        Largest accepted check-point error (relative, as ``rtol``).
    max_intervals : int
        Per segment; beyond it the model is not smooth enough for ``rtol`` (SourceError).
    n_model_rpm : int
        Number of rpm values the model was evaluated at.
    """

    def __init__(
        self,
        model: AmplitudeModel,
        orders: np.ndarray,
        profile: RpmProfile,
        degree: int = 4,
        rtol: float = 1e-10,
        initial_width_rpm: float = 100.0,
        max_intervals: int = 100_000,
    ) -> None:
        self.orders = np.asarray(orders, dtype=float)
        self.degree = degree
        self.max_intervals = max_intervals
        self.n_model_rpm = 0
        self.max_error = 0.0
        self._model = model
        n = degree + 1
        self._nodes = np.cos(np.pi * (np.arange(n) + 0.5) / n)
        self._checks = np.cos(np.pi * np.arange(n + 1) / n)  # ends and mid-node points
        self._vinv = np.linalg.inv(np.vander(self._nodes, n, increasing=True))
        self.edges: list[np.ndarray] = []
        self.coeffs: list[np.ndarray] = []
        cache: dict[tuple[float, float], tuple[np.ndarray, np.ndarray]] = {}
        for seg in profile.segments:
            lo, hi = sorted((seg.rpm_from, seg.rpm_to))
            if (lo, hi) not in cache:
                cache[(lo, hi)] = self._build(lo, hi, initial_width_rpm, rtol)
            e, c = cache[(lo, hi)]
            self.edges.append(e)
            self.coeffs.append(c)
        # real form for the synthesis: Re{X e} = Re X cos - Im X sin
        self.real_coeffs = [_real_design(c) for c in self.coeffs]
        self._centre = [0.5 * (e[:-1] + e[1:]) for e in self.edges]
        # 1 / half width; 0 at a hold so that u = 0 there
        self._inv_half = [
            np.divide(2.0, np.diff(e), out=np.zeros(len(e) - 1), where=np.diff(e) > 0)
            for e in self.edges
        ]

    def _model_eval(self, rpm: np.ndarray) -> np.ndarray:
        self.n_model_rpm += rpm.size
        x = np.asarray(self._model.channel_amplitudes(rpm, self.orders))
        if x.ndim != 3 or x.shape[:2] != (rpm.size, self.orders.size):
            raise SourceError(
                "model channel_amplitudes: expected shape "
                f"({rpm.size}, {self.orders.size}, n_ch), got {x.shape}"
            )
        return x

    def _build(
        self, lo: float, hi: float, width: float, rtol: float
    ) -> tuple[np.ndarray, np.ndarray]:
        n = self.degree + 1
        if hi == lo:
            x = self._model_eval(np.array([lo]))
            # a hold is exact: one constant term
            return np.array([lo, hi]), x[None, :1].copy()
        k = max(1, math.ceil((hi - lo) / width))
        pending = np.stack(
            [lo + (hi - lo) * np.arange(k) / k, lo + (hi - lo) * np.arange(1, k + 1) / k], 1
        )
        pending[-1, 1] = hi
        min_width = 1e-9 * hi
        done_iv: list[np.ndarray] = []
        done_c: list[np.ndarray] = []
        floor = 0.0
        while len(pending):
            mid = 0.5 * (pending[:, 0] + pending[:, 1])
            half = 0.5 * (pending[:, 1] - pending[:, 0])
            u = np.concatenate([self._nodes, self._checks])
            rpm = (mid[:, None] + half[:, None] * u[None, :]).ravel()
            x = self._model_eval(rpm).reshape(len(pending), u.size, self.orders.size, -1)
            coef = np.einsum("kj,ijoc->ikoc", self._vinv, x[:, :n])
            xc = x[:, n:]
            fit = np.einsum("pk,ikoc->ipoc", np.vander(self._checks, n, increasing=True), coef)
            scale = np.abs(xc).max(axis=2)  # (n_int, n_check, n_ch)
            floor = max(floor, 1e-12 * float(scale.max(initial=0.0)))
            err = (np.abs(fit - xc).max(axis=2) / np.maximum(scale, floor or 1.0)).max(axis=(1, 2))
            ok = (err <= rtol) | (half * 2 <= min_width)
            if np.any(ok):
                self.max_error = max(self.max_error, float(err[ok].max()))
                done_iv.append(pending[ok])
                done_c.append(coef[ok])
            bad = pending[~ok]
            n_done = sum(len(d) for d in done_iv)
            if n_done + 2 * len(bad) > self.max_intervals:
                raise SourceError(
                    f"amplitude table: more than {self.max_intervals} intervals needed for a "
                    f"relative error of {rtol:g} over {lo:g}..{hi:g} rpm (worst {err.max():.2g}); "
                    "the model is not smooth in rpm at that level: raise table_rtol"
                )
            m = 0.5 * (bad[:, 0] + bad[:, 1])
            pending = np.concatenate([np.stack([bad[:, 0], m], 1), np.stack([m, bad[:, 1]], 1)])
        iv = np.concatenate(done_iv)
        c = np.concatenate(done_c)
        order = np.argsort(iv[:, 0])
        iv, c = iv[order], c[order]
        return np.concatenate([iv[:, 0], iv[-1:, 1]]), c

    def locate(self, segment: int, rpm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interval index and normalised rpm ``u`` in ``[-1, 1]`` of each rpm of a segment."""
        e = self.edges[segment]
        if len(e) == 2:  # one interval (a hold, or a smooth short ramp)
            j = np.zeros(np.shape(rpm), dtype=np.intp)
        else:
            j = np.searchsorted(e, rpm, side="right") - 1
            np.clip(j, 0, len(e) - 2, out=j)
        return j, (rpm - self._centre[segment][j]) * self._inv_half[segment][j]

    def evaluate(self, segment: int, rpm: np.ndarray) -> np.ndarray:
        """Tabulated ``X`` at rpm values of one segment: (n, n_o, n_ch) complex, m/s^2."""
        rpm = np.atleast_1d(np.asarray(rpm, dtype=float))
        j, u = self.locate(segment, rpm)
        c = self.coeffs[segment][j]  # (n, degree+1, n_o, n_ch)
        out = c[:, -1]
        for k in range(c.shape[1] - 2, -1, -1):
            out = out * u[:, None, None] + c[:, k]
        return out


def _real_design(c: np.ndarray) -> np.ndarray:
    """(n_int, deg+1, n_o, n_ch) complex -> (n_int, (deg+1) n_ch, 2 n_o) real matmul operands.

    Row ``k n_ch + c`` holds ``Re C_k, -Im C_k`` of channel ``c`` interleaved per
    order, matching the columns ``cos h phi, sin h phi`` of :func:`order_basis`.
    """
    n_int, n_k, n_o, n_ch = c.shape
    d = np.stack([c.real, -c.imag], axis=3)  # (n_int, n_k, n_o, 2, n_ch)
    return np.ascontiguousarray(d.transpose(0, 1, 4, 2, 3).reshape(n_int, n_k * n_ch, 2 * n_o))


# -- pure synthesis ------------------------------------------------------------------------------


def order_basis(phi: np.ndarray, n_orders: int) -> np.ndarray:
    """Columns ``cos(h phi), sin(h phi)`` interleaved, ``h = 0.5 .. n_orders / 2``: (n, 2 n_orders).

    It is the float view of ``exp(i h phi)`` laid out (n, n_orders): no copy,
    and its transpose goes to BLAS as is (measured 3x faster than stacking the
    real and imaginary parts into rows).
    """
    z = np.exp(0.5j * np.asarray(phi, dtype=float))
    e = np.empty((z.size, n_orders), dtype=complex)
    e[:, 0] = z
    # powers by repeated products: 24 products lose < 1e-14, far cheaper than 24 complex exps
    for k in range(1, n_orders):
        np.multiply(e[:, k - 1], z, out=e[:, k])
    return e.view(np.float64)


_CHUNK = 1024  # samples per matmul: keeps the operands in cache (measured ~1.5x faster than 2560)


def synthesize_accel(table: AmplitudeTable, profile: RpmProfile, t: np.ndarray) -> np.ndarray:
    """Noise-free accelerations at times ``t`` (s, increasing): (n_ch, n) float, m/s^2.

    The pure function behind :class:`SimulatedBench`; a sample's value depends
    only on its time, never on the block it belongs to.
    """
    t = np.asarray(t, dtype=float)
    seg, phi, omega = profile.evaluate(t)
    rpm = omega * (60.0 / (2.0 * math.pi))
    basis = order_basis(phi, table.orders.size)
    n_ch = table.coeffs[0].shape[3]
    out = np.empty((n_ch, t.size))
    if t.size == 0:
        return out
    # runs of samples in one segment and one table interval (seg is non-decreasing)
    seg_cuts = [0, *(np.flatnonzero(seg[1:] != seg[:-1]) + 1).tolist(), t.size]
    for a0, b0 in itertools.pairwise(seg_cuts):
        s = int(seg[a0])
        j, u = table.locate(s, rpm[a0:b0])
        cuts = [0, *(np.flatnonzero(j[1:] != j[:-1]) + 1).tolist(), b0 - a0]
        coeffs = table.real_coeffs[s]
        for a, b in itertools.pairwise(cuts):
            d = coeffs[j[a]]
            for c0 in range(a, b, _CHUNK):
                c1 = min(b, c0 + _CHUNK)
                y = (d @ basis[a0 + c0 : a0 + c1].T).reshape(-1, n_ch, c1 - c0)
                acc = y[-1]
                if y.shape[0] > 1:
                    uu = u[c0:c1]
                    for k in range(y.shape[0] - 2, -1, -1):  # Horner in u, in place
                        acc *= uu
                        acc += y[k]
                out[:, a0 + c0 : a0 + c1] = acc
    return out


# -- the source ----------------------------------------------------------------------------------


class SimulatedBench(Source):
    """A simulated bench streaming accelerations, rpm, tacho (and cam, pressure).

    Parameters
    ----------
    model : AmplitudeModel
        The as-built bench (``ptinertia.bench.build_simulated_model``).
    tacho : ptinertia.config.Tacho
        Tacho kind, delivery and channel names.
    accel_rate_hz : float
        Accelerometer (and pressure) sample rate.
    profile : RpmProfile
    max_order : float
        Highest order synthesised; every half order from 0.5 is included.
    noise_snr_db : float or None
        Per-channel SNR ``20 log10(rms signal / noise std)``; None for no noise.
    seed : int
        Seeds the noise (the model's own errors are seeded by its builder).
    block_s : float
        Length of the time window each round of items covers.
    paced : bool
        Sleep so that a window is yielded when the wall clock reaches its end.
    tacho_rise_s : float or None
        Edge rise time of a sampled tacho (default :func:`tacho_synth.default_rise_time`).
    truth : dict or None
        The simulated truth (JSON-serialisable), also put in ``layout.metadata``.
    metadata : dict or None
        Extra metadata (bench text, ...).
    table_rtol, table_degree : float, int
        Amplitude table accuracy (see :class:`AmplitudeTable`).
    record_pressure : bool
        Stream the cylinder-1 pressure (``tacho.pressure_channel``, bar) even when it
        is not the phase reference (the estimator takes the gas torque from it).
    dead_channels : accelerometer channels that read NaN all run (an open input, as a
        DAQ marks it): the fault the order tracker flags and the estimator survives.
    """

    def __init__(
        self,
        model: AmplitudeModel,
        *,
        tacho: Tacho,
        accel_rate_hz: float,
        profile: RpmProfile,
        max_order: float = 6.0,
        noise_snr_db: float | None = None,
        seed: int = 0,
        block_s: float = 0.1,
        paced: bool = False,
        tacho_rise_s: float | None = None,
        truth: dict[str, Any] | None = None,
        metadata: dict[str, Any] | None = None,
        table_rtol: float = 1e-10,
        table_degree: int = 4,
        record_pressure: bool = False,
        dead_channels: tuple[str, ...] = (),
    ) -> None:
        super().__init__()
        if not block_s > 0:
            raise SourceError(
                f"block_s: expected a positive block length in seconds, got {block_s}"
            )
        self.model = model
        self.tacho = tacho
        self.profile = profile
        self.block_s = float(block_s)
        self.paced = paced
        self.truth = dict(truth or {})
        self.orders = half_orders(max_order)
        self.fs = float(accel_rate_hz)
        nyquist_order = 60 * self.fs / 2 / profile.rpm_max
        if self.orders[-1] >= nyquist_order:
            raise SourceError(
                f"max_order {self.orders[-1]:g} aliases: at {profile.rpm_max:g} rpm and "
                f"{self.fs:g} Hz the highest order below Nyquist is {nyquist_order:.3g}; "
                "lower [simulation] max_order or raise the sample rate"
            )
        self.table = AmplitudeTable(
            model, self.orders, profile, degree=table_degree, rtol=table_rtol
        )
        channels = tuple(model.channel_names)
        unknown = sorted(set(dead_channels) - set(channels))
        if unknown:
            raise SourceError(
                f"[simulation] dead_channels: {unknown} are not accelerometer channels (have {list(channels)})"
            )
        self._dead = np.array([c in dead_channels for c in channels])
        groups = [SampleGroup("accel", self.fs, tuple(ChannelSpec(c, "m/s^2") for c in channels))]
        self._pressure = tacho.phase_reference == "pressure" or record_pressure
        if self._pressure:
            if model.pressure(np.zeros(1)) is None:
                why = (
                    "tacho.phase_reference = 'pressure'"
                    if tacho.phase_reference == "pressure"
                    else "a cylinder-pressure channel"
                )
                raise SourceError(
                    f"{why} needs a cylinder pressure, but the gas "
                    "model gives none (use gas model 'parametric' or 'trace')"
                )
            groups.append(
                SampleGroup("pressure", self.fs, (ChannelSpec(tacho.pressure_channel, "bar"),))
            )
        groups.append(
            SampleGroup("rpm", float(tacho.rpm_rate_hz), (ChannelSpec(tacho.rpm_channel, "rpm"),))
        )
        self._patterns = {tacho.channel: tacho_synth.crank_pattern(tacho)}
        if tacho.phase_reference == "cam":
            self._patterns[tacho.cam_channel] = tacho_synth.cam_pattern(tacho)
        edge_channels: tuple[str, ...] = ()
        self._sampled_tacho = tacho.delivery == "sampled"
        if self._sampled_tacho:
            fs_t = float(tacho.sample_rate_hz)
            self.tacho_rise_s = (
                tacho_rise_s if tacho_rise_s is not None else tacho_synth.default_rise_time(fs_t)
            )
            for name, pattern in self._patterns.items():
                tacho_synth.check_rise_time(
                    pattern, self.tacho_rise_s, profile.rpm_max, f"sampled {name}"
                )
            groups.append(
                SampleGroup("tacho", fs_t, tuple(ChannelSpec(c, "V") for c in self._patterns))
            )
        else:
            self.tacho_rise_s = 0.0
            edge_channels = tuple(self._patterns)
        self.noise_std = np.zeros(len(channels))
        if noise_snr_db is not None:
            self.noise_std = self.signal_rms() / 10 ** (noise_snr_db / 20)
        self._noisy = bool(np.any(self.noise_std > 0))
        seeds = np.random.SeedSequence([int(seed), 0x5EED]).spawn(len(channels))
        self._rngs = [np.random.default_rng(s) for s in seeds]
        meta: dict[str, Any] = {
            "source": "sim",
            "truth": self.truth,
            "orders": self.orders.tolist(),
            "profile": profile.describe(),
            "noise_snr_db": noise_snr_db,
            "noise_std": dict(zip(channels, self.noise_std.tolist(), strict=True)),
            "seed": int(seed),
            "table_max_error": self.table.max_error,
            "dead_channels": list(dead_channels),
        }
        meta.update(metadata or {})
        self._layout = StreamLayout(tuple(groups), edge_channels, meta)

    @property
    def layout(self) -> StreamLayout:
        return self._layout

    def exact_amplitudes(self, rpm: npt.ArrayLike, orders: npt.ArrayLike) -> np.ndarray:
        """The model's amplitudes (what the signal contains): (n_rpm, n_orders, n_ch) complex."""
        return np.asarray(
            self.model.channel_amplitudes(np.atleast_1d(np.asarray(rpm, dtype=float)), orders)
        )

    def signal_rms(self, n_points: int = 20000) -> np.ndarray:
        """Rms (m/s^2) of each noise-free channel over the profile: (n_ch,).

        ``mean_t sum_h |X_h(rpm(t))|^2 / 2`` on a uniform time grid (cross terms
        between orders average out over the cycles of a sweep).
        """
        t = (np.arange(n_points) + 0.5) * (self.profile.duration_s / n_points)
        rpm = self.profile.rpm(t)
        seg = self.profile.segment_index(t)
        power = np.zeros(self.table.coeffs[0].shape[3])
        for s in np.unique(seg):
            r = rpm[seg == s]
            for a in range(0, r.size, 1000):  # bounded memory: (1000, n_o, n_ch) at a time
                x = self.table.evaluate(int(s), r[a : a + 1000])
                power += 0.5 * (np.abs(x) ** 2).sum(axis=(0, 1))
        return np.sqrt(power / n_points)

    # -- streaming ----------------------------------------------------------------------------

    def _n_total(self, rate_hz: float) -> int:
        return math.ceil(self.profile.duration_s * rate_hz - 1e-9)

    def _index_at(self, k: int, rate_hz: float, n_total: int) -> int:
        """Samples with ``t < k * block_s`` (the same integer for every caller)."""
        return min(n_total, max(0, math.ceil(k * self.block_s * rate_hz - 1e-9)))

    def _group_data(self, group: SampleGroup, i0: int, i1: int) -> np.ndarray:
        t = np.arange(i0, i1) / group.rate_hz
        if group.name == "accel":
            x = synthesize_accel(self.table, self.profile, t)
            if self._noisy:
                for c, rng in enumerate(self._rngs):
                    x[c] += self.noise_std[c] * rng.standard_normal(t.size)
            x[self._dead] = np.nan
            return x
        if group.name == "pressure":
            phi = np.mod(self.profile.phi(t), 4 * math.pi)
            return np.asarray(self.model.pressure(phi), dtype=float)[None, :] / 1e5
        if group.name == "rpm":
            return self.profile.rpm(t)[None, :]
        # sampled tacho (and cam)
        return np.stack(
            [
                tacho_synth.square_wave(
                    i0, i1 - i0, group.rate_hz, self.profile, p, self.tacho_rise_s
                )
                for p in self._patterns.values()
            ]
        )

    def _iter_items(self) -> Iterator[StreamItem]:
        duration = self.profile.duration_s
        n_windows = math.ceil(duration / self.block_s - 1e-9)
        totals = {g.name: self._n_total(g.rate_hz) for g in self._layout.groups}
        start = time.monotonic()
        for k in range(n_windows):
            t_a, t_b = k * self.block_s, min((k + 1) * self.block_s, duration)
            items: list[tuple[float, int, StreamItem]] = []
            for gi, g in enumerate(self._layout.groups):
                i0 = self._index_at(k, g.rate_hz, totals[g.name])
                i1 = (
                    totals[g.name]
                    if k == n_windows - 1
                    else self._index_at(k + 1, g.rate_hz, totals[g.name])
                )
                if i1 > i0:
                    items.append(
                        (i0 / g.rate_hz, gi, SampleBlock(g.name, i0, self._group_data(g, i0, i1)))
                    )
            for ci, name in enumerate(self._layout.edge_channels):
                p = self._patterns[name]
                te = tacho_synth.edge_times(self.profile, p.rising_rad, p.period_rad, t_a, t_b)
                if te.size:
                    items.append((float(te[0]), 100 + ci, EdgeBlock(name, te)))
            items.sort(key=lambda it: (it[0], it[1]))
            if self.paced:
                delay = start + t_b - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            for _, _, item in items:
                yield item
