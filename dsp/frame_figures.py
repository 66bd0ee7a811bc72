"""A batch's frame figures (speed, speed change, leakage figure, angle, flag bits) and its
output orders in the crank angle, frame by frame in one pass, for the compiled path.

:func:`dsp.assemble._finish` computes them with some thirty array operations per step (its
numpy code, :func:`frame_figures_numpy` and :func:`frame_codes_numpy`, is the reference);
:func:`frame_outputs` is the same arithmetic as loops, which the compiled path
(:func:`dsp.kernels.frame_outputs`) runs through numba in one call. The same operations in
the same order, so the same bits: the magnitudes are numpy's own (its SIMD ``abs`` of a
complex is not libm's ``hypot``: it differs in the last bit, measured, and whether it fuses
a multiply-add depends on the machine), the sums over the internal orders add them in order
as numpy's reduction over that (non-contiguous) axis does, NaN propagates through the
largest output order as ``np.max`` lets it, and the divisions by zero numpy lets through
(inf, NaN) are written out (numba's ``/`` would raise). The leakage figure takes the square
root of a difference of nearly equal powers, so only equal bits keep it equal. The turn to
the crank angle with a wheel is a product by +-1, exact however it is computed. Plain
Python: the loops run uncompiled too, which is how the tests step through them.

Measured (issue 24; the run's 60 s log compiled, 120 steps of about 25 frames, CPU best
of 7, load 2.4-2.8): the figures and codes in two calls and the turns in numpy, about
22 us a step; in this one call about 7 us; :func:`dsp.assemble._finish` as a whole (with
its frame objects made from one dict each) 48 -> 33 us a step, 5.8 -> 4.0 ms a minute.
"""

from __future__ import annotations

import math

import numpy as np

TWO_PI = 2.0 * math.pi  # dsp.state's (not imported: the state imports the kernels)
_CODE_BITS = np.array([8, 4, 2, 1])  # frame_codes_numpy's flags' bits (never modified)


def frame_outputs(
    times: np.ndarray,
    omegas: np.ndarray,
    x: np.ndarray,
    absx: np.ndarray,
    ms: np.ndarray,
    corrected: np.ndarray,
    rows: np.ndarray,
    signs: np.ndarray,
    spectrum: np.ndarray,
    spectrum_signs: np.ndarray,
    js: np.ndarray,
    parity: np.ndarray,
    spacing: float,
    steps: int,
    chains: np.ndarray,
    ambiguous: np.ndarray,
    rpm_lo: float,
    rpm_hi: float,
    ok: np.ndarray,
    correcting: bool,
    variance: np.ndarray,
    out: np.ndarray,
    spec: np.ndarray,
    rpm: np.ndarray,
    rpm_change: np.ndarray,
    leak: np.ndarray,
    angles: np.ndarray,
    codes: np.ndarray,
) -> None:
    """Everything :func:`dsp.assemble._finish` computes of a batch's frames before it makes
    the frame objects, frame by frame in one pass (the numpy path's bits).

    ``times``, ``omegas`` (f, 3) at the window's start, centre and end (s, rad/s), ``x``
    (f, n_int, n_ch) the corrected amplitudes and ``absx`` their magnitudes (``np.abs``),
    ``ms`` (f, n_ch) the mean squares, ``corrected`` (f, n_ch), ``rows`` the output
    orders' rows of ``x``. rpm is 720 deg over the window's duration, ``rpm_change`` the
    speed change across it (``(omega_end - omega_start) * duration / 4 pi``), ``leak``
    (f, n_ch) the leakage figure, as :func:`frame_figures_numpy` makes them.

    ``out`` (f, n_orders, n_ch) gets the output orders, in the crank angle with a wheel
    (``steps == 1``): times ``signs[parity % 2]`` (:func:`dsp.frame_constants.rotation`),
    as numpy multiplies a complex by a real made complex; with ``steps > 1`` unturned (the
    caller turns them by numpy's complex exponential). ``spec`` (f, n_spec) the same of
    ``spectrum[:, :n_spec, 0]`` with ``spectrum_signs``, its mean (column 0) made real with a
    wheel (with N pulses the caller turns it first, then makes it real)
    (n_spec 0: no spectrum channel). ``angles`` and ``codes`` (f,) as
    :func:`frame_codes_numpy` makes them from ``js``, ``parity``, ``chains``,
    ``ambiguous`` (f,), ``ok``, ``corrected``, ``variance`` (f, n_ch).
    """
    f, n_int, n_ch = absx.shape
    n_spec = spec.shape[1]
    wheel = steps == 1
    for i in range(f):
        # speed, its change across the window and the leakage figure
        duration = times[i, 2] - times[i, 0]
        if duration != 0.0:
            rpm[i] = 120.0 / duration
        else:  # numpy's 120 / 0: inf of the zero's sign (numba's "/" would raise)
            rpm[i] = np.inf if math.copysign(1.0, duration) > 0.0 else -np.inf
        change = (omegas[i, 2] - omegas[i, 0]) * duration / (4.0 * math.pi)
        rpm_change[i] = change
        scale = abs(change) / math.pi
        for c in range(n_ch):
            explained = 0.0
            total = 0.0
            for k in range(n_int):
                a = absx[i, k, c]
                explained += a * a  # numpy's square
                total += a
            explained = 0.5 * explained
            d = ms[i, c] - explained
            rest = math.sqrt(2.0 * (d if d >= 0.0 or d != d else 0.0))
            known = 0.0 if corrected[i, c] else total
            strongest = -np.inf
            for o in range(rows.size):
                v = absx[i, rows[o], c]
                if v != v or strongest != strongest:
                    strongest = np.nan
                elif v > strongest:
                    strongest = v
            num = scale * (known + rest)
            if strongest != 0.0:
                leak[i, c] = num / strongest
            else:  # numpy's x / 0 (strongest >= 0): NaN for 0 / 0, else inf
                leak[i, c] = np.nan if num != num or num == 0.0 else np.inf
        # the output orders (and the spectrum) from the wheel angle to the crank angle:
        # (re, im) (g, 0) = (re g - im 0, re 0 + im g), numpy's product (exact here: g is
        # +-1, so fused or not, the same bits, signed zeros and NaN included)
        s = parity[i] % 2
        for o in range(rows.size):
            g = signs[s, o]
            for c in range(n_ch):
                v = x[i, rows[o], c]
                if wheel:
                    out[i, o, c] = complex(v.real * g - v.imag * 0.0, v.real * 0.0 + v.imag * g)
                else:
                    out[i, o, c] = v
        for k in range(n_spec):
            v = spectrum[i, k, 0]
            if wheel:
                g = spectrum_signs[s, k]
                v = complex(v.real * g - v.imag * 0.0, v.real * 0.0 + v.imag * g)
            spec[i, k] = v
        if n_spec and wheel:  # the mean: real (turned first: with N pulses, by the caller)
            spec[i, 0] = complex(spec[i, 0].real, 0.0)
        # the angle and the flag bits
        angles[i] = js[i] * spacing + TWO_PI * parity[i] / steps
        code = 0
        for c in range(n_ch):
            if variance[i, c] != 1.0:
                code = 16
        if ambiguous[i]:
            code += 8
        if chains[i] > 0:
            code += 4
        if rpm[i] >= rpm_lo and rpm[i] <= rpm_hi:
            code += 2
        if correcting:
            for c in range(n_ch):
                if ok[i, c] and not corrected[i, c]:
                    code += 1
                    break
        codes[i] = code


def frame_figures_numpy(
    times: np.ndarray,
    omegas: np.ndarray,
    x: np.ndarray,
    ms: np.ndarray,
    corrected: np.ndarray,
    out: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """rpm, rpm change (f,) and leakage figure (f, n_ch) of frames with window start,
    centre and end ``times``, ``omegas`` (f, 3), corrected amplitudes ``x`` (f, n_int,
    n_ch), mean squares ``ms`` (f, n_ch), output orders ``out``: the numpy path of
    :func:`dsp.assemble._finish`, the reference of :func:`frame_outputs`'s figures."""
    duration = times[:, 2] - times[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        rpm = 120.0 / duration  # 720 deg over the window's duration
        rpm_change = (omegas[:, 2] - omegas[:, 0]) * duration / (4.0 * math.pi)
        # what can leak: the internal orders unless corrected for (their amplitudes add in
        # the worst case), plus whatever power the internal orders do not explain
        absx = np.abs(x)
        explained = 0.5 * np.sum(absx**2, axis=1)
        rest = np.sqrt(2.0 * np.maximum(ms - explained, 0.0))
        known = np.where(corrected, 0.0, absx.sum(axis=1))
        strongest = np.max(absx[:, out, :], axis=1)  # of the output orders
        leak = np.abs(rpm_change)[:, None] / math.pi * (known + rest) / strongest
    return rpm, rpm_change, leak


def frame_codes_numpy(
    js: np.ndarray,
    parity: np.ndarray,
    spacing: float,
    steps: int,
    chains: np.ndarray,
    ambiguous: np.ndarray,
    rpm: np.ndarray,
    rpm_range: tuple[float, float],
    ok: np.ndarray,
    corrected: np.ndarray,
    correcting: bool,
    variance: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Each frame's crank angle ``j spacing + 2 pi p / steps`` (rad) and a code of its flag
    bits (:func:`dsp.assemble._finish`): 16 a window lost samples (a variance factor not
    1), 8 the cycle is ambiguous, 4 the chain was rebased (``chain > 0``), 2 the rpm is
    in ``rpm_range``, 1 leakage left uncorrected (a usable channel not corrected while
    ``correcting``). Frames ``js``, ``parity``, ``chains``, ``ambiguous``, ``rpm`` (f,),
    ``ok``, ``corrected``, ``variance`` (f, n_ch). The numpy reference of
    :func:`frame_outputs`'s angles and codes."""
    in_range = (rpm >= rpm_range[0]) & (rpm <= rpm_range[1])
    uncorrected = (ok & ~corrected).any(axis=1) if correcting else in_range & False
    codes = np.column_stack((ambiguous, chains > 0, in_range, uncorrected)) @ _CODE_BITS
    lost = variance != 1.0
    if lost.any():  # (rare: most windows lose no sample)
        codes += lost.any(axis=1) * 16
    return js * spacing + TWO_PI * parity / steps, codes
