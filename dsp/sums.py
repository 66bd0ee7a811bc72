"""Per-segment sums of the angle-domain DFT: samples in, one row per segment out.

Segment ``m`` of a group covers ``[c_m - tau/2, c_(m+1) - tau/2)`` of crank angle
(``c_m = m * 360 / frames_per_rev`` deg): the taper zone around ``c_m`` and
the flat stretch after it. For each segment the tracker keeps

* ``a``: ``sum x exp(-i h phi) q`` over the whole segment (``q = omega dt``, rad),
* ``d``: the same over the zone, weighted by the falling taper ``1 - rise``,
* ``wa``, ``wd``: ``sum q`` and ``sum q (1 - rise)`` (the normalisation),
* ``s2``, ``n2``: ``sum x^2`` and the sample count over the samples whose grid
  index is a multiple of :data:`dsp.sum_sets.POWER_STRIDE` (the mean square behind the
  ``leakage`` figure: a quarter of the samples estimate it well and cost a quarter),
* ``clip``: a sample at or above the clip level,

so that the window of frame ``j`` is a sum of whole rows (:mod:`dsp.sum_rows`, which
holds the row layout and the window sums). Each sample is touched once (twice in a
zone).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

from dsp import kernels
from dsp.sum_rows import Row, row_size, unpack
from dsp.sum_sets import (
    Cut,
    Segments,
    SetSums,
    SumSet,
    base_parts,
    half_parts,
    numpy_sums,
    zones,
)


def add_samples(
    rows: dict[int, Row],
    phi: np.ndarray,
    omega: np.ndarray,
    x: Sequence[np.ndarray],
    first_index: int,
    rate_hz: float,
    k2: np.ndarray,
    frames_per_rev: int,
    taper_deg: float,
    clip_level: float | None,
) -> dict[int, Row]:
    """Add consecutive samples to their segments.

    Parameters
    ----------
    rows : dict
        Segment ``m`` -> :data:`Row`; not modified (a new dict is returned).
    phi, omega : (n,) float64
        Crank angle (rad, increasing) and speed (rad/s) of each sample.
    x : sequence of (n_ch, n_i) float64, sum of n_i = n
        The tracked channels, in the pieces (stream blocks) the samples came in,
        not copied together (a megabyte per 0.5 s at 25.6 kHz); a segment two
        pieces share gets a partial sum from each, so the sums round exactly as
        with one call per piece.
    first_index : int
        Grid index of the first sample (picks the samples of the mean square).
    rate_hz : float
    k2 : (n_orders,) int64
        Twice the orders, ascending (0 is the mean: its carrier is ``q``).
    frames_per_rev, taper_deg : int, float
    clip_level : float or None
    """
    (out,) = add_sample_sets(
        [SumSet(rows, x, k2, clip_level)], phi, omega, first_index, rate_hz, frames_per_rev,
        taper_deg,
    )  # fmt: skip
    return out


def add_sample_sets(
    sets: Sequence[SumSet],
    phi: np.ndarray,
    omega: np.ndarray,
    first_index: int,
    rate_hz: float,
    frames_per_rev: int,
    taper_deg: float,
    compiled: bool | None = None,
) -> list[dict[int, Row]]:
    """:func:`add_samples` for several sets of channels and orders on the same samples.

    The segments, the carriers (up to the highest order of any set) and the taper
    weights are computed once; each set gets the rows it would get from a call of
    its own, bit for bit (its carriers and zone weights laid out as in that call).
    ``compiled``: the carriers and sums by :func:`dsp.kernels.piece_sums` (one pass,
    the orders of each set only; within 1e-12 of this numpy reference, see there);
    None: :data:`dsp.kernels.USE`. (:func:`dsp.segments.accumulate` calls its three
    steps itself: groups on one sample clock share the cut, and the tracked channels'
    packed rows are checked before they are merged.)
    """
    compiled = kernels.USE if compiled is None else compiled
    sizes = [xi.shape[1] for xi in sets[0].x]
    cut = cut_samples(phi, omega, sizes, rate_hz, frames_per_rev, taper_deg, compiled)
    packed = packed_rows(sets, cut, first_index, frames_per_rev, compiled)
    return [merge_rows(st.rows, cut.seg.mu, w) for st, w in zip(sets, packed, strict=True)]


def packed_rows(
    sets: Sequence[SumSet], cut: Cut, first_index: int, frames_per_rev: int, compiled: bool
) -> list[np.ndarray]:
    """Every set's sums of the segments of ``cut``, packed: (seg, row_size) per set, a
    segment split between pieces once per piece (:func:`merge_rows` adds them)."""
    if compiled:
        return kernels.compiled_rows(sets, cut, first_index, frames_per_rev)
    sums, wa, wd = numpy_sums(sets, cut, first_index)
    return [
        _packed(st.k2, cut.seg.mu, set_sums, wa, wd, 2 * frames_per_rev)
        for st, set_sums in zip(sets, sums, strict=True)
    ]


def merge_rows(rows: dict[int, Row], mu: np.ndarray, w: np.ndarray) -> dict[int, Row]:
    """``rows`` (not modified) with the packed rows ``w`` of segments ``mu`` added, in order."""
    out = dict(rows)
    for mm, row in zip(mu.tolist(), w, strict=True):
        out[mm] = out[mm] + row if mm in out else row
    return out


def cut_samples(
    phi: np.ndarray,
    omega: np.ndarray,
    sizes: Sequence[int],
    rate_hz: float,
    frames_per_rev: int,
    taper_deg: float,
    compiled: bool,
) -> Cut:
    """What every set's sums on these samples share (:class:`dsp.sum_sets.Cut`): the
    segments of pieces of ``sizes`` samples, ``q``, the angles from the frame angles and
    the carriers' base (and on the numpy path the zones). Arguments as
    :func:`add_sample_sets`'s."""
    spacing = 2.0 * math.pi / frames_per_rev
    half = 0.5 * math.radians(taper_deg)
    cuts = list(itertools.accumulate(sizes, initial=0))  # where each piece begins
    # each piece cut into segments as a call of its own would: a segment split between
    # two pieces appears twice, and its parts are added in order at the end
    falls: tuple[np.ndarray, np.ndarray] | None = None
    if compiled:
        # q, the same segments and angles from one compiled pass, and the zones' taper
        # made once for every set (dsp.kernels.segment_cuts)
        mu, starts, ends, zone_end, per_piece, delta, half32, c, q, falls = kernels.segment_cuts(
            phi, omega, rate_hz, np.array(cuts, dtype=np.int64), spacing, half
        )  # fmt: skip
        cos_half, sin_half = half_parts(half32)
    else:
        q = omega * (1.0 / rate_hz)
        parts = [_segments(phi, p0, p1, spacing, half) for p0, p1 in itertools.pairwise(cuts)]
        if len(parts) == 1:
            mu, starts, ends, zone_end = parts[0]
        else:
            mu, starts, ends, zone_end = (np.concatenate(col) for col in zip(*parts, strict=True))
        per_piece = [part[0].size for part in parts]  # segments of each piece
        c = mu * spacing  # frame angles c_m
        # carriers about each segment's own frame angle c_m (exact rotation applied below):
        # the same sample gets the same carrier whatever the block cut, and the angle stays small
        delta = phi - np.repeat(c, ends - starts)
        cos_half, sin_half = base_parts(delta)
    seg = Segments(mu, starts, ends, zone_end, cuts, per_piece, c, half)
    zoned = None if compiled else zones(seg, phi, q)
    return Cut(seg, phi, q, delta, cos_half, sin_half, zoned, falls)


def _packed(
    k2: np.ndarray, mu: np.ndarray, sums: SetSums, wa: np.ndarray, wd: np.ndarray, period: int
) -> np.ndarray:
    """One set's sums (:func:`dsp.sum_sets.numpy_sums`) as rows (seg, row_size)."""
    a, d, s2, n2, clip, re, im = sums
    no = k2.size
    n_ch = a.shape[1]
    # back to complex, rotated by the frame angle: exp(-i h c_m), reduced exactly with
    # integers (the carriers hold exp(-i h (phi - c_m)))
    rot = np.exp(-2j * np.pi * ((mu[:, None] * k2[None, :]) % period) / period)[:, None, :]
    if re == list(range(no)):  # Re rows then Im rows
        ac = (a[..., :no] + 1j * a[..., no:]) * rot
        dc = (d[..., :no] + 1j * d[..., no:]) * rot
    else:  # the rows of the orders in the carriers shared with the tracked channels
        ac = (a[..., re] + 1j * a[..., im]) * rot
        dc = (d[..., re] + 1j * d[..., im]) * rot
    w = np.zeros((mu.size, row_size(n_ch, no)))
    w_a, w_d, w_s2, w_n2, w_wa, w_wd, w_clip = unpack(w, n_ch, no)
    w_a[:] = ac
    w_d[:] = dc
    w_s2[:] = s2
    w_n2[:] = n2
    w_wa[:] = wa
    w_wd[:] = wd
    w_clip[:] = clip
    return w


def _segments(
    phi: np.ndarray, p0: int, p1: int, spacing: float, half: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Segments ``m`` met by samples ``p0 .. p1-1``, their first and end sample, and zone ends.

    A segment begins at ``c_m - tau/2``, its zone ends at ``c_m + tau/2``; the first
    sample's segment is that of ``floor((phi + tau/2) / spacing)``.
    """
    piece = phi[p0:p1]
    m0 = math.floor((piece[0] + half) / spacing)
    m1 = math.floor((piece[-1] + half) / spacing)
    mu = np.arange(m0, m1 + 1)
    c = mu * spacing
    starts = piece.searchsorted(c - half, side="left")
    starts[0] = 0
    starts += p0
    ends = np.empty_like(starts)
    ends[:-1] = starts[1:]
    ends[-1] = p1
    zone_end = piece.searchsorted(c + half, side="left")
    zone_end += p0
    # within the segment (np.clip costs 3x this)
    np.maximum(zone_end, starts, out=zone_end)
    np.minimum(zone_end, ends, out=zone_end)
    return mu, starts, ends, zone_end
