"""The compiled arithmetic of a run of frames fitted alike (``PTINERTIA_NUMBA=1``).

Each function here does in one loop over a run's (frame, order) pairs what the numpy
path does in a dozen to thirty-five array calls: :func:`fitted_arrays` (the used
channels' gather, the rigid fit of :meth:`estimator.kinematics.RigidFit.fit_arrays`
and the readings' power, for :func:`estimator.fitted_runs.fit_run`), :func:`bend_excess`
(the curvature gate, :meth:`estimator.gating.OrderGates.curvature`),
:func:`order_screen` (:meth:`~estimator.gating.OrderGates.screen_orders`),
:func:`noise_sums` and :func:`excess_rows` (:mod:`estimator.rigidity`), and
:func:`noise_medians` and :func:`window_means` (:mod:`estimator.channel_noise`). The
numpy functions stay the default and the reference; :func:`estimator.row_kernels.jit`
compiles a loop (``cache=True``, ``nogil=True``) on its first call, so the default path
never imports numba.

Why: a run is a dozen frames of 3 orders by 9 channels, and at that size numpy's
per-call overhead, not the arithmetic, is what it costs (issue 24). Measured on the 60 s
log's frames (a 12-frame run, timeit CPU best of 5, load 5-10): ``fit_run`` 216-235 us
on main, 175-176 numpy now, 93-100 compiled; in it the gather, fit and power 25.6 -> 4.4
us, the curvature 19.6 -> 8.7, the noise levels 27.8 -> 12.3 (scipy's chi-square
quantile stays), the excess 8.1 -> 1.5, the order screen 18.3 -> 3.4; the channel
noise's ``add_many`` about 6.3 -> 3.4 us a frame. The whole estimator on those frames
(1498 used; callgrind, instructions per used frame, the blocks of
``benchmarks/pipeline_stages._feed``): compiled 1477 k on main -> 1329 k (-10 %), numpy
1860 k -> 1800 k (-3.2 %, this module's loops unused). Their cost at the start of a
compiled run: about 2.3 s of CPU once per install to compile the seven loops, then 2.5-5
ms each to load from numba's cache.

How close: the gather is a copy, the channel noise's medians and windows and the
curvature's sums take numpy's operations in numpy's order (the same bits, tested);
the fit's two matrix products, the noise levels' double sum, the level's ``|z|^2`` and
the neighbour leakage's product are summed in the loop's order where numpy takes
BLAS's or its pairwise sums: within a few units in the last place (tested within 1e-13
relative, the order screen's reasons equal). ``ptinertia run --rerun off --realistic``
compiled against numpy: every estimate and interval within 1e-12 relative but the
half-order residual ratio (4.4e-11; 6.4e-11 with the row kernels alone) and a principal
axis component of 0.029 (1.4e-12; 4.6e-12 before); the default (noise-free) run: the same
decisions, its intervals within 5e-11 (the row kernels alone: 1.4e-10), its round-off
quantities (variance factor, zero unbalance and crank offset) move as with the row
kernels (:mod:`estimator.compiled_rows`).
"""

from __future__ import annotations

import numpy as np

from estimator.kinematics import RigidFit
from estimator.row_kernels import jit


def fitted_arrays(
    fit: RigidFit, amplitudes: np.ndarray, columns: np.ndarray, compiled: bool = True
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The readings (n, k, u) of the ``columns`` of ``amplitudes`` (n, k, n_frame_ch)
    complex, m/s^2; :meth:`RigidFit.fit_arrays` of them (x (n, k, 6) complex, residual
    RMS, relative residual, noise variance (n, k)) and their mean square per order
    (n, k), (m/s^2)^2. ``compiled=False``: the loop run by the interpreter (tests)."""
    n_f, n_o, _ = amplitudes.shape
    u = len(columns)
    readings = np.empty((n_f, n_o, u), complex)
    x = np.empty((n_f, n_o, 6), complex)
    out = np.empty((4, n_f, n_o))
    sw, pinv, jw = fit.sw, fit.pinv, fit.jw
    (jit(fit_pairs) if compiled else fit_pairs)(
        np.ascontiguousarray(amplitudes, complex),
        np.asarray(columns, np.int64),
        np.ascontiguousarray(sw, float),
        np.ascontiguousarray(pinv, float),
        np.ascontiguousarray(jw, float),
        float(max(sw.size - fit.rank, 1)),
        float(fit.mean_w),
        readings,
        x,
        out,
    )
    return readings, x, out[0], out[1], out[2], out[3]


def fit_pairs(
    amps: np.ndarray,
    cols: np.ndarray,
    sw: np.ndarray,
    pinv: np.ndarray,
    jw: np.ndarray,
    dof: float,
    mean_w: float,
    readings: np.ndarray,
    x: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`fitted_arrays`' loop: ``out`` gets the residual RMS, the relative residual,
    the noise variance and the power, in that order."""
    n_f, n_o = amps.shape[0], amps.shape[1]
    u = cols.shape[0]
    y_re = np.empty(u)
    y_im = np.empty(u)
    for f in range(n_f):
        for o in range(n_o):
            signal = 0.0
            for c in range(u):
                a = amps[f, o, cols[c]]
                readings[f, o, c] = a
                signal += a.real * a.real + a.imag * a.imag
                y_re[c] = a.real * sw[c]  # the weighted readings
                y_im[c] = a.imag * sw[c]
            for p in range(6):  # x = pinv y
                re = 0.0
                im = 0.0
                for c in range(u):
                    re += pinv[p, c] * y_re[c]
                    im += pinv[p, c] * y_im[c]
                x[f, o, p] = complex(re, im)
            resid_ss = 0.0
            for c in range(u):  # y - jw x
                re = 0.0
                im = 0.0
                for p in range(6):
                    re += jw[c, p] * x[f, o, p].real
                    im += jw[c, p] * x[f, o, p].imag
                re = y_re[c] - re
                im = y_im[c] - im
                resid_ss += re * re + im * im
            residual_rms = np.sqrt(resid_ss / dof / mean_w)
            signal_rms = np.sqrt(signal / u)
            out[0, f, o] = residual_rms
            out[1, f, o] = residual_rms / signal_rms if signal_rms > 0 else 0.0
            out[2, f, o] = resid_ss / (2 * dof)
            out[3, f, o] = signal / u


def bend_excess(
    seq_w: np.ndarray,
    chained: np.ndarray,
    noise: np.ndarray,
    trace: float,
    bend_noise: float,
    compiled: bool = True,
) -> np.ndarray:
    """:meth:`estimator.gating.OrderGates.curvature`'s arithmetic: (n, k) the relative
    second difference of Omega' (``seq_w`` (2 + n, k, 3) complex: the two before and the
    n frames') beyond ``bend_noise`` times its noise (``noise`` (n, k) the fits' noise
    variances, ``trace`` that of the fit's Omega' covariance), 0 where not ``chained``
    (n,) or not finite."""
    out = np.empty(noise.shape)
    (jit(bend_pairs) if compiled else bend_pairs)(
        np.ascontiguousarray(seq_w, complex),
        np.asarray(chained, np.bool_),
        np.ascontiguousarray(noise, float),
        float(trace),
        float(bend_noise),
        out,
    )
    return out


def bend_pairs(
    seq_w: np.ndarray,
    chained: np.ndarray,
    noise: np.ndarray,
    trace: float,
    bend_noise: float,
    out: np.ndarray,
) -> None:
    """:func:`bend_excess`' loop."""
    n_f, n_o = noise.shape
    for f in range(n_f):
        for o in range(n_o):
            size = 0.0
            bend = 0.0
            for i in range(3):
                w = seq_w[f + 2, o, i]
                d = w - 2 * seq_w[f + 1, o, i] + seq_w[f, o, i]
                size += w.real * w.real + w.imag * w.imag
                bend += d.real * d.real + d.imag * d.imag
            size = max(np.sqrt(size), 1e-300)
            sigma = np.sqrt(2 * noise[f, o] * trace) / size
            excess = np.sqrt(bend) / size - bend_noise * sigma
            out[f, o] = excess if chained[f] and np.isfinite(excess) and excess > 0 else 0.0


def order_screen(
    rpm: np.ndarray,
    orders: np.ndarray,
    force: np.ndarray,
    moment: np.ndarray,
    curvature: np.ndarray,
    power: np.ndarray,
    leak: np.ndarray,
    near_hz: float,
    max_curvature: float,
    excited: np.ndarray,
    compiled: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`estimator.gating.OrderGates.screen_orders`' arithmetic: ``why`` (n, k) int
    and the error ``floor`` (n, k), (m/s^2)^2, from the excitation ``force`` and
    ``moment`` (n, k, 3) complex at ``rpm`` (n,), the ``curvature`` and ``power`` (n, k),
    ``leak`` (k, k) the neighbour leakage's shares squared, ``near_hz`` the frequency
    below which an order is near the modes (-inf: never), and ``excited`` (n, k) the
    orders excited whatever their known excitation (the unbalance's order 1)."""
    why = np.empty(curvature.shape, np.int64)
    floor = np.empty(curvature.shape)
    (jit(screen_pairs) if compiled else screen_pairs)(
        np.asarray(rpm, float),
        np.asarray(orders, float),
        np.ascontiguousarray(force, complex),
        np.ascontiguousarray(moment, complex),
        np.ascontiguousarray(curvature, float),
        np.ascontiguousarray(power, float),
        np.ascontiguousarray(leak, float),
        float(near_hz),
        float(max_curvature),
        np.ascontiguousarray(excited, np.bool_),
        why,
        floor,
    )
    return why, floor


def screen_pairs(
    rpm: np.ndarray,
    orders: np.ndarray,
    force: np.ndarray,
    moment: np.ndarray,
    curvature: np.ndarray,
    power: np.ndarray,
    leak: np.ndarray,
    near_hz: float,
    max_curvature: float,
    excited: np.ndarray,
    why: np.ndarray,
    floor: np.ndarray,
) -> None:
    """:func:`order_screen`'s loop."""
    n_f, n_o = curvature.shape
    level = np.empty(n_o)
    bent = np.empty(n_o)
    for f in range(n_f):
        top = -np.inf
        for o in range(n_o):
            sf = 0.0
            sm = 0.0
            for i in range(3):
                sf += abs(force[f, o, i]) ** 2
                sm += abs(moment[f, o, i]) ** 2
            level[o] = 0.3 * np.sqrt(sf) + np.sqrt(sm)
            if level[o] > top or np.isnan(level[o]):  # (a NaN stays, as in np.max)
                top = level[o]
            bent[o] = curvature[f, o] ** 2 * power[f, o]
        limit = 1e-6 * (top if top >= 1e-300 or np.isnan(top) else 1e-300)
        for o in range(n_o):
            leak_var = 0.0
            for j in range(n_o):
                leak_var += leak[o, j] * bent[j]
            floor[f, o] = bent[o] + leak_var
            if not (level[o] > limit or excited[f, o]):
                why[f, o] = 1
            elif orders[o] * rpm[f] / 60.0 < near_hz:
                why[f, o] = 2
            elif curvature[f, o] > max_curvature:
                why[f, o] = 3
            elif leak_var > max_curvature**2 * power[f, o]:
                why[f, o] = 4
            else:
                why[f, o] = 0
