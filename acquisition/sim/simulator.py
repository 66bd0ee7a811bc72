"""The simulated bench: a :class:`~acquisition.stream.Source` synthesised from a bench model.

Signals (``phi``, ``rpm`` from :class:`~acquisition.sim.sweep.RpmProfile`):

* accelerations ``x_c(t) = sum_h Re{X_hc(rpm(t)) exp(i h phi(t))}`` over the
  half orders ``0.5 .. max_order``, ``X`` from the model (m/s^2);
* cylinder-1 pressure (bar) when ``tacho.phase_reference == "pressure"``;
* the rpm channel (exact instantaneous rpm) at ``tacho.rpm_rate_hz``;
* the tacho (and cam) as edge timestamps or as a sampled square wave
  (:mod:`acquisition.sim.tacho_synth`).

The model is slow compared with the sample rate, so ``X(rpm)`` is tabulated
once per sweep segment (:mod:`acquisition.sim.amplitude_table`) and the
accelerations are synthesised from that table (:mod:`acquisition.sim.synthesis`).
The angles of a block are evaluated once for the accelerations and the pressure;
with ``PTINERTIA_NUMBA=1`` the per-sample work is compiled (:mod:`acquisition.sim.kernels`).

Noise: white, per channel, ``std_c = rms_c / 10^(snr_db / 20)`` with ``rms_c``
the rms of channel ``c``'s noise-free signal over the whole sweep (that is the
definition ``SNR = 20 log10(rms signal / noise std)``); each channel draws from
its own generator seeded from ``seed``, so the samples do not depend on how
the stream is cut into blocks.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import numpy.typing as npt

from acquisition.sim import block_kernels, kernels, tacho_synth
from acquisition.sim.amplitude_table import AmplitudeModel, AmplitudeTable
from acquisition.sim.sweep import RPM_TO_RAD_S, RpmProfile
from acquisition.sim.synthesis import half_orders, synthesize_accel
from acquisition.sim.tacho_synth import TachoSpec
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


class SimulatedBench(Source):
    """A simulated bench streaming accelerations, rpm, tacho (and cam, pressure).

    Parameters
    ----------
    model : AmplitudeModel
        The as-built bench (``ptinertia.to_physics.build_simulated_model``).
    tacho : TachoSpec
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
        Sleep so that a window is yielded when the clock reaches its end.
    clock, sleep : callables
        Monotonic seconds and a sleep (default :func:`time.monotonic`,
        :func:`time.sleep`); a test passes a fake clock instead of waiting.
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
        tacho: TachoSpec,
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
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
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
        self._clock = clock
        self._sleep = sleep
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
        omega_max = profile.rpm_max * 2 * math.pi / 60
        self._anchor_spacing = kernels.anchor_spacing(omega_max, self.fs)
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
        self._last_motion: tuple[tuple[float, int, int], tuple[np.ndarray, ...]] = (
            (math.nan, 0, 0),
            (),
        )

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

    def _motion(self, rate_hz: float, i0: int, i1: int) -> tuple[np.ndarray, ...]:
        """Times, segments, crank angles and speeds of samples ``i0 .. i1 - 1`` at ``rate_hz``.

        Kept for the next group of the same window at the same rate (the pressure
        beside the accelerations): the profile is evaluated once per block, not per group.
        """
        key = (rate_hz, i0, i1)
        if self._last_motion[0] != key:
            t = np.arange(i0, i1) / rate_hz
            motion = (
                kernels.motion(self.profile, t)[:3] if kernels.USE else self.profile.evaluate(t)
            )
            self._last_motion = (key, (t, *motion))
        return self._last_motion[1]

    def _group_data(self, group: SampleGroup, i0: int, i1: int) -> np.ndarray:
        if group.name == "accel" and kernels.USE:
            # the motion, the carriers (exact phases every `spacing` samples, at indices
            # fixed by the stream) and the products in two calls that hold no GIL: in a
            # live run the processing thread waits for the GIL after every call here
            # (acquisition.sim.block_kernels)
            *motion, x = block_kernels.accel_block(
                self.table, self.profile, group.rate_hz, i0, i1, self._anchor_spacing
            )
            self._last_motion = ((group.rate_hz, i0, i1), tuple(motion))
            t = motion[0]
        elif group.name in ("accel", "pressure"):
            t, seg, phi, omega = self._motion(group.rate_hz, i0, i1)
        else:
            t = np.arange(i0, i1) / group.rate_hz
        if group.name == "accel":
            if not kernels.USE:
                x = synthesize_accel(self.table, self.profile, t, (seg, phi, omega), None, False)
            if self._noisy:
                for c, rng in enumerate(self._rngs):
                    x[c] += self.noise_std[c] * rng.standard_normal(t.size)
            x[self._dead] = np.nan
            return x
        if group.name == "pressure":
            cycle = getattr(self.model, "pressure_cycle", None) if kernels.USE else None
            if cycle is not None:  # the model's spline, compiled (a bench model has one)
                return kernels.pressure(cycle.pieces, phi)[None, :] / 1e5
            return np.asarray(self.model.pressure(phi), dtype=float)[None, :] / 1e5
        if group.name == "rpm":  # RpmProfile.rpm's arithmetic either way
            omega = kernels.motion(self.profile, t)[2] if kernels.USE else self.profile.omega(t)
            return (omega / RPM_TO_RAD_S)[None, :]
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
        # the compiled edge times hold no GIL (acquisition.sim.block_kernels)
        edges = block_kernels.edge_times if kernels.USE else tacho_synth.edge_times
        start = self._clock()
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
                te = edges(self.profile, p.rising_rad, p.period_rad, t_a, t_b)
                if te.size:
                    items.append((float(te[0]), 100 + ci, EdgeBlock(name, te)))
            items.sort(key=lambda it: (it[0], it[1]))
            if self.paced:
                delay = start + t_b - self._clock()
                if delay > 0:
                    self._sleep(delay)
            for _, _, item in items:
                yield item
