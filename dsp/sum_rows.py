"""The row that holds a segment's sums (:mod:`dsp.sums`), and the window sums read from rows.

The window of frame ``j`` (``c_j +- 360 deg``, ``n = frames_per_rev``) is

    (a - d)[j - n] + sum_{m = j-n+1}^{j+n-1} a[m] + d[j + n]

(rising taper, full weight, falling taper). Rows are kept in a dict keyed by ``m``
so an hour-long tacho dropout costs nothing. A row is one float64 vector holding all
of a segment's sums (:func:`unpack` gives named views), so that adding two partial
rows, or stacking a window's rows, is one array operation; rows are never modified.
The compiled path adds a window's rows in :func:`add_windows` and makes a group's
amplitudes in :func:`amplitudes_of_windows` (the same bits).
"""

from __future__ import annotations

import functools

import numpy as np

# One float64 vector per segment, in three blocks (see unpack):
#   plain:   a (n_ch x no complex, as Re/Im pairs), wa, s2 (n_ch), n2
#   taper:   d (n_ch x no complex), wd, then zeros where plain has s2 and n2
#   clip:    (n_ch) the number of clipped samples
# so that a window, (a - d)[j-n] + a[j-n+1 .. j+n-1] + d[j+n], is the same few
# operations on whole blocks for every sum (the zeros leave s2, n2 summed over
# segments j-n .. j+n-1).
Row = np.ndarray


def _block(n_ch: int, no: int) -> int:
    return 2 * n_ch * no + n_ch + 2


def row_size(n_ch: int, no: int) -> int:
    """Length of a :data:`Row` for ``n_ch`` channels and ``no`` orders."""
    return 2 * _block(n_ch, no) + n_ch


def unpack(
    w: np.ndarray, n_ch: int, no: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Views of the sums in rows ``w`` (s, :func:`row_size`), last axis contiguous.

    Returns ``a, d`` (s, n_ch, no) complex, ``s2`` (s, n_ch), ``n2, wa, wd`` (s,)
    and ``clip`` (s, n_ch), the number of clipped samples (adding rows adds counts).
    """
    h = _block(n_ch, no)
    a, wa, s2, n2 = plain_block(w[:, :h], n_ch, no)
    d, wd, _, _ = plain_block(w[:, h : 2 * h], n_ch, no)
    return a, d, s2, n2, wa, wd, w[:, 2 * h :]


def plain_block(
    block: np.ndarray, n_ch: int, no: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``a`` (s, n_ch, no) complex, ``wa`` (s,), ``s2`` (s, n_ch), ``n2`` (s,) of a plain block."""
    k = 2 * n_ch * no
    a = block[:, :k].view(complex).reshape(block.shape[0], n_ch, no)
    return a, block[:, k], block[:, k + 1 : k + 1 + n_ch], block[:, k + 1 + n_ch]


def window_sums(
    rows: dict[int, Row], j0: int, j1: int, n: int, n_ch: int, no: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Window sums of frames ``j0 .. j1`` (inclusive).

    Returns
    -------
    s : (f, n_ch, n_orders) complex
        ``sum w x exp(-i h phi) q``.
    w : (f,)
        ``sum w q`` (rad; 720 deg up to the quadrature error).
    mean_square : (f, n_ch)
        Mean square of the samples of segments ``j - n .. j + n - 1``.
    clipped : (f, n_ch) bool
    """
    rows_w = window_rows(rows, j0, j1, n, n_ch, no)
    h = _block(n_ch, no)
    plain, taper, clip = rows_w[:, :h], rows_w[:, h : 2 * h], rows_w[:, 2 * h :]
    f = j1 - j0 + 1
    last = 2 * n  # offset of segment j + n from segment j - n
    # rising taper, full weight, falling taper: every sum of the row at once
    total = plain[:f] - taper[:f]
    count = clip[:f].copy()
    for k in range(1, last):
        total += plain[k : k + f]
        count += clip[k : k + f]
    total += taper[last : last + f]
    count += clip[last : last + f]
    s, w, p, cnt = plain_block(total, n_ch, no)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_square = p / cnt[:, None]
    return s, w, mean_square, count > 0


def window_rows(rows: dict[int, Row], j0: int, j1: int, n: int, n_ch: int, no: int) -> np.ndarray:
    """The rows of segments ``j0 - n .. j1 + n`` stacked (zeros where a segment has none)."""
    zero = _zero_row(row_size(n_ch, no))
    return np.array([rows.get(m, zero) for m in range(j0 - n, j1 + n + 1)])  # 3x np.stack


@functools.cache
def _zero_row(size: int) -> np.ndarray:
    """A row of zeros, made once per size (read-only: only ever copied)."""
    zero = np.zeros(size)
    zero.setflags(write=False)
    return zero


def add_windows(
    rows_w: np.ndarray, n: int, h: int, n_ch: int, total: np.ndarray, mean_square: np.ndarray
) -> None:
    """:func:`window_sums` from the stacked rows on, frame by frame, for the compiled path
    (:func:`dsp.kernels.window_sums`; plain loops, run uncompiled by the tests).

    ``rows_w`` (f + 2n, :func:`row_size`), ``h`` the length of a plain block; writes the
    window's plain block ``total`` (f, h) and the clip counts into ``total[:, h:]``
    (f, n_ch), and ``mean_square`` (f, n_ch). The same additions in the same order as
    :func:`window_sums`'s array operations, element by element, so the same bits.
    """
    f = total.shape[0]
    last = 2 * n
    k = h - n_ch - 2  # offset of wa in the plain block (after a: 2 n_ch no)
    for i in range(f):
        # row after row into the frame's own sums (slices indexed from 0: numba checks no
        # index for wrap-around and vectorises over the columns; each column still adds
        # its rows in the order above, so the same bits)
        acc, cnt = total[i, :h], total[i, h : h + n_ch]
        first, minus = rows_w[i, :h], rows_w[i, h : 2 * h]
        for c in range(h):
            acc[c] = first[c] - minus[c]
        clips = rows_w[i, 2 * h : 2 * h + n_ch]
        for c in range(n_ch):
            cnt[c] = clips[c]
        for m in range(1, last + 1):
            if m < last:
                plain = rows_w[i + m, :h]
                for c in range(h):
                    acc[c] += plain[c]
            clips = rows_w[i + m, 2 * h : 2 * h + n_ch]
            for c in range(n_ch):
                cnt[c] += clips[c]
        plus = rows_w[i + last, h : 2 * h]
        for c in range(h):
            acc[c] += plus[c]
        # s2 / n2 as numpy divides (numba's "/" raises on a zero count, numpy gives inf or nan)
        n2 = total[i, k + 1 + n_ch]
        for c in range(n_ch):
            p = total[i, k + 1 + c]
            if n2 != 0.0:
                mean_square[i, c] = p / n2
            elif p != p or p == 0.0:
                mean_square[i, c] = np.nan
            else:
                mean_square[i, c] = np.inf if p > 0.0 else -np.inf


def amplitudes_of_windows(
    total: np.ndarray,
    mean_square: np.ndarray,
    h: int,
    no: int,
    usable: np.ndarray,
    cols: np.ndarray,
    x: np.ndarray,
    ms: np.ndarray,
    ok: np.ndarray,
    nan_rows: np.ndarray,
    clip_rows: np.ndarray,
) -> None:
    """A group's amplitudes ``2 s / w`` from :func:`add_windows`'s sums, with its flags, as
    :func:`dsp.window_amplitudes.window_amplitudes` makes them without holes (plain loops
    for the compiled path, :func:`dsp.kernels.group_amplitudes`).

    ``total`` (f, h + n_ch) and ``mean_square`` (f, n_ch) as :func:`add_windows` writes
    them, ``usable`` (f,) the frames whose tacho and group are good, ``cols`` (n_ch,) the
    group's columns among all channels; writes those columns of ``x`` (f, no, n_all)
    complex, ``ms`` and ``ok`` (f, n_all), and ``nan_rows``, ``clip_rows`` (f,): a usable
    channel of the frame had a non-finite amplitude, clipped samples. The division is
    numpy's ``(2.0 * s) / w`` of a complex by a real, step by step (``w`` made complex:
    Smith's quotient with a zero imaginary part), so the same bits.
    """
    f = total.shape[0]
    n_ch = cols.size
    k = h - n_ch - 2  # offset of wa in the plain block
    for i in range(f):
        w = total[i, k]
        nan_rows[i] = False
        clip_rows[i] = False
        for c in range(n_ch):
            col = cols[c]
            if not usable[i]:
                for o in range(no):
                    x[i, o, col] = complex(np.nan, 0.0)
                ms[i, col] = np.nan
                ok[i, col] = False
                continue
            finite = True
            for o in range(no):
                sr = total[i, 2 * (c * no + o)]
                si = total[i, 2 * (c * no + o) + 1]
                tr = 2.0 * sr - 0.0 * si
                ti = 2.0 * si + 0.0 * sr
                if w != w:
                    xr = np.nan
                    xi = np.nan
                elif w == 0.0:  # numpy divides by |w|: inf or nan, not an error
                    xr = np.nan if tr != tr or tr == 0.0 else (np.inf if tr > 0.0 else -np.inf)
                    xi = np.nan if ti != ti or ti == 0.0 else (np.inf if ti > 0.0 else -np.inf)
                else:
                    rat = 0.0 / w
                    scl = 1.0 / (w + 0.0 * rat)
                    xr = (tr + ti * rat) * scl
                    xi = (ti - tr * rat) * scl
                x[i, o, col] = complex(xr, xi)
                finite = finite and np.isfinite(xr) and np.isfinite(xi)
            ms[i, col] = mean_square[i, c]
            clipped = total[i, h + c] > 0
            ok[i, col] = finite and not clipped
            nan_rows[i] = nan_rows[i] or not finite
            clip_rows[i] = clip_rows[i] or clipped


def drop_before(rows: dict[int, Row], m: int) -> dict[int, Row]:
    """The rows from segment ``m`` on (``rows`` itself when it holds none before: the
    maps are never modified, only replaced)."""
    if not rows or min(rows) >= m:
        return rows
    return {k: v for k, v in rows.items() if k >= m}
