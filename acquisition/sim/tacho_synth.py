"""Tacho and cam signals of a simulated bench, from the exact crank angle.

Conventions (:class:`TachoSpec`, which the application builds from the bench
file's ``[tacho]``; ``phi`` is the crank angle of cylinder 1 from its firing TDC):

* ``kind="wheel"``: an N-M wheel at angle ``theta_w = phi + tdc_after_gap_deg``;
  rising edges at ``theta_w = 360 j / N`` for ``j = 0 .. N-M-1``, the first
  tooth after the gap at ``theta_w = 0``, so cylinder-1 TDC comes
  ``tdc_after_gap_deg`` after that tooth.
* ``kind="pulses"``: the same wheel without a gap (N pulses per revolution).
* ``kind="rpm"``: one pulse per revolution whose rising edge is at
  ``phi = tdc_offset_deg`` (cylinder-1 TDC plus the offset).
* cam (``phase_reference="cam"``): one rising edge per 720 deg at
  ``phi = cam_angle_deg``.

Every tooth or pulse is high for half its pitch (the cam for 360 deg). A
sampled square wave (0/5 V) has linear edges of finite rise time centred on
the exact edge time, so the 2.5 V crossing interpolated between the two
samples around it is the exact edge time whenever the rise time spans at
least two sample periods (the default, see :func:`default_rise_time`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from acquisition.sim.sweep import RpmProfile
from acquisition.stream import SourceError

HIGH_V = 5.0


@dataclass(frozen=True)
class TachoSpec:
    """What the simulated bench needs to know about its tacho (see the module conventions).

    Attributes
    ----------
    kind : {"wheel", "pulses", "rpm"}
    teeth, missing : int
        An N-M wheel (``missing`` ignored for ``pulses``).
    delivery : {"edges", "sampled"}
        Edge timestamps, or a 0/5 V square wave sampled at ``sample_rate_hz``.
    sample_rate_hz : float
    channel : str
        The crank tacho's channel.
    tdc_after_gap_deg, tdc_offset_deg : float
        Crank angle from the first tooth after the gap to cylinder-1 TDC (wheel,
        pulses); the once-per-rev pulse's angle after TDC (``kind="rpm"``).
    rpm_channel : str
    rpm_rate_hz : float
        The rpm channel and its rate.
    phase_reference : {"none", "cam", "pressure"}
    cam_channel : str
    cam_angle_deg : float
    pressure_channel : str
        Cylinder-1 pressure (bar).
    """

    kind: Literal["wheel", "pulses", "rpm"]
    teeth: int
    missing: int
    delivery: Literal["edges", "sampled"]
    sample_rate_hz: float
    channel: str
    tdc_after_gap_deg: float
    tdc_offset_deg: float
    rpm_channel: str
    rpm_rate_hz: float
    phase_reference: Literal["none", "cam", "pressure"]
    cam_channel: str
    cam_angle_deg: float
    pressure_channel: str


@dataclass(frozen=True)
class EdgePattern:
    """Edges repeating every ``period_rad`` of crank angle.

    Attributes
    ----------
    rising_rad, falling_rad : (n,) float, rad
        Crank angles ``phi`` of the rising and falling edges within one
        period, each in ``[0, period_rad)``.
    period_rad : float
        ``2 pi`` for a crank wheel, ``4 pi`` for a cam.
    """

    rising_rad: np.ndarray
    falling_rad: np.ndarray
    period_rad: float

    @property
    def min_spacing_rad(self) -> float:
        """Smallest crank angle between two consecutive edges of either polarity."""
        all_edges = np.sort(np.concatenate([self.rising_rad, self.falling_rad]))
        gaps = np.diff(np.concatenate([all_edges, [all_edges[0] + self.period_rad]]))
        return float(gaps.min())


def _pattern(rising_deg: np.ndarray, high_deg: float, period_deg: float) -> EdgePattern:
    period = math.radians(period_deg)
    rising = np.sort(np.mod(np.radians(rising_deg), period))
    falling = np.sort(np.mod(rising + math.radians(high_deg), period))
    return EdgePattern(rising, falling, period)


def crank_pattern(tacho: TachoSpec) -> EdgePattern:
    """Edge pattern of the crank tacho (wheel, pulses or once-per-rev pulse)."""
    if tacho.kind == "rpm":
        return _pattern(np.array([tacho.tdc_offset_deg]), 180.0, 360.0)
    n = tacho.teeth
    present = n - (tacho.missing if tacho.kind == "wheel" else 0)
    theta_w = 360.0 * np.arange(present) / n
    return _pattern(theta_w - tacho.tdc_after_gap_deg, 180.0 / n, 360.0)


def cam_pattern(tacho: TachoSpec) -> EdgePattern:
    """One edge per 720 deg at ``phi = cam_angle_deg``, high for 360 deg."""
    return _pattern(np.array([tacho.cam_angle_deg]), 360.0, 720.0)


def angles_between(
    angles_rad: np.ndarray, period_rad: float, phi_a: float, phi_b: float
) -> np.ndarray:
    """Every ``angle + m * period`` in ``[phi_a, phi_b)``, sorted (rad)."""
    m = np.arange(math.floor(phi_a / period_rad) - 1, math.floor(phi_b / period_rad) + 2)
    cand = (m[:, None] * period_rad + angles_rad[None, :]).ravel()
    return np.sort(cand[(cand >= phi_a) & (cand < phi_b)])


def edge_times(
    profile: RpmProfile, angles_rad: np.ndarray, period_rad: float, t_a: float, t_b: float
) -> np.ndarray:
    """Times (s) of the edges at ``angles_rad (mod period)`` with ``t_a <= t < t_b``.

    The selection is by the computed time itself, so consecutive windows
    sharing a boundary give every edge exactly once, whatever the split.
    """
    phi_a, phi_b = profile.phi(np.array([t_a, t_b]))
    margin = 1e-9 * max(1.0, abs(phi_b))
    t = profile.t_of_phi(angles_between(angles_rad, period_rad, phi_a - margin, phi_b + margin))
    return t[(t >= t_a) & (t < t_b)]


def square_wave(
    i0: int,
    n: int,
    rate_hz: float,
    profile: RpmProfile,
    pattern: EdgePattern,
    rise_s: float,
    high_v: float = HIGH_V,
) -> np.ndarray:
    """Samples ``i0 .. i0+n-1`` (at ``k / rate_hz``) of a 0/``high_v`` square wave.

    ``v(t) = high_v * (base + sum_e step_e ramp((t - t_e) / rise_s))`` with
    ``ramp(x) = clip(x + 1/2, 0, 1)``: each edge a linear ramp centred on its
    exact time ``t_e``. Built in O(n + edges): a cumulative sum of the
    completed steps, then the few samples on a ramp set one by one. Each
    sample depends only on its index, never on the block it falls in.

    Returns
    -------
    (n,) float, volts
    """
    if n <= 0:
        return np.zeros(0)
    t_first, t_last = i0 / rate_hz, (i0 + n - 1) / rate_hz
    phi_a, phi_b = profile.phi(np.array([t_first - rise_s, t_last + rise_s]))
    # one period of margin on each side, so the level before the first sample is known
    lo, hi = phi_a - pattern.period_rad, phi_b + pattern.period_rad
    rising = profile.t_of_phi(angles_between(pattern.rising_rad, pattern.period_rad, lo, hi))
    falling = profile.t_of_phi(angles_between(pattern.falling_rad, pattern.period_rad, lo, hi))
    te = np.concatenate([rising, falling])
    step = np.concatenate([np.ones(rising.size), -np.ones(falling.size)])
    order = np.argsort(te, kind="stable")
    te, step = te[order], step[order]
    level = np.cumsum(step)
    level -= level.min()  # the margin starts anywhere in the pattern: levels are 0/1 after this
    half = 0.5 * rise_s
    j0 = int(np.searchsorted(te, t_first - half, side="right")) - 1  # complete before sample 0
    te, step = te[j0 + 1 :], step[j0 + 1 :]
    # first sample at or after each ramp's end: from there the step is complete
    k_end = np.clip(np.ceil((te + half) * rate_hz - 1e-9).astype(np.int64) - i0, 0, n)
    inc = np.zeros(n + 1)
    np.add.at(inc, k_end, step)
    v = level[j0] + np.cumsum(inc[:n])
    # samples on a ramp: at most ceil(rise * rate) + 1 per edge
    k_start = np.ceil((te - half) * rate_hz - 1e-9).astype(np.int64) - i0
    width = math.ceil(rise_s * rate_hz) + 1
    k = k_start[:, None] + np.arange(width)[None, :]
    on = (k >= 0) & (k < np.minimum(k_end, n)[:, None])
    tk = (k + i0) / rate_hz
    frac = np.clip((tk - te[:, None]) / rise_s + 0.5, 0.0, 1.0)
    np.add.at(v, k[on], (step[:, None] * frac)[on])
    return high_v * v


def default_rise_time(sample_rate_hz: float) -> float:
    """2.5 sample periods, at least 2 us: two samples always lie on each linear edge."""
    return max(2e-6, 2.5 / sample_rate_hz)


def check_rise_time(pattern: EdgePattern, rise_s: float, rpm_max: float, what: str) -> None:
    """Refuse a rise time that makes consecutive edges overlap at the top speed."""
    spacing_s = pattern.min_spacing_rad / (rpm_max * 2 * math.pi / 60)
    if rise_s >= 0.5 * spacing_s:
        raise SourceError(
            f"{what}: edge rise time {rise_s * 1e6:.3g} us is not below half the edge spacing "
            f"({spacing_s * 1e6:.3g} us at {rpm_max:g} rpm); raise the sample rate"
        )
