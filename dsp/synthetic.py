"""Synthetic order signals with an exactly known crank angle, for tests and benchmarks.

Independent of the simulated bench's model: the crank speed ramps linearly,
``phi(t) = phi0 + w0 t + a t^2 / 2`` (the bench's own :class:`~acquisition.sim.sweep.RpmProfile`,
inverse in closed form), every channel is a
sum of orders ``x(t) = sum_h Re{A_h(rpm(t)) exp(i h phi(t))}`` with
``A_h(rpm) = A_h0 (rpm / rpm_ref)^p_h``, and the tacho edges are the exact
times at which the wheel passes its teeth (wheel angle ``theta_w = phi +
tdc_after_gap_deg``, teeth at ``360 j / N`` deg, ``j = 0 .. N-M-1``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from acquisition.sim.sweep import RpmProfile, ramp
from acquisition.stream import (
    ChannelSpec,
    EdgeBlock,
    SampleBlock,
    SampleGroup,
    StreamItem,
    StreamLayout,
)


@dataclass(frozen=True)
class Ramp:
    """Linear rpm ramp ``rpm0 -> rpm1`` over ``duration_s``; constant outside.

    The crank angle and its inverse are the simulated bench's
    (:class:`~acquisition.sim.sweep.RpmProfile` of one segment), so the tests of the
    order tracker and the simulator share one exact kinematics.
    """

    rpm0: float
    rpm1: float
    duration_s: float
    phi0_rad: float = 0.0

    @cached_property
    def profile(self) -> RpmProfile:
        """The one-segment profile behind the ramp."""
        return RpmProfile([ramp(self.rpm0, self.rpm1, self.duration_s)], self.phi0_rad)

    def phi(self, t: np.ndarray | float) -> np.ndarray:
        return self.profile.phi(np.asarray(t, dtype=float))

    def omega(self, t: np.ndarray | float) -> np.ndarray:
        return self.profile.omega(np.asarray(t, dtype=float))

    def rpm(self, t: np.ndarray | float) -> np.ndarray:
        return self.profile.rpm(np.asarray(t, dtype=float))

    def t_of_phi(self, phi: np.ndarray | float) -> np.ndarray:
        """Exact inverse (cancellation-free root of the quadratic)."""
        return self.profile.t_of_phi(np.asarray(phi, dtype=float))


@dataclass(frozen=True)
class OrderContent:
    """One channel's orders: ``A_h(rpm) = amplitude * (rpm / rpm_ref)^power``."""

    orders: tuple[float, ...]
    amplitudes: tuple[complex, ...]
    powers: tuple[float, ...]
    rpm_ref: float = 3000.0

    def at(self, rpm: np.ndarray) -> np.ndarray:
        """Complex amplitudes at ``rpm``: (n_rpm, n_orders)."""
        r = np.atleast_1d(np.asarray(rpm, dtype=float))[:, None] / self.rpm_ref
        return np.asarray(self.amplitudes)[None, :] * r ** np.asarray(self.powers)[None, :]

    def amplitude(self, order: float, rpm: np.ndarray) -> np.ndarray:
        return self.at(rpm)[:, self.orders.index(order)]


def random_content(
    rng: np.random.Generator,
    orders: Sequence[float] = tuple(np.arange(0.5, 6.01, 0.5)),
    power_range: tuple[float, float] = (0.0, 2.0),
) -> OrderContent:
    """Random amplitudes (1..3, random phase) and rpm powers for every order."""
    n = len(orders)
    amps = (1.0 + 2.0 * rng.random(n)) * np.exp(2j * np.pi * rng.random(n))
    powers = rng.uniform(*power_range, n)
    return OrderContent(tuple(float(h) for h in orders), tuple(amps), tuple(powers))


@dataclass
class SyntheticBench:
    """A stream of accelerometer blocks and tacho edges with exact truth.

    Parameters
    ----------
    ramp : Ramp
    contents : sequence of OrderContent
        One per accelerometer channel (``a0, a1, ...``).
    rate_hz : float
        Accelerometer sampling rate.
    teeth, missing : int
        Wheel N-M.
    tdc_after_gap_deg : float
    noise_std : float
        White noise added to every accelerometer sample (m/s^2).
    tacho : {"edges", "sampled"}
    tacho_rate_hz, rise_s : float
        Sampled tacho: 0/5 V square wave, each tooth high for half its pitch,
        linear edges of ``rise_s``.
    cam_angle_deg : float or None
        Adds a cam edge channel ``cam`` (one edge per 720 deg at this phi).
    pressure : bool
        Adds channel ``p_cyl1`` (bar) to the accel group: a firing peak after
        phi = 0 (mod 720 deg).
    """

    ramp: Ramp
    contents: Sequence[OrderContent]
    rate_hz: float = 5120.0
    teeth: int = 60
    missing: int = 2
    tdc_after_gap_deg: float = 84.0
    noise_std: float = 0.0
    seed: int = 0
    tacho: str = "edges"
    tacho_rate_hz: float = 200_000.0
    rise_s: float = 2e-6
    cam_angle_deg: float | None = None
    pressure: bool = False
    drop_edges: Sequence[int] = ()
    extra_edges_s: Sequence[float] = ()
    channel_names: Sequence[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.channel_names:
            self.channel_names = [f"a{i}" for i in range(len(self.contents))]

    @property
    def layout(self) -> StreamLayout:
        chans = [ChannelSpec(c, "m/s^2") for c in self.channel_names]
        if self.pressure:
            chans.append(ChannelSpec("p_cyl1", "bar"))
        groups = [SampleGroup("accel", self.rate_hz, tuple(chans))]
        edges = []
        if self.tacho == "sampled":
            groups.append(SampleGroup("tacho", self.tacho_rate_hz, (ChannelSpec("tacho", "V"),)))
        else:
            edges.append("tacho")
        if self.cam_angle_deg is not None:
            edges.append("cam")
        return StreamLayout(tuple(groups), tuple(edges))

    # -- truth ---------------------------------------------------------------------------------

    def edge_times(self, t_end: float) -> np.ndarray:
        """Exact rising-edge times in [0, t_end], minus dropped ones, plus extra ones."""
        n, m = self.teeth, self.missing
        lo = self.ramp.phi(0.0) + math.radians(self.tdc_after_gap_deg)
        hi = self.ramp.phi(t_end) + math.radians(self.tdc_after_gap_deg)
        j = np.arange(math.floor(lo / (2 * math.pi) * n) - 1, math.ceil(hi / (2 * math.pi) * n) + 1)
        j = j[(j % n) < n - m]
        theta = 2 * math.pi * j / n
        t = self.ramp.t_of_phi(theta - math.radians(self.tdc_after_gap_deg))
        t = t[(t >= 0) & (t <= t_end)]
        if len(self.drop_edges):
            t = np.delete(t, list(self.drop_edges))
        if len(self.extra_edges_s):
            t = np.sort(np.concatenate((t, np.asarray(self.extra_edges_s, float))))
        return t

    def cam_times(self, t_end: float) -> np.ndarray:
        assert self.cam_angle_deg is not None
        c = math.radians(self.cam_angle_deg)
        k = np.arange(
            math.floor((self.ramp.phi(0.0) - c) / (4 * math.pi)),
            math.ceil((self.ramp.phi(t_end) - c) / (4 * math.pi)) + 1,
        )
        t = self.ramp.t_of_phi(c + 4 * math.pi * k)
        return t[(t >= 0) & (t <= t_end)]

    def accel(self, t: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """(n_channels, n) accelerations at times ``t``."""
        phi = self.ramp.phi(t)
        rpm = self.ramp.rpm(t)
        out = np.empty((len(self.contents), t.size))
        for c, content in enumerate(self.contents):
            amps = content.at(rpm)
            h = np.asarray(content.orders)
            out[c] = np.real(amps * np.exp(1j * phi[:, None] * h[None, :])).sum(axis=1)
        if self.noise_std and rng is not None:
            out += self.noise_std * rng.standard_normal(out.shape)
        return out

    def pressure_bar(self, t: np.ndarray) -> np.ndarray:
        """A crude cylinder-1 pressure: 1 bar plus a 40 bar peak 15 deg after firing TDC."""
        psi = np.mod(self.ramp.phi(t) + 2 * math.pi, 4 * math.pi) - 2 * math.pi
        return 1.0 + 40.0 * np.exp(-0.5 * ((psi - math.radians(15)) / math.radians(25)) ** 2)

    def tacho_volts(self, t: np.ndarray) -> np.ndarray:
        """Sampled square wave: high for half a pitch after each tooth edge.

        Linear edges of ``rise_s`` centred on the exact edge times, so the
        mid-level (2.5 V) crossing is the tooth's edge time.
        """
        n = self.teeth
        off = math.radians(self.tdc_after_gap_deg)
        # nearest tooth edge at or before t + rise/2 (a ramp may have started)
        pos = (self.ramp.phi(t + 0.5 * self.rise_s) + off) / (2 * math.pi) * n
        j = np.floor(pos)
        present = (j % n) < n - self.missing
        t_rise = self.ramp.t_of_phi(2 * math.pi * j / n - off)
        t_fall = self.ramp.t_of_phi(2 * math.pi * (j + 0.5) / n - off)
        up = np.clip((t - t_rise) / self.rise_s + 0.5, 0.0, 1.0)
        down = np.clip((t - t_fall) / self.rise_s + 0.5, 0.0, 1.0)
        return 5.0 * np.where(present, np.minimum(up, 1.0 - down), 0.0)

    # -- the stream ----------------------------------------------------------------------------

    def items(
        self,
        duration_s: float,
        block_s: float = 0.1,
        rng_blocks: np.random.Generator | None = None,
    ) -> Iterator[StreamItem]:
        """Blocks in time order; random block sizes (down to one sample) with ``rng_blocks``."""
        rng = np.random.default_rng(self.seed)
        n_total = int(duration_s * self.rate_hz)
        edges = self.edge_times(duration_s)
        cams = self.cam_times(duration_s) if self.cam_angle_deg is not None else None
        k = 0
        e_done = 0
        c_done = 0
        tk = 0
        n_tacho = int(duration_s * self.tacho_rate_hz)
        while k < n_total:
            if rng_blocks is not None:
                size = int(rng_blocks.integers(1, int(2 * block_s * self.rate_hz) + 2))
            else:
                size = int(block_s * self.rate_hz)
            size = min(size, n_total - k)
            t = (k + np.arange(size)) / self.rate_hz
            t_end = (k + size) / self.rate_hz
            if self.tacho == "edges":
                e_to = int(np.searchsorted(edges, t_end))
                if e_to > e_done:
                    yield EdgeBlock("tacho", edges[e_done:e_to])
                    e_done = e_to
            else:
                k_to = min(int(t_end * self.tacho_rate_hz), n_tacho)
                while tk < k_to:
                    step = k_to - tk
                    if rng_blocks is not None:
                        step = min(step, int(rng_blocks.integers(1, 4000)))
                    tt = (tk + np.arange(step)) / self.tacho_rate_hz
                    yield SampleBlock("tacho", tk, self.tacho_volts(tt)[None, :])
                    tk += step
            if cams is not None:
                c_to = int(np.searchsorted(cams, t_end))
                if c_to > c_done:
                    yield EdgeBlock("cam", cams[c_done:c_to])
                    c_done = c_to
            data = self.accel(t, rng)
            if self.pressure:
                data = np.vstack((data, self.pressure_bar(t)))
            yield SampleBlock("accel", k, data)
            k += size
