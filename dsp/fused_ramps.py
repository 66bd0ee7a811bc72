"""The leakage correction's coupling applied frame by frame, with eight float64 lanes.

Compiled helper of :func:`dsp.leakage.ramp_correction` (imported only where the compiled
path runs, :data:`dsp.kernels.USE`: it imports numba). The numpy path applies the
coupling as ``same[phase] @ b + image[phase] @ conj(b)``: two stacked complex matrix
products, which numpy hands to BLAS one frame at a time (50 calls a step of 25 frames,
each tiny), about 40-57 us for the tracked channels and 40-50 us for the spectrum
channel per step, more than their arithmetic. Here the two products are one real
matrix (:func:`dsp.leakage.real_coupling`, ``2 n_int`` square, its columns padded to a
multiple of eight) times ``(Re b, Im b)``, a column of eight lanes at a time.

Measured (issue 24, load 5-6 on 2 cores): per step of 25 frames, the tracked channels'
correction (8 half orders, 9 channels) 45-58 us with numpy's products, 5.8 us of CPU
here; the spectrum channel's (19 orders) 40-54 us and 2.2 us; the run's dsp stage
compiled (60 s log, CPU best of 5, interleaved with main) 0.101-0.103 s -> 0.0945-0.098 s
a minute, with the two-block spectrum sums of :mod:`dsp.spectrum_lanes`.

Not the numpy path's bits: the products are summed in another order (and with fused
multiply-adds), within a few 1e-16 of the correction's largest element (measured on
random couplings and ramps; ``tests/dsp/test_kernels.py`` holds it to 1e-12), and the
frames move by that much of a correction that is itself a small part of an amplitude
(the run's log: by 1.7e-15 of a frame's largest element). What moves beyond 1e-12 in the
results is rounding noise: on ``ptinertia run`` (compiled, against the compiled path
before) the noise-free run's figures of nothing (an unbalance of 3e-10 kg m, a crank
offset of 5e-7 deg, the half-order residual ratio and the variance factor; the crank
offset's std by 2.2e-12), on ``--realistic`` the half-order residual ratio by 3.7e-11, a
principal axis' 0.029 component by 3.9e-12 and the crank offset by 2.3e-12: the
envelope the compiled path already had against numpy (4.4e-11, 1.4e-12 there).
numba's cache watches this file only: the hash of :mod:`dsp.vec8`, which it inlines, is
written in it (checked by ``tests/dsp/test_kernels.py``), so an edit of vec8 rebuilds it.
"""

from __future__ import annotations

from numba import njit

from dsp.vec8 import vadd, vfma, vload, vsplat, vstore, vzero

HELPERS = ("vec8.py",)
HELPERS_SHA256 = "d5b248d7803074a1bceacba3229e2f17bae7537116e76ac70f400793a0fa8ca4"


@njit(cache=True, nogil=True)
def apply_ramps(x, b, phase, coupling, m8, out, acc):
    """``out = x - corr`` (f, n_int, n_ch) complex, ``corr = same[phase] @ b + image[phase]
    @ conj(b)`` for the ramps ``b`` (f, n_int, n_ch) complex, frames at ``phase`` (f,) of
    the coupling's period. ``coupling`` is :func:`dsp.leakage.real_coupling` flattened:
    per phase ``2 n_int`` rows of ``m8`` columns, row ``k`` what ``Re b_k`` (``k < n_int``)
    or ``Im b_(k - n_int)`` adds to the real parts (columns ``0 .. n_int - 1``) and the
    imaginary parts (``n_int .. 2 n_int - 1``) of the frame's orders. ``acc`` (m8,) scratch.
    """
    f, n_int, n_ch = x.shape
    rows = 2 * n_int * m8  # one phase's block
    for i in range(f):
        base = phase[i] * rows
        for c in range(n_ch):
            for g in range(0, m8, 16):
                # two columns of lanes at a time, the real parts' and the imaginary parts'
                # terms of each in chains of their own: four independent chains
                two = g + 8 < m8
                a_re, a_im, b_re, b_im = vzero(), vzero(), vzero(), vzero()
                for k in range(n_int):
                    bk = b[i, k, c]
                    at = base + k * m8 + g
                    br, bi = vsplat(bk.real), vsplat(bk.imag)
                    a_re = vfma(vload(coupling, at), br, a_re)
                    a_im = vfma(vload(coupling, at + n_int * m8), bi, a_im)
                    if two:
                        b_re = vfma(vload(coupling, at + 8), br, b_re)
                        b_im = vfma(vload(coupling, at + 8 + n_int * m8), bi, b_im)
                vstore(acc, g, vadd(a_re, a_im))
                if two:
                    vstore(acc, g + 8, vadd(b_re, b_im))
            for h in range(n_int):
                out[i, h, c] = x[i, h, c] - complex(acc[h], acc[n_int + h])
