"""The order frame and the analysis window that produces it.

Window. Each frame integrates over one engine cycle in the angle domain,

    X_h = 2 / W * sum_k w(phi_k) x_k exp(-i h phi_k) omega_k dt,   W = sum_k w(phi_k) omega_k dt,

a Riemann sum over the time samples of ``(2/L) int w(phi) x exp(-i h phi) dphi``
(``omega dt`` is the Jacobian ``dphi``; no resampling). The window ``w`` is flat
over the 720 deg cycle with smooth tapers of width ``tau`` centred on its two
ends, shaped so that the tapers of consecutive cycles add to exactly one
(``rise(s) + rise(1 - s) = 1``). Its periodic extension with period 720 deg is
therefore constant, so its transform vanishes at every multiple of 0.5
order: a neighbouring half order of constant amplitude is rejected exactly
(not "by 60 dB"), while the smooth tapers keep the sum over samples spectrally
accurate (a bare rectangular window cut between two samples errs by about
1e-2). The taper is the normalised integral of a ``sin^8`` bump,
``rise(s) = int_0^s sin^8(pi u) du / int_0^1 sin^8``, seven times continuously
differentiable; of the partition-of-unity tapers tried (raised cosine,
``sin^2(pi/2 sin^2)``, 7th/9th-order smoothstep, Planck, erf, Kaiser-Bessel
and ``sin^4 .. sin^12`` bump integrals) it gave the smallest worst-case error:
with orders up to 6 present at 4500 rpm and 5120 Hz and a 45 deg taper, 5e-8
of the strongest order (``sin^2(pi/2 sin^2)``: 3e-6, 9th-order smoothstep: 2e-6;
at 30 deg: 4e-6, against 1e-5 and 2e-5; raised cosine at 30 deg: 1.5e-4).

Frames sit at deterministic crank angles ``c_m = m * 360 deg / frames_per_rev``
(``c_0`` = firing TDC of cylinder 1), with the window ``c_m +- 360 deg``, so live
and replayed streams give the same frames. The window is assembled from
per-segment sums: a *zone* of width ``tau`` around each ``c_m`` and the *flat*
stretch between two zones; a sample is visited once (twice in a zone, for the
taper-weighted sum).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Frame flags. ``cycle_ambiguous``: no cam/pressure reference (yet): phi may be
#: off by 360 deg, half orders then flip sign. ``angle_ambiguous``: N pulses
#: per revolution without a gap: phi is known modulo 360/N deg. ``angle_rebased``:
#: after a tacho dropout too long to count the revolutions across, phi may
#: differ from the stream start's reference (cleared where :mod:`dsp.rejoin`
#: re-acquires it). ``nan``: a channel lost more of the window than could be filled or
#: fitted (:mod:`dsp.gap_fit`; fewer missing samples only raise its ``variance_factor``).
#: ``clipped`` / ``missing_channel``: a channel had clipped samples, or the whole group
#: missed samples, in the window (``channel_ok`` False; missing give NaN amplitudes).
#: ``no_tacho`` / ``tacho_resync``: the window overlaps a stretch without crank
#: angle (a dropout; a missed or extra edge until the next gap): every
#: amplitude NaN. ``rpm_out_of_range``: mean rpm outside the configured range.
#: ``leakage_uncorrected``: no frame one cycle earlier to correct the sweep
#: leakage with (the first two frames of a stream or after a long stretch).
FLAGS = frozenset(
    {
        "cycle_ambiguous",
        "angle_ambiguous",
        "angle_rebased",
        "nan",
        "clipped",
        "no_tacho",
        "rpm_out_of_range",
        "missing_channel",
        "tacho_resync",
        "leakage_uncorrected",
    }
)


@dataclass(frozen=True)
class OrderFrame:
    """Complex order amplitudes of every channel over one analysis window.

    Attributes
    ----------
    time_s : float
        Time at which the crank reaches the window's centre angle (s, stream clock).
    rpm : float
        Mean speed over the window: 720 deg / the time the crank takes to turn it.
    crank_angle_rad : float
        phi at ``time_s`` (unwrapped, from the stream start's phi reference; a
        multiple of ``2 pi / frames_per_rev``).
    orders : tuple of float
    channels : tuple of str
    amplitudes : (n_orders, n_channels) complex
        ``x(t) = Re{X exp(i h phi(t))}``, channel units (m/s^2). NaN where the
        window holds NaN samples, a sample gap, or no valid angle.
    channel_ok : (n_channels,) bool
        False when the channel had clipped or missing samples in the window (missing
        ones only when more than :mod:`dsp.gap_fit` fills or fits).
    rpm_change : float
        ``(rpm_last - rpm_first) / rpm`` across the window.
    leakage : (n_channels,) float
        Estimated relative error that amplitude change across the window
        leaves in the channel's orders:
        ``|rpm_change| / pi * (sum_h |X_h| + sqrt(2 P_rest)) / max_h |X_h|``. A
        component of amplitude A varying as rpm^2 changes by ``2 rpm_change A``
        across the window and leaks ``1 / (2 pi)`` of that into each adjacent
        half order. The sum runs over the internally tracked orders and is left
        out when the sweep correction removed their leakage; ``P_rest`` is the
        window's mean square (from every fourth sample) less the power of those
        orders, bounding what lies outside them. A bound for uncorrected frames
        (amplitudes growing as rpm^2); after correction it counts only what the
        correction cannot see. Zero at constant speed; NaN where the amplitudes are.
    flags : frozenset of str
        Subset of :data:`FLAGS`.
    spectrum : (2 spectrum_max_order + 1,) complex or None
        Every half order of ``spectrum_channel`` (its own unit) over the same
        window, None unless the tracker was configured with one
        (``OrderTrackerConfig.spectrum_channel``). Index ``k`` is order ``k / 2``:
        ``spectrum[0]`` is the window mean (real; the same normalisation, so a
        constant ``c`` gives ``c``), ``k >= 1`` follow ``amplitudes``:
        ``x(phi) = spectrum[0] + sum_k Re{spectrum[k] exp(i k phi / 2)}``, corrected
        for sweep leakage like them (order 0 included). NaN in full where the
        window holds NaN samples of the channel, a sample gap, or no valid angle.
        The channel's faults do not touch the other fields (no flag, no
        ``channel_ok``; no clip check): a NaN spectrum is the sign.
    spectrum_channel : str or None
        The channel of ``spectrum`` (None when there is none).
    variance_factor : (n_channels,) float or None
        How much larger than in a complete window the variance of each channel's
        amplitudes is, where the window lost samples (a lost CAN frame): those
        amplitudes are a least-squares fit over the samples present
        (:mod:`dsp.gap_fit`). None when no channel lost a sample (all ones).
    """

    time_s: float
    rpm: float
    crank_angle_rad: float
    orders: tuple[float, ...]
    channels: tuple[str, ...]
    amplitudes: np.ndarray
    channel_ok: np.ndarray
    rpm_change: float
    leakage: np.ndarray
    flags: frozenset[str]
    spectrum: np.ndarray | None = None
    spectrum_channel: str | None = None
    variance_factor: np.ndarray | None = None

    def amplitude(self, order: float, channel: str) -> complex:
        """The complex amplitude of one order on one channel."""
        return complex(self.amplitudes[self.orders.index(order), self.channels.index(channel)])

    def spectrum_at(self, order: float) -> complex:
        """The complex amplitude of one half order of the spectrum channel (0: its mean)."""
        if self.spectrum is None:
            raise ValueError("this frame carries no spectrum (spectrum_channel was None)")
        k = 2 * order
        if not (k == round(k) and 0 <= k < self.spectrum.size):
            raise ValueError(
                f"order {order}: expected a multiple of 0.5 from 0 to "
                f"{(self.spectrum.size - 1) / 2:g}"
            )
        return complex(self.spectrum[round(k)])


_GRID = 8192
_S = np.arange(_GRID + 1) / _GRID


def rise_table(s: np.ndarray) -> np.ndarray:
    """:func:`rise` by linear interpolation in a 8193-point table (error < 4e-8).

    The table is symmetric, so ``rise_table(s) + rise_table(1 - s) = 1`` still holds
    to rounding; it costs a fifth of the five sines. The same numbers as
    ``np.interp(s, _S, _TABLE)``, bit for bit, in a fifth of its time: the grid is
    uniform with a power-of-two step, so the interval is an exact ``floor`` instead of
    a binary search per sample, and the formula is ``np.interp``'s.
    """
    with np.errstate(invalid="ignore"):  # NaN in, NaN out, as np.interp
        j = np.floor(s * _GRID).astype(np.int64)
        np.clip(j, 0, _GRID - 1, out=j)
        out = _SLOPE[j] * (s - _S[j]) + _TABLE[j]
    # outside [0, 1): np.interp's end values
    out[s >= 1.0] = _TABLE[-1]
    out[s < 0.0] = _TABLE[0]
    return out


def rise(s: np.ndarray) -> np.ndarray:
    """The taper on ``s`` in [0, 1]: normalised integral of ``sin^8(pi u)``; ``rise(s) + rise(1-s) = 1``.

    ``sin^8 x = (35 - 56 cos 2x + 28 cos 4x - 8 cos 6x + cos 8x) / 128``, integrated term by term.
    """
    a = 2.0 * np.pi * np.asarray(s, dtype=float)
    return (
        s
        - 4.0 / (5.0 * np.pi) * np.sin(a)
        + 1.0 / (5.0 * np.pi) * np.sin(2.0 * a)
        - 4.0 / (105.0 * np.pi) * np.sin(3.0 * a)
        + 1.0 / (280.0 * np.pi) * np.sin(4.0 * a)
    )


def rise_mean_square() -> float:
    """``int_0^1 rise(s)^2 ds`` (for the noise prediction of :func:`noise_std`)."""
    s = (np.arange(20000) + 0.5) / 20000
    return float(np.mean(rise(s) ** 2))


def noise_std(sigma: float, rate_hz: float, rpm: float, taper_deg: float) -> float:
    """Predicted std of the real (and of the imaginary) part of ``X_h`` under white noise.

    For noise of std ``sigma`` per sample, ``Var Re X = Var Im X = 2 sigma^2
    sum (w q)^2 / (sum w q)^2`` with ``q = omega dt``; at constant speed
    that is ``2 sigma^2 / N_eff`` with ``N = rate * 120 / rpm`` samples per
    cycle and ``N_eff = N L / int w^2``, ``int w^2 = L - tau + 2 tau int rise^2``.
    The amplitude then scatters by this std, the phase by it divided by ``|X|`` (rad).
    """
    length = 4.0 * math.pi
    tau = math.radians(taper_deg)
    w2 = length - tau + 2.0 * tau * rise_mean_square()
    n = rate_hz * 120.0 / rpm
    return sigma * math.sqrt(2.0 * w2 / length / n)


def centre_phase(k2: np.ndarray, m: int, frames_per_rev: int) -> np.ndarray:
    """``exp(-i h c_m)`` for orders ``h = k2 / 2`` and ``c_m = 2 pi m / frames_per_rev``, exactly.

    The argument is reduced with integers (``h c_m = 2 pi k2 m / (2 frames_per_rev)``)
    so the phase of an hour-long stream is as exact as its first second.
    """
    period = 2 * frames_per_rev
    frac = (k2 * m) % period
    return np.exp(-2j * np.pi * frac / period)


_TABLE = rise(_S)
_TABLE = 0.5 * (_TABLE + 1.0 - _TABLE[::-1])  # exactly antisymmetric about (1/2, 1/2)
_SLOPE = (_TABLE[1:] - _TABLE[:-1]) / (_S[1:] - _S[:-1])  # as np.interp computes it

# rise_table's grid, value and slope at each grid point side by side (grid, slope, value), for
# the compiled sums that repeat its arithmetic (dsp.fused_segments.falling_taper): one cache
# line a sample instead of three (the zone's samples step through the table ~140 points
# apart, and the piece's samples push it out of the cache). Issue 24, the run's 60 s log:
# the tapers alone 7.0 -> 2.4 ms a minute, dsp.fused_sums.piece_sums's calls 24.6-25.6 ->
# 23.1 ms (tracked channels) and 13.7 -> 11.1-11.6 ms (spectrum channel), CPU best of 9,
# load 2, the same bits. The last point's slope is never read (zero)
RISE_PACKED = np.zeros(3 * _S.size)
RISE_PACKED[0::3], RISE_PACKED[1:-3:3], RISE_PACKED[2::3] = _S, _SLOPE, _TABLE
