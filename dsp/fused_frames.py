"""Frame assembly's compiled loops chained in one call each, for the compiled path.

Imported only where the compiled path runs (:data:`dsp.kernels.USE`: it imports numba).
A step of the frame assembly (:mod:`dsp.assemble`, 120 a minute of the run's log) called
two kernels back to back in two places, each call with its own argument checks and its
own output arrays made in numpy:

* :func:`group_windows`: a group's window sums (:func:`dsp.sum_rows.add_windows`) and
  its amplitudes and flags from them (:func:`dsp.sum_rows.amplitudes_of_windows`), for
  the tracked channels and for the spectrum channel;
* :func:`correct_ramps`: the leakage correction's ramps (:func:`dsp.ramp_slopes.ramp_slopes`)
  and its coupling applied (:func:`dsp.fused_ramps.apply_ramps`), for both as well.

Here each pair is one call that runs the same compiled loops in turn, so the same bits
as the two calls (the same functions, compiled with the same options). numba's cache
watches this file only: the hash of the files whose functions it inlines is written in
it (checked by ``tests/dsp/test_kernels.py``), so an edit of one of them rebuilds it.

Measured (issue 24; the run's 60 s log compiled, its 120 steps captured and replayed,
CPU best of 9, interleaved with the code before): the leakage correction of the tracked
channels 2.75 -> 2.3-2.5 ms a minute (load 3.5-4), the spectrum channel's sums and
correction 4.5 -> 4.1 ms; with :mod:`dsp.window_times` and one parity per settled batch,
a step's assembly (:func:`dsp.assemble._batch`) 24 -> 20 ms a minute (load 10).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from dsp.fused_ramps import apply_ramps
from dsp.ramp_slopes import ramp_slopes
from dsp.sum_rows import add_windows, amplitudes_of_windows

HELPERS = ("fused_ramps.py", "ramp_slopes.py", "sum_rows.py", "vec8.py")
HELPERS_SHA256 = "b78a48fd02ffd667f9473591d564e6677ce75034620ee89be20d26466d6e1ea4"

# the loops as dsp.kernels compiles them (cache=True, nogil=True): the same machine code
_add_windows = njit(cache=True, nogil=True)(add_windows)
_amplitudes_of_windows = njit(cache=True, nogil=True)(amplitudes_of_windows)
_ramp_slopes = njit(cache=True, nogil=True)(ramp_slopes)


@njit(cache=True, nogil=True)
def group_windows(rows_w, n, h, no, usable, cols, x, ms, ok, nan_rows, clip_rows):
    """A group's window sums and amplitudes from its stacked rows ``rows_w`` (f + 2 n,
    :func:`dsp.sum_rows.row_size`; :func:`dsp.sum_rows.window_rows`), ``h`` the length of
    a plain block: writes ``x``, ``ms``, ``ok``, ``nan_rows``, ``clip_rows`` as
    :func:`dsp.sum_rows.amplitudes_of_windows` does; returns 1 if a usable frame had a
    non-finite amplitude, plus 2 if one had clipped samples (0: neither)."""
    f = rows_w.shape[0] - 2 * n
    n_ch = cols.size
    total = np.empty((f, h + n_ch))
    mean_square = np.empty((f, n_ch))
    _add_windows(rows_w, n, h, n_ch, total, mean_square)
    _amplitudes_of_windows(total, mean_square, h, no, usable, cols, x, ms, ok, nan_rows, clip_rows)
    code = 0
    for i in range(f):
        if nan_rows[i]:
            code |= 1
        if clip_rows[i]:
            code |= 2
    return code


@njit(cache=True, nogil=True)
def correct_ramps(all_j, all_c, all_x, x, js, chains, tacho_bad, period, n_back, coupling, m8,
                  out, good):  # fmt: skip
    """The ramps of frames ``js`` (:func:`dsp.ramp_slopes.ramp_slopes`: ``all_j``,
    ``all_c``, ``all_x``, ``chains``, ``tacho_bad``, ``period``, ``n_back`` as there; writes
    ``good``) and ``out = x - corr`` with their coupling (:func:`dsp.fused_ramps.apply_ramps`:
    ``coupling``, ``m8`` as there) at the frames' phase ``js % period``; ``x`` the new
    frames' raw amplitudes (f, n_int, n_ch), ``all_x``'s last ``f``."""
    f, n_int, n_ch = x.shape
    b = np.empty((f, n_int, n_ch), np.complex128)
    _ramp_slopes(all_j, all_c, all_x, js, chains, tacho_bad, period, n_back, b, good)
    phase = np.empty(f, np.int64)
    for i in range(f):
        phase[i] = js[i] % period
    apply_ramps(x, b, phase, coupling, m8, out, np.empty(m8))
