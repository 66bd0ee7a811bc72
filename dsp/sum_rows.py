"""The row that holds a segment's sums (:mod:`dsp.sums`), and the window sums read from rows.

The window of frame ``j`` (``c_j +- 360 deg``, ``n = frames_per_rev``) is

    (a - d)[j - n] + sum_{m = j-n+1}^{j+n-1} a[m] + d[j + n]

(rising taper, full weight, falling taper). Rows are kept in a dict keyed by ``m``
so an hour-long tacho dropout costs nothing. A row is one float64 vector holding all
of a segment's sums (:func:`unpack` gives named views), so that adding two partial
rows, or stacking a window's rows, is one array operation; rows are never modified.
"""

from __future__ import annotations

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
    a, wa, s2, n2 = _plain(w[:, :h], n_ch, no)
    d, wd, _, _ = _plain(w[:, h : 2 * h], n_ch, no)
    return a, d, s2, n2, wa, wd, w[:, 2 * h :]


def _plain(
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
    zero = np.zeros(row_size(n_ch, no))
    rows_w = np.array([rows.get(m, zero) for m in range(j0 - n, j1 + n + 1)])  # 3x np.stack
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
    s, w, p, cnt = _plain(total, n_ch, no)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_square = p / cnt[:, None]
    return s, w, mean_square, count > 0


def drop_before(rows: dict[int, Row], m: int) -> dict[int, Row]:
    """The rows from segment ``m`` on."""
    return {k: v for k, v in rows.items() if k >= m}
