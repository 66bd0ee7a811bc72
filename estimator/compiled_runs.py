"""The compiled arithmetic of a run of frames fitted alike (``PTINERTIA_NUMBA=1``).

:func:`fitted_arrays` does, in one loop over a run's (frame, order) pairs, what
:func:`estimator.fitted_runs.fit_run` otherwise does in a dozen numpy calls: gather the
used channels' amplitudes, fit the rigid motion (:meth:`estimator.kinematics.RigidFit.
fit_arrays`) and take the readings' mean square per order. The numpy functions stay the
default and the reference; :func:`estimator.row_kernels.jit` compiles the loop
(``cache=True``, ``nogil=True``) on its first call, so the default path never imports
numba.

Why: a run is a dozen frames of 3 orders by 9 channels, and at that size numpy's
per-call overhead, not the arithmetic, is what the fit costs (issue 24: the fit,
its gather and the power 28-45 us a 12-frame run in numpy calls against a few us here).

How close: the gather is a copy (the same readings); the fit's two matrix products are
summed in the loop's order where numpy takes BLAS's, so the motions, residuals and
power agree within a few units in the last place (tested within 1e-13 relative);
``ptinertia run --rerun off`` and ``--realistic``: compiled against compiled before
within 1e-12 relative on every estimate (the figures in the commit).
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
